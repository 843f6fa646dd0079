"""Accuracy over many seeds (issue 21, section 1): matching per pair class and instrument, pointing per instrument.

For each seed: ``mercury-dem synth`` a mission of the preset (default ``tiny``) with that seed,
``mercury-dem run --no-dem --scheduler sync`` on it (the pointing error after the global
adjustment per instrument, from ``report.json``: ``validation.image_space_error_px.by_instrument``,
the RMS over the instrument's images of each image's pointing error in its own pixels), and
every tile matched again as the pipeline matches it (``bench_match.tracks_study``: the run's
plan, tracks on) with each match's true error. The pairs are grouped by illumination class,
scale band, convergence band and instrument pair (WAC-WAC, NAC-NAC, WAC-NAC); per group and
seed: the share of truly overlapping pairs (>= 10 %) with >= 20 matches, the median / p95 true
error (match image's pixels) and the share > 2 px. Then the spread over seeds: median seed,
worst seed (the highest error / lowest share), and the seed it was.

Each seed's figures are kept in ``WORKDIR/seed_<N>.json`` (a later call reuses them; missions
and runs too), so the study resumes.

Run (CPU-heavy: take the lock, nice'd):
    flock /tmp/mercury_bench.lock nice .venv/bin/python workflows/benchmarks/bench_seeds.py \\
        --workdir /tmp/seeds --seeds 201-212
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

CONVERGENCE_BANDS = ((0, 10), (10, 20), (20, 30), (30, 45), (45, 180))
TARGETS = {  # (group, figure): (goal, 'max' or 'min')
    ("similar", "p95_px"): (0.5, "max"),
    ("similar", "median_px"): (0.2, "max"),
    ("all", "outlier_share"): (0.005, "max"),
}
POINTING_GOAL_PX = 0.5


def _cli(*args: str, log: Path) -> float:
    """Run ``mercury-dem ARGS`` in a subprocess (this interpreter, this checkout); seconds."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(Path(__file__).resolve().parents[2]) + os.pathsep + env.get("PYTHONPATH", "")
    t0 = time.perf_counter()
    with open(log, "a") as fh:
        subprocess.run([sys.executable, "-m", "mercury_dem.cli", *args], check=True, env=env, stdout=fh, stderr=fh)
    return time.perf_counter() - t0


def pair_groups(rows: list[dict[str, Any]], instrument: dict[str, str]) -> dict[str, list[int]]:
    """Report rows by group: illumination class, scale band, convergence band, instrument pair."""
    from mercury_dem.validate.matching import illumination_class, scale_class

    groups: dict[str, list[int]] = {"all": []}
    for k, r in enumerate(rows):
        names = ["all", illumination_class(r["incidence_difference_deg"], r["sun_azimuth_difference_deg"]),
                 "scale " + scale_class(r["scale_ratio"])]
        conv = r.get("convergence_deg", float("nan"))
        for lo, hi in CONVERGENCE_BANDS:
            if np.isfinite(conv) and lo <= conv < hi:
                names.append(f"convergence {lo}-{hi if hi < 180 else '+'}")
        ins = sorted(instrument.get(str(r[x]), "?").replace("MDIS-", "") for x in ("ref_id", "match_id"))
        names.append("-".join(ins))
        if names[1] == "similar":
            names.append("similar " + "-".join(ins))
            if np.isfinite(conv):  # the class's tail is its convergent pairs (issue 21 §2)
                names.append("similar, convergence " + ("< 45" if conv < 45 else ">= 45"))
        for n in names:
            groups.setdefault(n, []).append(k)
    return groups


def group_figures(err: np.ndarray, pair: np.ndarray, rows: list[dict[str, Any]], overlaps: list[float],
                  groups: dict[str, list[int]], min_matches: int = 20,
                  across: np.ndarray | None = None) -> dict[str, dict[str, float]]:
    """Per group: pairs, overlapping pairs, share of them with >= min_matches, measures, median, p95, > 2 px;
    with ``across`` (the error across the epipolar line, ``true_error_components``) its median and p95 too."""
    counts = np.bincount(pair, minlength=len(rows)) if pair.size else np.zeros(len(rows), np.int64)
    # a pair skipped as redundant (``match.redundant_convergence_deg``: a narrower route joins its images) was
    # not tried, so it is not a pair that failed to match
    from mercury_dem.match.selection import REDUNDANT_REASON

    redundant = np.array([str(r.get("reason", "")).startswith(REDUNDANT_REASON) for r in rows], bool)
    ov_all = (np.asarray(overlaps, float) >= 0.10) & ~redundant
    out: dict[str, dict[str, float]] = {}
    for name, members in groups.items():
        m = np.asarray(members, np.int64)
        e = err[np.isin(pair, m)]
        e = e[np.isfinite(e)]
        ov = ov_all[m]
        out[name] = {
            "n_pairs": float(m.size), "n_overlapping": float(ov.sum()),
            "share_with_min_matches": float(np.mean(counts[m][ov] >= min_matches)) if ov.any() else float("nan"),
            "n_redundant": float(redundant[m].sum()),
            "n_measures": float(e.size),
            "median_px": float(np.median(e)) if e.size else float("nan"),
            "p95_px": float(np.percentile(e, 95)) if e.size else float("nan"),
            "outlier_share": float(np.mean(e > 2.0)) if e.size else float("nan"),
        }
        if across is not None:
            a = across[np.isin(pair, m)]
            a = a[np.isfinite(a)]
            out[name]["across_median_px"] = float(np.median(a)) if a.size else float("nan")
            out[name]["across_p95_px"] = float(np.percentile(a, 95)) if a.size else float("nan")
    return out


def one_seed(seed: int, workdir: Path, preset: str, config: str | None, missions: Path | None = None,
             study_matching: bool = True, render_grid_px: float = 0.0) -> dict[str, Any]:
    """Synthesize, run and study one seed (cached in WORKDIR/seed_N.json; missions in ``missions`` when given).

    ``study_matching`` False: the run's pointing figures only (for a change that does not touch matching:
    its matching figures are those of the run before it)."""
    out_json = workdir / f"seed_{seed}.json"
    if out_json.exists():
        return json.loads(out_json.read_text())
    from bench_match import tracks_study

    from mercury_dem.mission import open_mission

    mission, run = (missions or workdir) / f"mission_{seed}", workdir / f"run_{seed}"
    log = workdir / f"seed_{seed}.log"
    t_synth = t_run = 0.0
    if not (mission / "mission.json").exists():
        grid = ["--render-grid-px", str(render_grid_px)] if render_grid_px > 0 else []
        t_synth = _cli("synth", str(mission), "--preset", preset, "--seed", str(seed), "--quiet", "--overwrite", *grid,
                       log=log)
    cfg = ["--config", config] if config else []
    if not (run / "report.json").exists():
        t_run = _cli("run", str(mission), "--out", str(run), "--scheduler", "sync", "--no-dem", "--quiet", *cfg, log=log)
    report = json.loads((run / "report.json").read_text())
    val = report.get("validation", {})
    ms = open_mission(str(mission))
    instrument = dict(zip(ms.catalog["image_id"].astype(str), ms.catalog["instrument"].astype(str)))
    t0 = time.perf_counter()
    if study_matching:
        from mercury_dem.config import load_config

        mcfg = load_config(config).match  # the run's matching settings (the defaults without --config)
        study = tracks_study(str(mission), str(run), config=mcfg, verbose=False, tracks=mcfg.tracks)
        rows = study["pair_rows"]
        figs = group_figures(np.asarray(study["pair_errors"], float), np.asarray(study["pair_of_error"], np.int64),
                             rows, study["pair_overlaps"], pair_groups(rows, instrument),
                             across=np.asarray(study["pair_errors_across"], float))
    else:
        nan = float("nan")
        study = {"pairs": nan, "pairs_matched": nan, "matches": nan, "net_median_px": nan, "net_p95_px": nan,
                 "match_seconds": 0.0}
        figs = {}
    t_study = time.perf_counter() - t0
    result = {
        "seed": seed, "preset": preset, "config": config,
        "groups": figs,
        "pointing_px": {k: v.get("adjusted_rms") for k, v in
                        val.get("image_space_error_px", {}).get("by_instrument", {}).items()},
        "pointing_images": {k: v.get("images") for k, v in
                            val.get("image_space_error_px", {}).get("by_instrument", {}).items()},
        "point_error_m": val.get("point_error_m", {}),
        "pairs": study["pairs"], "pairs_matched": study["pairs_matched"], "matches": study["matches"],
        "net_median_px": study["net_median_px"], "net_p95_px": study["net_p95_px"],
        "seconds": {"synth": t_synth, "run": t_run, "study": t_study, "matching": study["match_seconds"]},
    }
    tmp = out_json.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result, indent=1))
    tmp.replace(out_json)
    return result


def spread(values: list[float], worst: str) -> tuple[float, float, int]:
    """(median over seeds, worst value, index of the worst); NaN seeds ignored."""
    v = np.array([np.nan if x is None else x for x in values], float)
    ok = np.isfinite(v)
    if not ok.any():
        return float("nan"), float("nan"), -1
    k = int(np.nanargmax(v) if worst == "max" else np.nanargmin(v))
    return float(np.median(v[ok])), float(v[k]), k


def report(results: list[dict[str, Any]]) -> str:
    """Markdown: per group the spread over seeds; pointing per instrument; the targets."""
    seeds = [r["seed"] for r in results]
    names: list[str] = []
    for r in results:
        for n in r["groups"]:
            if n not in names:
                names.append(n)
    order = ["all", "similar", "incidence", "azimuth", "scale <=1.5x", "scale 1.5-4x", "scale >4x"]
    names = [n for n in order if n in names] + sorted(n for n in names if n not in order)
    lines = [f"seeds: {', '.join(map(str, seeds))} ({len(seeds)} missions, preset {results[0]['preset']})", "",
             "| group | pairs (sum) | overlapping with >= 20: median seed / worst | median px: median seed / worst "
             "| p95 px: median seed / worst (seed) | > 2 px: median seed / worst "
             "| across the epipolar line, p95 px: median seed / worst |",
             "|---|---|---|---|---|---|---|"]
    for n in names:
        g = [r["groups"].get(n, {}) for r in results]
        npairs = int(sum(x.get("n_pairs", 0) for x in g))
        sh = spread([x.get("share_with_min_matches") for x in g], "min")
        md = spread([x.get("median_px") for x in g], "max")
        p9 = spread([x.get("p95_px") for x in g], "max")
        ou = spread([x.get("outlier_share") for x in g], "max")
        ac = spread([x.get("across_p95_px") for x in g], "max")
        lines.append(f"| {n} | {npairs} | {100 * sh[0]:.0f} % / {100 * sh[1]:.0f} % | {md[0]:.3f} / {md[1]:.3f} "
                     f"| {p9[0]:.3f} / {p9[1]:.3f} ({seeds[p9[2]] if p9[2] >= 0 else '-'}) "
                     f"| {100 * ou[0]:.2f} % / {100 * ou[1]:.2f} % | {ac[0]:.3f} / {ac[1]:.3f} |")
    lines += ["", "| instrument | images per mission | pointing after adjustment px (RMS): median seed / worst (seed) | every seed |",
              "|---|---|---|---|"]
    insts = sorted({k for r in results for k in r["pointing_px"]})
    for ins in insts:
        vals = [r["pointing_px"].get(ins) for r in results]
        md = spread(vals, "max")
        nimg = int(np.median([r["pointing_images"].get(ins, 0) for r in results]))
        lines.append(f"| {ins} | {nimg} | {md[0]:.3f} / {md[1]:.3f} ({seeds[md[2]]}) | "
                     + " ".join("-" if v is None else f"{v:.3f}" for v in vals) + " |")
    lines += ["", "| target | goal | median seed | worst seed | met (median <= goal, worst <= 1.2 goal) |", "|---|---|---|---|---|"]
    for (grp, fig), (goal, _) in TARGETS.items():
        md = spread([r["groups"].get(grp, {}).get(fig) for r in results], "max")
        lines.append(f"| {grp} {fig} | {goal} | {md[0]:.4f} | {md[1]:.4f} | {'yes' if md[0] <= goal and md[1] <= 1.2 * goal else 'NO'} |")
    for ins in insts:
        md = spread([r["pointing_px"].get(ins) for r in results], "max")
        lines.append(f"| pointing {ins} px | {POINTING_GOAL_PX} | {md[0]:.3f} | {md[1]:.3f} | "
                     f"{'yes' if md[0] <= POINTING_GOAL_PX and md[1] <= 1.2 * POINTING_GOAL_PX else 'NO'} |")
    secs = np.array([[r["seconds"][k] for k in ("synth", "run", "study")] for r in results])
    lines += ["", f"seconds per seed (median): synth {np.median(secs[:, 0]):.0f}, run {np.median(secs[:, 1]):.0f}, "
                  f"matching study {np.median(secs[:, 2]):.0f} (0 = reused)"]
    return "\n".join(lines)


def parse_seeds(text: str) -> list[int]:
    """'201-205,300' -> [201, 202, 203, 204, 205, 300]."""
    out: list[int] = []
    for part in text.split(","):
        if "-" in part:
            a, b = part.split("-")
            out.extend(range(int(a), int(b) + 1))
        elif part:
            out.append(int(part))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--workdir", required=True, help="missions, runs and per-seed figures go here (reused)")
    p.add_argument("--seeds", default="201-212", help="e.g. 201-212 or 5,9,13")
    p.add_argument("--preset", default="tiny")
    p.add_argument("--config", help="YAML configuration for the runs (default: the defaults)")
    p.add_argument("--json", help="also write every seed's figures to this file")
    p.add_argument("--missions", help="take (or make) the missions in this directory (e.g. another study's "
                   "WORKDIR: the same missions, matched and adjusted again)")
    p.add_argument("--render-grid-px", type=float, default=0.0,
                   help="missions made here are rendered on this grid (synth --render-grid-px; 0: the preset's)")
    p.add_argument("--report-only", action="store_true", help="only the report of the seeds already in WORKDIR")
    p.add_argument("--pointing-only", action="store_true", help="run and pointing figures only, no matching "
                   "study (for changes after matching: the adjustment's weights, its priors)")
    a = p.parse_args()
    work = Path(a.workdir)
    work.mkdir(parents=True, exist_ok=True)
    results = []
    for s in parse_seeds(a.seeds):
        if a.report_only and not (work / f"seed_{s}.json").exists():
            continue
        r = one_seed(s, work, a.preset, a.config, Path(a.missions) if a.missions else None, not a.pointing_only,
                     a.render_grid_px)
        g = r["groups"].get("similar", {})
        print(f"seed {s}: similar median {g.get('median_px', float('nan')):.3f} p95 {g.get('p95_px', float('nan')):.3f}, "
              f"outliers {100 * r['groups'].get('all', {}).get('outlier_share', float('nan')):.2f} %, pointing "
              + ", ".join(f"{k} {v:.3f}" for k, v in r["pointing_px"].items() if v is not None), flush=True)
        results.append(r)
    print()
    print(report(results))
    if a.json:
        Path(a.json).write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
