"""``RUN/report.json``: the stable contract that tools and notebooks read, and its printed summary.

Keys (see docs/design.md): ``tiles`` {total, non_empty, succeeded, failed: [{tile, error, failure}]},
``levels`` {region: [...], hemisphere: [...], global: {...}} with per unit id, name, ok, error, failure,
images, points, measures, rms_px, sigma0, rejected, iterations, seconds; ``images`` {input,
controlled, uncontrolled: [ids], excluded: {id: reason}}; ``timings``; ``config``; ``versions``;
``execution``; ``dem``; ``failures`` {level: {kind: count}} (the failed units of each level counted by
their :class:`~mercury_dem.pipeline.results.UnitFailure`; ``unrecorded`` for summaries of older runs);
and, when the mission has truth, ``validation``.
"""

from __future__ import annotations

import math
import sys
from typing import TYPE_CHECKING, Any, TextIO

from mercury_dem.config import Config, to_dict
from mercury_dem.io.run_store import PAIRS_FILE, RunStore, read_solution
from mercury_dem.io.tables import read_table
from mercury_dem.pipeline.results import Summary, TileSummary, UnitSummary

if TYPE_CHECKING:
    from mercury_dem.mission import Mission

LEVEL_KEYS = ("id", "name", "ok", "error", "failure", "images", "points", "measures", "rms_px", "sigma0", "rejected",
              "iterations", "seconds", "converged", "reason", "sigma0_history", "flagged_images", "islands",
              "children", "altimetry", "point_prior", "point_prior_centre", "levelling", "underdetermined_points", "weak_images",
              "images_without_measures", "single_measure_points")


def _level_row(s: Summary) -> dict[str, Any]:
    """A unit's row of ``report.json``'s levels: the keys of ``LEVEL_KEYS`` its summary has, in that order."""
    has: dict[str, Any] = {"id": s.id, "name": s.name, "ok": s.ok, "error": s.error}
    if s.failure is not None:
        has["failure"] = s.failure.value
    if isinstance(s, UnitSummary) and s.children is not None:  # merged: its adjustment's figures
        has.update(s.adjustment, children=s.children)
        if s.single_measure_points is not None:
            has["single_measure_points"] = s.single_measure_points
    if s.seconds is not None:
        has["seconds"] = s.seconds
    return {k: has[k] for k in LEVEL_KEYS if k in has}


def versions() -> dict[str, str]:
    """Versions of this package, Python and the libraries that shape a result (``run.json``, ``report.json``)."""
    import cv2
    import numpy as np
    import scipy
    import xarray
    import zarr

    from mercury_dem import __version__
    from mercury_dem.compute.clusters import versions as execution_versions

    return {
        "mercury_dem": __version__, "python": sys.version.split()[0], "numpy": np.__version__,
        "scipy": scipy.__version__, "opencv": cv2.__version__, **execution_versions(),
        "zarr": zarr.__version__, "xarray": xarray.__version__,
    }


def build_report(store: RunStore, mission: Mission, config: Config, plan: dict[str, Any],
                 summaries: dict[str, list[Summary]], timings: dict[str, float], conn: Any,
                 dem_summary: dict[str, Any] | None, validation: dict[str, Any] | None = None) -> dict[str, Any]:
    """The run's report (``report.json``): images, levels, timings, validation against the truth and the DEM's summary.

    ``summaries``: the typed summaries of each level's units (:mod:`mercury_dem.pipeline.results`);
    ``validation``: the global solution's against the truth when a worker computed it (else computed here).
    """
    glob = summaries.get("global", [])
    global_ok = bool(glob and glob[0].ok)
    report: dict[str, Any] = {
        "run": store.location,
        "mission": _mission_ref(store, mission),
        # the target, as the mission declares it: the datum its heights refer to and its CRS
        "body": mission.body.to_dict(),
        "tiles": tiles_block(plan, summaries.get("tile", [])),
        "levels": {
            "region": [_level_row(s) for s in summaries.get("region", [])],
            "hemisphere": [_level_row(s) for s in summaries.get("hemisphere", [])],
            "global": _level_row(glob[0]) if glob else None,
        },
        "failures": failure_counts(summaries),
    }
    controlled, validation = _global_solution(store, mission, validation) if global_ok else ([], None)
    cset = set(controlled)
    ids_all = [str(x) for x in mission.catalog["image_id"]]
    uncontrolled = [i for i in ids_all if i not in cset]
    report["images"] = {
        "input": len(ids_all),
        "controlled": len(controlled),
        "uncontrolled": uncontrolled,
        "uncontrolled_reasons": uncontrolled_reasons(store, uncontrolled, plan, global_ok,
                                                     report["tiles"]["image_errors"]),
        "excluded": plan.get("excluded", {}),
    }
    report["timings"] = {k: float(v) for k, v in timings.items()}
    report["execution"] = {"mode": conn.mode, "description": conn.description}
    report["config"] = to_dict(config)
    report["versions"] = versions()
    if dem_summary is not None:
        report["dem"] = dem_summary
    if validation is not None:
        if dem_summary is not None and "validation" in dem_summary:
            validation["dem"] = dem_summary.pop("validation")
        report["validation"] = validation
    return report


def tiles_block(plan: dict[str, Any], tiles: list[Summary]) -> dict[str, Any]:
    """``report.json``'s ``tiles``: counts, the failed tiles with their errors, the images whose pixels failed."""
    return {
        "total": int(plan["tiles_total"]),
        "non_empty": len(plan["non_empty_tiles"]),
        "succeeded": sum(1 for s in tiles if s.ok),
        "failed": [{"tile": s.id, "error": s.error, "failure": _kind(s)} for s in tiles if not s.ok],
        "image_errors": {k: v for s in tiles if isinstance(s, TileSummary) for k, v in s.image_errors.items()},
    }


def _kind(s: Summary) -> str:
    return "unrecorded" if s.failure is None else s.failure.value


def failure_counts(summaries: dict[str, list[Summary]]) -> dict[str, dict[str, int]]:
    """``report.json``'s ``failures``: per level with a failed unit, the failed units counted by kind (most first)."""
    out: dict[str, dict[str, int]] = {}
    for level, units in summaries.items():
        counts: dict[str, int] = {}
        for s in units:
            if not s.ok:
                counts[_kind(s)] = counts.get(_kind(s), 0) + 1
        if counts:
            out[level] = dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))
    return out


def _global_solution(store: RunStore, mission: Mission, validation: dict[str, Any] | None = None,
                     ) -> tuple[list[str], dict[str, Any] | None]:
    """The images the global solution controls (at least one measure), and its validation against the mission's
    truth (None without one): ``validation`` when given (computed on a worker, :func:`validate_global_task`),
    else :func:`validate_global` here.
    """
    sid, rot, pos, table = read_solution(store.solution_path("global", 0))
    nmeas = table["n_measures"].to_numpy()
    controlled = [str(i) for i, n in zip(sid, nmeas) if n > 0]
    if mission.truth is None:
        return controlled, None
    return controlled, validation if validation is not None else validate_global(store, mission)


def validate_global(store: RunStore, mission: Mission) -> dict[str, Any]:
    """The global solution against the mission's truth (:func:`mercury_dem.validate.run.validate_run`)."""
    from mercury_dem.io.network_store import read_network
    from mercury_dem.validate.run import validate_run

    sid, rot, pos, table = read_solution(store.solution_path("global", 0))
    nmeas = table["n_measures"].to_numpy()
    net = read_network(store.network_path("global", 0))
    keep = nmeas > 0
    return validate_run(net, list(sid[keep]), rot[keep], mission, nmeas[keep], positions=pos[keep])


def validate_global_task(run_url: str) -> dict[str, Any]:
    """Task body of a bucket run (issue 33: the client stays light): :func:`validate_global` on a worker, which
    reads the run, its mission and truth from the bucket into its own cache.
    """
    from mercury_dem.mission import open_mission

    store = RunStore.open(run_url)
    return validate_global(store, open_mission(store.read_run()["mission"]))


def uncontrolled_reasons(store: RunStore, ids: list[str], plan: dict[str, Any], global_ok: bool,
                         image_errors: dict[str, str] | None = None) -> dict[str, str]:
    """Why each uncontrolled image is: excluded, its pixels unreadable or unusable (``image_errors``, from the
    tiles), no a-priori overlap, no pair matched, or all measures rejected.
    """
    import pandas as pd

    if not ids:
        return {}
    images, pairs, _ = store.read_plan()
    excluded = plan.get("excluded", {})
    partners: dict[str, int] = {}
    for a, b in zip(pairs["image_i"].astype(str), pairs["image_j"].astype(str)):
        partners[a] = partners.get(a, 0) + 1
        partners[b] = partners.get(b, 0) + 1
    rows = []
    for t in store.completed_units("tile"):
        p = store.unit_file("tile", t, PAIRS_FILE)
        if p.is_file():
            t = read_table(p, f"tile {t}")  # a tile without pairs wrote a table without columns
            if {"ref_id", "match_id", "status", "reason"} <= set(t.columns):
                rows.append(t[["ref_id", "match_id", "status", "reason"]])
    tried = pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(columns=["ref_id", "match_id", "status", "reason"])
    out = {}
    for i in ids:
        if i in excluded:
            out[i] = f"excluded: {excluded[i]}"
            continue
        if image_errors and i in image_errors:
            out[i] = unit_message(image_errors[i], f"image {i}")
            continue
        if partners.get(i, 0) == 0:
            out[i] = ("no a-priori overlap with any other image: its footprint shares no ground with the others "
                      "(add images that overlap it, or accept it as uncontrolled)")
            continue
        mine = tried[(tried["ref_id"].astype(str) == i) | (tried["match_id"].astype(str) == i)]
        matched = mine[mine["status"] == "matched"]
        if len(mine) and not len(matched):
            why = "; ".join(sorted({str(r)[:120] for r in mine["reason"]})[:3])
            out[i] = f"none of its {len(mine)} overlapping pairs matched ({why})"
        elif not global_ok:
            out[i] = "the global adjustment failed (see levels.global.error)"
        else:
            out[i] = (f"{len(matched)} of its pairs matched, but none of its measures survived the merge and the "
                      "adjustment's outlier rejection")
    return out


def _mission_ref(store: RunStore, mission: Mission) -> str:
    """The mission as the user named it: its URL when it is read from a bucket (``mission.path`` is then
    its local cached copy), else its path as before.
    """
    named = str(store.read_run().get("mission", ""))
    return named if "://" in named else str(mission.path)


def write_report(store: RunStore, report: dict[str, Any]) -> None:
    """Write ``report.json`` into the run store atomically (and commit it to a bucket run): :meth:`RunStore.write_report`."""
    store.write_report(report)


def _f(x: Any, fmt: str = ".3f") -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, fmt)


def print_report(report: dict[str, Any], stream: TextIO) -> None:
    """A readable summary of report.json."""
    w = stream.write
    w(f"run {report['run']}  (mission {report['mission']})\n")
    w(_tiles_and_images_text(report))
    w(_levels_text(report["levels"]))
    for level, counts in (report.get("failures") or {}).items():
        w(f"failed {level} units by kind: " + ", ".join(f"{k} {n}" for k, n in counts.items()) + "\n")
    v = report.get("validation")
    if v:
        w(_validation_text(v))
    from mercury_dem.pipeline.reference_check import reference_by_map_table, reference_table, shape_check_lines

    dem = report.get("dem") or {}
    w(reference_table(dem.get("reference") or {}))
    w(reference_by_map_table(dem.get("reference_by_map") or {}))
    shape_lines = shape_check_lines(dem.get("shape_check"))
    if shape_lines:
        w("\n" + "\n".join(shape_lines) + "\n")
    for rel, why in (dem.get("products_skipped") or {}).items():
        w(f"not written: products/{rel} ({why})\n")
    w(dense_lines(report.get("dense")))
    tm = report.get("timings", {})
    w("\ntimings (s): " + ", ".join(f"{k} {v:.1f}" for k, v in tm.items()) + "\n")


def _tiles_and_images_text(report: dict[str, Any]) -> str:
    """The tiles and images lines: failed tiles, recomputed units, uncontrolled images and why, bad pixels."""
    t, im = report["tiles"], report["images"]
    out = [f"tiles: {t['non_empty']} non-empty of {t['total']}; {t['succeeded']} succeeded, {len(t['failed'])} failed\n"]
    for f in t["failed"][:10]:
        name = f"tile {f['tile']}"
        out.append(f"  {name}: {unit_message(f['error'], name)}\n")
    out.append(f"images: {im['input']} input, {im['controlled']} controlled, {len(im['uncontrolled'])} uncontrolled\n")
    for c in (report.get("integrity") or {}).get("corrupt", []):  # units that failed their checksums on resume
        out.append(f"  recomputed {c.get('name')}: {'; '.join(c.get('problems', [])[:3])}\n")
    reasons = im.get("uncontrolled_reasons") or {}
    for i in im["uncontrolled"][:10]:
        if i in reasons:
            out.append(f"  uncontrolled {i}: {reasons[i]}\n")
    shown = set(im["uncontrolled"][:10])
    for i, why in list((t.get("image_errors") or {}).items())[:10]:
        if i not in shown:  # an image with bad pixels that is controlled all the same (another copy, ...)
            out.append(f"  image {i}: {unit_message(why, f'image {i}')}\n")
    return "".join(out)


def _levels_text(levels: dict[str, Any]) -> str:
    """The table of adjusted units (one row each, FAILED with its message) and each unit's notes."""
    out = ["\n", f"{'level':<22}{'images':>7}{'points':>9}{'measures':>10}{'rms px':>8}{'sigma0':>8}{'rej':>7}"
                  f"{'iter':>5}{'s':>7}\n"]
    rows = list(levels["region"]) + list(levels["hemisphere"])
    if levels["global"]:
        rows.append(levels["global"])
    for r in rows:
        name = r.get("name") or str(r.get("id"))
        if not r.get("ok"):
            out.append(f"{name:<22} FAILED: {unit_message(r.get('error'), name)}\n")
            continue
        out.append(f"{name:<22}{r.get('images', 0):>7}{r.get('points', 0):>9}{r.get('measures', 0):>10}"
                   f"{_f(r.get('rms_px')):>8}{_f(r.get('sigma0')):>8}{r.get('rejected', 0):>7}{r.get('iterations', 0):>5}"
                   f"{_f(r.get('seconds'), '.1f'):>7}\n")
    for r in rows:
        for line in level_notes(r):
            out.append(f"  {r.get('name') or r.get('id')}: {line}\n")
    return "".join(out)


def _validation_text(v: dict[str, Any]) -> str:
    """The pointing, point and DEM errors against the truth."""
    p = v["pointing_error_urad"]
    ims = v.get("image_space_error_px") or {}
    pe = v["point_error_m"]
    out = (f"\npointing error vs truth, in each image's pixels (IFOV) RMS: a-priori {_f(ims.get('a_priori_rms'), '.2f')}, "
           f"adjusted {_f(v.get('adjusted_rms_in_ifov'), '.2f')}\n"
           f"pointing error vs truth (urad RMS): a-priori {_f(p['a_priori_rms'], '.1f')}, adjusted "
           f"{_f(p['adjusted_rms'], '.1f')} (boresight {_f(p.get('adjusted_boresight_rms'), '.1f')}, twist "
           f"{_f(p.get('adjusted_twist_rms'), '.1f')}; mean IFOV {_f(v['ifov_urad'], '.1f')})\n"
           f"point error vs truth (m): median {_f(pe['median'], '.1f')}, p95 {_f(pe['p95'], '.1f')} ({pe['points']} points)\n")
    d = v.get("dem")
    return out + (dem_validation_table(d) if d else "")


def dense_lines(dense: dict[str, Any] | None, limit: int = 5) -> str:
    """The dense stage's block of ``report.json`` in a few lines (empty when the run has none)."""
    if not dense:
        return ""
    if dense.get("error"):
        return f"\ndense: {dense['error']}\n"
    p = dense.get("pairs", {})
    reasons = ", ".join(f"{k} {v}" for k, v in sorted((p.get("rejected_by_reason") or {}).items(), key=lambda kv: -kv[1]))
    out = [f"\ndense: {p.get('selected', 0)} of {p.get('candidates', 0)} candidate pairs selected (rejected: "
           f"{reasons or 'none'}); {dense.get('chips', 0)} chips, {dense.get('chips_failed', 0)} failed; "
           f"{dense.get('points', 0)} points\n"]
    for what, kinds in (("failed tiles", (dense.get("tiles") or {}).get("failed_by_kind")),
                        ("failed pairs and chips", dense.get("failures_by_kind"))):
        if kinds:  # an older run's report has no counts by kind: its errors below only
            out.append(f"  {what} by kind: " + ", ".join(f"{k} {v}" for k, v in kinds.items()) + "\n")
    for t in (dense.get("tiles") or {}).get("failed", [])[:limit]:
        out.append(f"  {t.get('error')}\n")
    for f in (dense.get("failures") or [])[:limit]:
        out.append(f"  {f.get('error')}\n")
    dem = dense.get("dem") or {}
    if dem.get("error"):
        out.append(f"  dense DEM: {dem['error']}\n")
    elif dem:
        frac = dem.get("source_fraction", {})
        out.append(f"  dense DEM: {dem.get('pixels_per_degree')} pixel/deg, dense {_f(frac.get('dense'), '.0%')}, "
                   f"sparse fallback {_f(frac.get('sparse_fallback'), '.0%')}; RMSE dense / sparse on the dense "
                   f"pixels {_f(dem.get('rmse_ratio_dense_over_sparse'), '.2f')}; frame {dem.get('frame', 'adjusted')}"
                   + (f", levelled on the altimetry in {lv['tiles']} tiles" if (lv := dem.get("altimetry_level")) else "")
                   + (f"; {pl['pairs_levelled']} of {pl['pairs']} pairs put on the sparse DEM's level (median "
                      f"{_f(pl.get('offset_median_m'), '+.0f')} m)" if (pl := dem.get("pair_level")) else "")
                   + "\n")
    out += _dense_product_lines(dense)
    return "".join(out)


def _dense_product_lines(dense: dict[str, Any]) -> list[str]:
    """The dense DEM's products, orthoimages and reference comparison, a line each (when the stage made them)."""
    out = []
    prod = dense.get("products") or {}
    if prod.get("error"):
        out.append(f"  dense products: {prod['error']}\n")
    elif prod:
        out.append(f"  dense products: {len(prod.get('files', []))} files in {prod.get('dir')}\n")
    ortho = dense.get("ortho") or {}
    if ortho:
        made = sum("path" in m for m in (ortho.get("mosaics") or {}).values())
        out.append(f"  orthoimages on the dense DEM: {ortho.get('images', 0)} images, {made} tile mosaics\n")
    ref = dense.get("reference") or {}
    for name, stats in (ref.get("dense") or {}).items():
        sparse = (ref.get("sparse") or {}).get(name) or {}
        delivered = (ref.get("delivered") or {}).get(name) or {}
        if "rmse_m" in stats:
            out.append(f"  vs {name}: delivered dense DEM RMSE {_f(delivered.get('rmse_m'), '.0f')} m (bias "
                       f"{_f(delivered.get('bias_m'), '+.0f')}), dense values alone "
                       f"{_f(stats.get('rmse_m'), '.0f')} m (bias {_f(stats.get('bias_m'), '+.0f')}), sparse on "
                       f"the same pixels {_f(sparse.get('rmse_m'), '.0f')} m (bias {_f(sparse.get('bias_m'), '+.0f')})\n")
    holes = (dense.get("dem") or {}).get("hole_fraction") or {}
    if holes.get("footprint_pixels"):
        out.append(f"  holes within the block's footprint ({holes['footprint_pixels']} pixels seen by >= 2 images): "
                   f"delivered {_f(holes.get('delivered'), '.1%')}, sparse {_f(holes.get('sparse'), '.1%')}, "
                   f"dense values alone {_f(holes.get('dense'), '.1%')}\n")
    return out


def level_notes(row: dict[str, Any], limit: int = 5) -> list[str]:
    """The parts of an adjusted unit it could not determine, one line each, with what they mean and what to do:
    islands (disconnected groups of images), images without measures, points seen by one image only.
    """
    def names(ids: list[Any]) -> str:
        return ", ".join(map(str, ids[:limit])) + (f" and {len(ids) - limit} more" if len(ids) > limit else "")

    out = []
    islands = row.get("islands") or []
    if len(islands) > 1:
        rest = "; ".join(f"[{names(isl)}]" for isl in islands[1:limit])
        out.append(f"{len(islands)} islands (groups of images no tie point joins; the largest has {len(islands[0])} "
                   f"images), besides it: {rest} — each island is held only by its a-priori pointing; add images "
                   "that overlap two islands to tie them")
    no_meas = row.get("images_without_measures") or []
    if no_meas:
        out.append(f"{len(no_meas)} images of its networks without a measure, left out of this adjustment "
                   f"(adjusted where they have measures, else uncontrolled): {names(no_meas)}")
    single = row.get("single_measure_points") or {}
    if single.get("count"):
        out.append(f"{single['count']} points with one measure, left unadjusted (one ray fixes no position), "
                   f"e.g. {names(single.get('ids') or [])}")
    return out


def unit_message(error: Any, name: str) -> str:
    """``error`` without a leading ``"<name>: "`` (messages in report.json name their unit; lines that
    already start with the unit's name print the rest).
    """
    text, prefix = str(error), f"{name}: "
    return text[len(prefix):] if text.startswith(prefix) else text


def dem_validation_table(d: dict[str, Any]) -> str:
    """``validation.dem`` as a table: one row per DEM (adjusted, a-priori), DEM minus truth in metres."""
    cols = (("rmse_m", "RMSE"), ("bias_m", "bias"), ("std_m", "std"), ("p5_m", "p5"), ("p50_m", "p50"),
            ("p95_m", "p95"))
    out = ["\nDEM minus truth (m)" + "".join(f"{label:>9}" for _, label in cols) + f"{'pixels':>11}\n"]
    for key, label in (("adjusted", "adjusted points"), ("a_priori", "a-priori points"),
                       ("registered", "registered (alt.)"), ("merged", "merged with alt."),
                       ("dense", "dense+fallback"), ("sparse_on_dense_grid", "sparse@dense grid"),
                       ("dense_on_dense_pixels", "dense, its pixels"), ("dense_alone_on_dense_pixels", "dense alone, same"),
                       ("sparse_on_dense_pixels", "sparse, same px")):
        row = d.get(key)
        if not isinstance(row, dict):
            continue
        if row.get("error"):
            out.append(f"  {label:<17} {row['error']}\n")
            continue
        out.append(f"  {label:<17}" + "".join(f"{_f(row.get(k), '.0f'):>9}" for k, _ in cols)
                   + f"{row.get('n_compared', 0):>11}\n")
    adjusted = d.get("adjusted")
    if isinstance(adjusted, dict) and adjusted.get("error_vs_latitude"):
        bands = [b for b in adjusted["error_vs_latitude"] if b.get("n")]
        out.append("  by latitude (bias/RMSE m): " + ", ".join(
            f"{b['lat_min']:.0f}..{b['lat_max']:.0f} {_f(b.get('bias_m'), '.0f')}/{_f(b.get('rmse_m'), '.0f')}"
            for b in bands) + "\n")
    low = adjusted.get("low_degree") if isinstance(adjusted, dict) else None
    if isinstance(low, dict):
        out.append("  long wavelengths: RMS of degrees 0.." + str(low["lmax"]) + " = "
                   + " / ".join(_f(v, ".0f") for v in low["degree_rms_m"])
                   + f" m; RMSE without them {_f(low.get('rmse_after_removal_m'), '.0f')} m\n")
    return "".join(out)
