"""Benchmark and accuracy study of tile matching (issue 4, sections 4 and 5).

Speed (default): seconds per pair of ``match_tile`` on a tile of overlapping
rendered images at 512^2 and 1024^2, side by side with the bare OpenCV floor for
the same pairs in the same run: FAST (same cap) + SIFT on both images, brute-force
k=2 one way, ratio test, one fundamental-matrix RANSAC -- no reuse, no guidance,
no refinement. Both at 1 thread and at 2 threads (ours: a thread pool over pairs;
the floor: OpenCV's own threads).

Accuracy (``--accuracy``): the standard pair classes of
:func:`mercury_dem.validate.matching.standard_pairs` rendered at 256^2, matched
with the defaults and with the pre-transform, guidance, NCC fallback and
refinement each switched off; true errors per class (Markdown tables).

Run (heavy; take the lock):
    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_match.py
    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_match.py --accuracy
    flock /tmp/mercury_bench.lock .venv/bin/python workflows/benchmarks/bench_match.py --mission MISSION
"""

from __future__ import annotations

import argparse
import dataclasses
import re
import time
from typing import Any

import cv2
import numpy as np
from harness import interleave, measure_here
from harness.scenarios import a_priori_overlaps

from mercury_dem.config.match import MatchConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.camera import mdis_wac
from mercury_dem.geometry.pose import rotation_from_angles
from mercury_dem.match import ImageGeometry, match_tile
from mercury_dem.match.features import image_quality, spread_best, stretch_to_8bit
from mercury_dem.validate.matching import (
    TruePose,
    format_summary,
    standard_pairs,
    summarize,
    true_error_components,
    true_errors,
    true_overlap,
)


def _surface_and_renderer() -> tuple[Any, Any]:
    from mercury_dem.synth.render import render_image
    from mercury_dem.synth.terrain import Surface, SurfaceParams

    return Surface(SurfaceParams(seed=42)), render_image


def _tile(n_px: int, n_images: int, rng: np.random.Generator) -> tuple[dict[str, Any], dict[str, ImageGeometry], list[tuple[str, str]], Any]:
    """n_images mutually overlapping views (same sun side, small offsets) and all their pairs."""
    surface, render = _surface_and_renderer()
    cam = mdis_wac(n_px)
    base = standard_pairs(cam)[0]  # the stereo pair's reference view
    images, geom = {}, {}
    offsets = [(0, 0), (60e3, 10e3), (-40e3, 50e3), (20e3, -60e3), (-70e3, -30e3), (80e3, 70e3)][:n_images]
    from mercury_dem.geometry.pose import look_at_rotation

    centre = base.ref.position / np.linalg.norm(base.ref.position) * 2439400.0
    alt = np.linalg.norm(base.ref.position) - 2439400.0
    up = centre / np.linalg.norm(centre)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    for k, (de, dn) in enumerate(offsets):
        c = centre + alt * up + de * east + dn * north
        r = look_at_rotation(c, centre + 0.3 * (de * east + dn * north), north)
        vid = f"img{k}"
        images[vid] = render(surface, cam, c, r, base.ref.sun, rng)
        r_ap = rotation_from_angles(rng.normal(0, 450e-6, 3)) @ r
        geom[vid] = ImageGeometry.of(cam, c + rng.normal(0, 100, 3), r_ap, base.ref.sun, datum_radius_m=DATUM_RADIUS_M)
    ids = list(images)
    pairs = [(ids[i], ids[j]) for i in range(len(ids)) for j in range(i + 1, len(ids))]
    return images, geom, pairs, surface


def floor_pair(a: np.ndarray, b: np.ndarray, config: MatchConfig) -> int:
    """The bare OpenCV work for one pair: detect + describe both, BF k=2 one way, ratio, one F RANSAC."""
    fast = cv2.FastFeatureDetector_create(threshold=config.fast_threshold, nonmaxSuppression=True)
    sift = cv2.SIFT_create()
    desc = []
    for img in (a, b):
        q = image_quality(img, config)
        i8 = stretch_to_8bit(img, q.low, q.high)
        kps = fast.detect(i8, None)
        pts = cv2.KeyPoint_convert(kps)
        resp = np.fromiter((k.response for k in kps), np.float32, len(kps))
        keep = spread_best(pts.astype(np.float64), resp, config.max_keypoints, i8.shape, config.keypoint_grid)
        kps = [kps[i] for i in keep]
        for k in kps:
            k.size = config.keypoint_size_px
        kps, d = sift.compute(i8, kps)
        desc.append((cv2.KeyPoint_convert(kps), d))
    (pa, da), (pb, db) = desc
    knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    good = [m[0] for m in knn if len(m) == 2 and m[0].distance < config.ratio * m[1].distance]
    if len(good) < 8:
        return 0
    qa = np.float64([pa[m.queryIdx] for m in good])
    qb = np.float64([pb[m.trainIdx] for m in good])
    _, mask = cv2.findFundamentalMat(qa, qb, cv2.FM_RANSAC, config.fundamental_tolerance_px, config.fundamental_confidence)
    return int(mask.sum()) if mask is not None else 0


def _timed(run: Any, label: str) -> Any:
    """One of :func:`speed`'s runs for ``harness.interleave``: timed in this process (``harness.measure_here``:
    wall, CPU of all threads); the table reads the last round's result (matches per pair)."""
    return lambda: measure_here(run, label=label)


def _timed_floor(images: Any, pairs: Any, cfg: Any, threads: int) -> Any:
    """The floor (:func:`floor_pair` on every pair) at ``threads`` OpenCV threads, for ``harness.interleave``."""
    def once() -> Any:
        old = cv2.getNumThreads()
        cv2.setNumThreads(threads)
        try:
            return measure_here(lambda: [floor_pair(images[a], images[b], cfg) for a, b in pairs], label="floor")
        finally:
            cv2.setNumThreads(old)
    return once


SPEED_VARIANTS = ("tracks_off", "extra0", "flow", "all_pairs")


def speed(sizes: list[int], n_images: int, repeats: int, variants: tuple[str, ...] = SPEED_VARIANTS) -> None:
    """Ours vs the floor, interleaved in every repetition; best-of and per-repetition ratios.

    Every repetition runs ours (the defaults), then each requested variant, then the
    floor, so a load change on the shared machine hits both sides of a ratio alike.
    The per-repetition ratios (ours / floor of the same repetition) are printed as
    well as the best-of ratios; CPU seconds are the process's (``process_time``, all threads).
    The rounds are ``harness.interleave``'s.
    """
    rng = np.random.default_rng(5)
    print(f"# bench_match speed: {n_images} mutually overlapping images per tile, all pairs; best of {repeats}")
    print("Wall seconds per pair (CPU seconds of the process in brackets: the machine is shared, CPU time is the")
    print("steadier figure at 1 thread). Ours includes computing every image's own features once.\n")
    print("(The tile's views converge by < 2 deg, so the dense-flow step, for pairs converging by >= "
          f"{MatchConfig().flow_min_convergence_deg:g} deg, does not run by default; the column 'flow on every pair' "
          "forces it, flow_min_convergence_deg=0.)\n")
    titles = {"tracks_off": "ours without track propagation: ratio wall, CPU",
              "extra0": "ours, propagate_extra=0 (full pairs receive no anchors): ratio wall, CPU",
              "flow": "ours with the flow on every pair: ratio wall, CPU",
              "all_pairs": "ours without the wide-pair route rule (redundant_convergence_deg=180): ratio wall, CPU"}
    head = ["size", "threads", "pairs", "ours s/pair", "floor s/pair", "ratio wall", "ratio CPU",
            *[titles[v] for v in variants], "per repetition: wall ratios; CPU ratios", "ours matches/pair",
            "floor F-inliers/pair"]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for n in sizes:
        images, geom, pairs, _ = _tile(n, n_images, rng)
        for threads in (1, 2):
            cfg = MatchConfig(threads=threads)
            runs = {
                "ours": lambda: match_tile(images, geom, pairs, cfg, pointing_sigma_urad=450.0),
                "tracks_off": lambda: match_tile(images, geom, pairs, cfg, tracks=False, pointing_sigma_urad=450.0),
                "extra0": lambda: match_tile(images, geom, pairs, dataclasses.replace(cfg, propagate_extra=0.0), pointing_sigma_urad=450.0),
                "flow": lambda: match_tile(images, geom, pairs, dataclasses.replace(cfg, flow_min_convergence_deg=0.0), pointing_sigma_urad=450.0),
                "all_pairs": lambda: match_tile(images, geom, pairs, dataclasses.replace(cfg, redundant_convergence_deg=180.0), pointing_sigma_urad=450.0),
            }
            res = interleave({**{key: _timed(runs[key], key) for key in ("ours", *variants)},
                              "floor": _timed_floor(images, pairs, cfg, threads)}, repeats)
            wall = {k: [m.wall_s for m in ms] for k, ms in res.items()}
            cpu = {k: [m.cpu_s for m in ms] for k, ms in res.items()}
            reps: Any = res["ours"][-1].value[1]
            fl: list[int] = res["floor"][-1].value
            k = len(pairs)
            o, f = min(wall["ours"]) / k, min(wall["floor"]) / k
            co, cf = min(cpu["ours"]) / k, min(cpu["floor"]) / k
            cols = [f"{min(wall[v]) / k / f:.2f}, {min(cpu[v]) / k / cf:.2f}" for v in variants]
            per_w = " ".join(f"{a / b:.2f}" for a, b in zip(wall["ours"], wall["floor"]))
            per_c = " ".join(f"{a / b:.2f}" for a, b in zip(cpu["ours"], cpu["floor"]))
            print(f"| {n}^2 | {threads} | {k} | {o:.3f} ({co:.3f}) | {f:.3f} ({cf:.3f}) | {o / f:.2f} | {co / cf:.2f} | "
                  + "".join(c + " | " for c in cols)
                  + f"{per_w}; {per_c} | {np.mean([r.n_matches for r in reps]):.0f} | {np.mean(fl):.0f} |", flush=True)


def accuracy() -> None:
    surface, render = _surface_and_renderer()
    cam = mdis_wac(256)
    scene = standard_pairs(cam)
    rng = np.random.default_rng(2024)
    ids: dict[int, str] = {}
    images: dict[str, Any] = {}
    geom: dict[str, ImageGeometry] = {}
    truth: dict[str, TruePose] = {}
    pairs = []
    for sp in scene:
        pid = []
        for v in (sp.ref, sp.match):
            if id(v) not in ids:
                vid = f"v{len(ids):02d}"
                ids[id(v)] = vid
                images[vid] = render(surface, v.camera, v.position, v.rotation, v.sun, rng)
                r_ap = rotation_from_angles(rng.normal(0, 450e-6, 3)) @ v.rotation
                geom[vid] = ImageGeometry.of(v.camera, v.position + rng.normal(0, 100, 3), r_ap, v.sun, datum_radius_m=DATUM_RADIUS_M)
                truth[vid] = TruePose(v.camera, v.position, v.rotation)
            pid.append(ids[id(v)])
        pairs.append((pid[0], pid[1]))
    overlaps = [true_overlap(truth[a], truth[b], surface.height, datum_radius_m=DATUM_RADIUS_M) for a, b in pairs]
    base = MatchConfig(threads=2, max_sun_azimuth_difference_deg=180.0)
    variants = {
        "defaults (the 90 deg sun-azimuth pair skipped: the requirement check)": MatchConfig(threads=2),
        "defaults with the sun-azimuth limit lifted (to measure the 90 deg pair)": base,
        "pre-transform off": dataclasses.replace(base, pretransform=False),
        "guidance off": dataclasses.replace(base, guided=False),
        "NCC fallback off": dataclasses.replace(base, ncc_fallback=False),
        "refinement off": dataclasses.replace(base, refine=False),
        "refinement on the DN (no local normalization, no dense flow)": dataclasses.replace(
            base, refine_normalize_sigma_px=0.0),
        "dense flow off": dataclasses.replace(base, flow_refine=False),
        "dense flow on every pair (flow_min_convergence_deg=0)": dataclasses.replace(base, flow_min_convergence_deg=0.0),
        "track propagation off": base,
    }
    for title, cfg in variants.items():
        m, reps = match_tile(images, geom, pairs, cfg, tracks=not title.startswith("track"), pointing_sigma_urad=450.0)
        pa = np.stack([m.sample_a, m.line_a], -1)
        pb = np.stack([m.sample_b, m.line_b], -1)
        err = true_errors(m.image_ids, m.image_a, m.image_b, pa, pb, truth, surface.height, datum_radius_m=DATUM_RADIUS_M)
        rows = [r.as_row() for r in reps]
        print(f"\n### {title}\n")
        print("| pair | status | route | matches | chain ratio>sym>F>H | ncc | kept>refined>local | flow moved/dropped | propagated | scale | d-inc | d-az | conv. deg | median px | p95 px | > 2 px |")
        print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
        for k, (name, r) in enumerate(zip([s.name for s in scene], reps)):
            e = err[m.pair == k]
            med = f"{np.median(e):.3f}" if e.size else "-"
            p95 = f"{np.percentile(e, 95):.3f}" if e.size else "-"
            out = f"{100 * np.mean(e > 2):.1f}%" if e.size else "-"
            print(f"| {name} | {r.status} | {r.route} | {r.n_matches} | {r.n_ratio}>{r.n_symmetry}>{r.n_fundamental}>"
                  f"{r.n_homography} | {r.n_ncc}>{r.n_ncc_homography} | {r.n_kept}>{r.n_refined}>{r.n_local} | {r.n_flow}/{r.n_flow_dropped} | "
                  f"{r.n_propagated} | {r.scale_ratio:.1f} | {r.incidence_difference_deg:.0f} | {r.sun_azimuth_difference_deg:.0f} | "
                  f"{r.convergence_deg:.0f} | {med} | {p95} | {out} |")
        print()
        print(format_summary(summarize(err, m.pair, rows, overlaps)))


def mission_accuracy(path: str, max_pairs: int = 0, config: MatchConfig | None = None, breakdown: bool = False) -> None:
    """Every a-priori overlapping pair of a synthetic mission (the first of each pair as reference), true errors by class."""
    from mercury_dem.mission import open_mission

    ms = open_mission(path)
    ids, cams, pos, rot, pairs = a_priori_overlaps(ms)
    n_all = len(pairs)
    if max_pairs and len(pairs) > max_pairs:
        pick = np.sort(np.random.default_rng(1).choice(len(pairs), max_pairs, replace=False))
        pairs = [pairs[k] for k in pick]
    used = sorted({x for p in pairs for x in p})
    images = {i: ms.read_image(i) for i in used}
    geom = {i: ImageGeometry.of(c, p, r, ms.sun_position(i), datum_radius_m=DATUM_RADIUS_M) for i, c, p, r in zip(ids, cams, pos, rot) if i in images}
    truth = {i: TruePose(c, *ms.need_truth().true_pose(i)) for i, c in zip(ids, cams) if i in images}
    surface = ms.need_truth().surface()
    overlaps = [true_overlap(truth[a], truth[b], surface.height, datum_radius_m=DATUM_RADIUS_M) for a, b in pairs]
    t0 = time.perf_counter()
    m, reps = match_tile(images, geom, pairs, config or MatchConfig(threads=2), pointing_sigma_urad=450.0)
    dt = time.perf_counter() - t0
    pa = np.stack([m.sample_a, m.line_a], -1)
    pb = np.stack([m.sample_b, m.line_b], -1)
    err = true_errors(m.image_ids, m.image_a, m.image_b, pa, pb, truth, surface.height, datum_radius_m=DATUM_RADIUS_M)
    rows = [r.as_row() for r in reps]
    status: dict[str, int] = {}
    for r in reps:
        key = f"{r.status}/{r.route}" if r.status == "matched" else f"{r.status}: {re.sub(r'[0-9.]+', 'N', r.reason.split(' (')[0])}"
        status[key] = status.get(key, 0) + 1
    print(f"mission {path}: {len(ids)} images, {n_all} a-priori overlapping pairs (>= 2 %), {len(pairs)} matched here, "
          f"{len(m)} matches in {dt:.1f} s ({dt / max(len(pairs), 1):.3f} s/pair, 2 threads)\n")
    print("| outcome | pairs |\n|---|---|")
    for k, v in sorted(status.items(), key=lambda kv: -kv[1]):
        print(f"| {k} | {v} |")
    print()
    print(format_summary(summarize(err, m.pair, rows, overlaps)))
    ov = np.asarray(overlaps) >= 0.10
    bad = [(a, b, f"{o:.2f}", r.reason) for (a, b), o, r in zip(pairs, overlaps, reps) if o >= 0.10 and r.n_matches < 20]
    print(f"\ntruly overlapping (>= 10 %) pairs with < 20 matches: {len(bad)} of {int(ov.sum())}")
    for b in bad[:15]:
        print("  ", *b)
    if breakdown:
        tail_breakdown(ms, m, err, rows, truth, surface)


def tail_breakdown(ms: Any, m: Any, err: np.ndarray, rows: list[dict[str, Any]], truth: dict[str, TruePose],
                   surface: Any) -> None:
    """Where the similar-illumination class's measures > 0.5 px come from (Markdown tables).

    Measures of 'similar' pairs up to 4x, broken down by: the pair's scale (match pixels per
    reference pixel: > 1 = the match image is finer, errors in its pixels), the cameras, the
    route and whether the measure was propagated, the refined NCC, the distance to the image
    edge, each image's emission angle, their difference and the angle between the two views'
    rays at the measure (true poses), and the
    terrain slope there (true surface, 0.01 deg baseline). Also the true error recomputed on the
    surface at the coarser image's resolution (what the renderer draws): the metric's share.
    """
    from mercury_dem.geometry.body import xyz_to_latlon
    from mercury_dem.geometry.pose import image_to_ground
    from mercury_dem.validate.matching import illumination_class

    ids = m.image_ids
    sim = np.array([illumination_class(r["incidence_difference_deg"], r["sun_azimuth_difference_deg"]) == "similar"
                    and r["scale_ratio"] <= 4.0 for r in rows])
    sel = np.flatnonzero(sim[m.pair] & np.isfinite(err)) if len(m) else np.zeros(0, np.int64)
    if sel.size == 0:
        return
    e = err[sel]
    pa = np.stack([m.sample_a, m.line_a], -1)[sel]
    pb = np.stack([m.sample_b, m.line_b], -1)[sel]
    ia, ib, pair = m.image_a[sel], m.image_b[sel], m.pair[sel]
    cams = {i: truth[i].camera for i in ids if i in truth}

    def per_image(points: np.ndarray, which: np.ndarray, fn: Any) -> np.ndarray:
        out = np.full(which.size, np.nan)
        for k in np.unique(which):
            s = np.flatnonzero(which == k)
            tp = truth[ids[k]]
            g, hit = image_to_ground(tp.camera, tp.position, tp.rotation, points[s], height=surface.height, datum_radius_m=DATUM_RADIUS_M)
            out[s] = np.where(hit, fn(g, tp), np.nan)
        return out

    def emission(g: np.ndarray, tp: TruePose) -> np.ndarray:
        n = g / np.linalg.norm(g, axis=1, keepdims=True)
        v = tp.position - g
        return np.degrees(np.arccos(np.clip(np.sum(n * v, 1) / np.linalg.norm(v, axis=1), -1, 1)))

    def slope(g: np.ndarray, tp: TruePose) -> np.ndarray:
        lat, lon, _ = xyz_to_latlon(g, datum_radius_m=DATUM_RADIUS_M)
        dd = 0.01
        h0 = surface.height(lat, lon)
        dy = np.radians(dd) * np.linalg.norm(g, axis=1)
        dx = dy * np.cos(np.radians(lat))
        return np.degrees(np.arctan(np.hypot((surface.height(lat + dd, lon) - h0) / dy,
                                             (surface.height(lat, lon + dd) - h0) / dx)))

    def convergence(points: np.ndarray, which: np.ndarray, other: np.ndarray) -> np.ndarray:
        """Angle (deg) between the two views' rays at the ground point of each measure."""
        out = np.full(which.size, np.nan)
        for k in np.unique(which):
            s = np.flatnonzero(which == k)
            tp = truth[ids[k]]
            g, hit = image_to_ground(tp.camera, tp.position, tp.rotation, points[s], height=surface.height, datum_radius_m=DATUM_RADIUS_M)
            va = tp.position - g
            vb = np.array([truth[ids[j]].position for j in other[s]]) - g
            cos = np.sum(va * vb, 1) / (np.linalg.norm(va, axis=1) * np.linalg.norm(vb, axis=1))
            out[s] = np.where(hit, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), np.nan)
        return out

    def edge(points: np.ndarray, which: np.ndarray) -> np.ndarray:
        w = np.array([cams[ids[k]].samples for k in which])
        h = np.array([cams[ids[k]].lines for k in which])
        return np.minimum.reduce([points[:, 0], points[:, 1], w - 1 - points[:, 0], h - 1 - points[:, 1]])

    # the metric on the surface the renderer draws (roughness octaves below 2 coarser pixels left out)
    e_res = np.full(sel.size, np.nan)
    for k in np.unique(pair):
        s = np.flatnonzero(pair == k)
        res = max(float(ms.catalog.set_index("image_id").loc[x, "pixel_scale_m"]) for x in (rows[k]["ref_id"], rows[k]["match_id"]))

        def h_res(la: Any, lo: Any, res: float = res) -> Any:
            return surface.height(la, lo, res)

        e_res[s] = true_errors(ids, ia[s], ib[s], pa[s], pb[s], truth, h_res, datum_radius_m=DATUM_RADIUS_M)
    d = np.abs(e_res - e)
    print(f"\nsimilar illumination up to 4x: {sel.size} measures, median {np.median(e):.3f} px, p95 "
          f"{np.percentile(e, 95):.3f} px, > 0.5 px {100 * np.mean(e > 0.5):.1f} %; the true error on the surface "
          f"drawn at the coarser image's resolution differs by median {np.nanmedian(d):.4f} px, p95 "
          f"{np.nanpercentile(d, 95):.4f} px")
    mpr = np.array([r["match_px_per_ref_px"] for r in rows])[pair]
    nac = np.array(["NAC" in cams[i].name for i in ids])
    route = np.array([{"guided": 0.0, "ncc": 1.0}.get(r["route"], 2.0) for r in rows])[pair]
    ea = per_image(pa, ia, emission)
    eb = per_image(pb, ib, emission)
    keys = {
        "scale (match px per ref px)": (mpr, [0, 0.6, 0.87, 1.15, 1.7, 2.5, 5], None),
        "cameras (ref-match)": (2.0 * nac[ia] + nac[ib], [0, 1, 2, 3, 4], ["WAC-WAC", "WAC-NAC", "NAC-WAC", "NAC-NAC"]),
        "route": (route, [0, 1, 2], ["guided", "ncc"]),
        "propagated": (m.propagated[sel].astype(float), [0, 1, 2, 3], ["own chain", "anchor of the kept image", "anchor of the warped image"]),
        "refined NCC": (m.score[sel], [-1, 0.7, 0.8, 0.9, 0.95, 1.01], None),
        "distance to the ref image edge px": (edge(pa, ia), [0, 10, 20, 40, 80, 1e9], None),
        "distance to the match image edge px": (edge(pb, ib), [0, 10, 20, 40, 80, 1e9], None),
        "emission ref deg": (ea, [0, 10, 20, 30, 45, 90], None),
        "emission match deg": (eb, [0, 10, 20, 30, 45, 90], None),
        "emission difference deg": (np.abs(ea - eb), [0, 5, 10, 20, 30, 90], None),
        "convergence of the two views deg": (convergence(pa, ia, ib), [0, 10, 20, 30, 45, 90], None),
        "slope deg": (per_image(pa, ia, slope), [0, 5, 10, 20, 30, 90], None),
    }
    n_tail = max(int(np.sum(e > 0.5)), 1)
    for name, (key, bins, labels) in keys.items():
        print(f"\n| {name} | measures | median px | p95 px | > 0.5 px | share of the > 0.5 px |\n|---|---|---|---|---|---|")
        for j, (lo, hi) in enumerate(zip(bins[:-1], bins[1:])):
            s = (key >= lo) & (key < hi)
            if s.sum() == 0:
                continue
            lab = labels[j] if labels else f"{lo:g}-{hi:g}"
            print(f"| {lab} | {s.sum()} | {np.median(e[s]):.3f} | {np.percentile(e[s], 95):.3f} | "
                  f"{100 * np.mean(e[s] > 0.5):.1f} % | {100 * np.sum(e[s] > 0.5) / n_tail:.1f} % |")


def convergence_study() -> None:
    """True error vs the two views' convergence (emission 0 vs 0-38 deg, same sun, same scale).

    A nadir view and one tilted north by ``em`` degrees (same range, WAC 256^2, 1.8 km/pixel,
    sun 45 deg from the east), matched with the defaults. Variants: the mission renderer;
    noise-free; noise-free with a pure Lambert law (no emission dependence of the brightness);
    and that with the relief scaled by 0 and 0.5. Separates what the metric, the noise, the
    photometry and the relief contribute to the error of convergent pairs.
    """
    from mercury_dem.synth.render import RenderSettings
    from mercury_dem.synth.terrain import Surface, SurfaceParams
    from mercury_dem.validate.matching import convergent_views

    class Scaled:
        """The truth surface with its relief scaled by ``k`` (albedo unchanged)."""

        def __init__(self, s: Any, k: float) -> None:
            self.s, self.k, self.radius_m = s, k, s.radius_m

        def sample_grid(self, grid: Any, dirs: Any) -> Any:
            h, a = self.s.sample_grid(grid, dirs)
            return h * self.k, a

        def height_unit(self, u: Any, r: Any = None) -> Any:
            return self.s.height_unit(u, r) * self.k

        def albedo_unit(self, u: Any, r: Any = None) -> Any:
            return self.s.albedo_unit(u, r)

        def height(self, la: Any, lo: Any, r: Any = None) -> Any:
            return self.s.height(la, lo, r) * self.k

    base = Surface(SurfaceParams(seed=42))
    quiet = dict(gain_e_per_dn=1e6, read_noise_dn=0.0)
    variants = {
        "mission renderer": (1.0, RenderSettings()),
        "noise-free": (1.0, RenderSettings(**quiet)),
        "noise-free, Lambert": (1.0, RenderSettings(lambert_weight=1.0, **quiet)),
        "noise-free, Lambert, relief x 0.5": (0.5, RenderSettings(lambert_weight=1.0, **quiet)),
        "noise-free, Lambert, flat": (0.0, RenderSettings(lambert_weight=1.0, **quiet)),
    }
    print("| renderer | emission 0 vs | matches | median px | p95 px | > 0.5 px |\n|---|---|---|---|---|---|")
    for name, (k, rs) in variants.items():
        surface = Scaled(base, k)
        rng = np.random.default_rng(7)
        for em in (0, 10, 20, 30, 38):
            images, geom, truth = convergent_views(surface, (0.0, float(em)), rng, rs)
            m, reps = match_tile(images, geom, [("v0", "v1")], MatchConfig(threads=2), pointing_sigma_urad=450.0)
            pa = np.stack([m.sample_a, m.line_a], -1)
            pb = np.stack([m.sample_b, m.line_b], -1)
            e = true_errors(m.image_ids, m.image_a, m.image_b, pa, pb, truth, surface.height, datum_radius_m=DATUM_RADIUS_M)
            e = e[np.isfinite(e)]
            if e.size:
                print(f"| {name} | {em} | {e.size} | {np.median(e):.3f} | {np.percentile(e, 95):.3f} | "
                      f"{100 * np.mean(e > 0.5):.1f} % |")
            else:
                print(f"| {name} | {em} | 0 | - | - | - |")


def tracks_study(mission_path: str, run_dir: str, config: MatchConfig | None = None, verbose: bool = True,
                 tracks: bool = True) -> dict[str, Any]:
    """Every tile of a mission matched and built into a network as the pipeline's ``run_tile`` does.

    Reads the plan of ``run_dir`` (``mercury-dem match MISSION --out RUN`` writes it; the
    tile networks there are not used), matches every tile with ``config`` and builds its
    network with the default network settings; returns (and prints) the points by number
    of rays, and the measures' true errors against their point's first measure
    (:func:`mercury_dem.validate.matching.network_true_errors`).
    """
    from mercury_dem.config import Config
    from mercury_dem.io.run_store import RunStore
    from mercury_dem.mission import open_mission
    from mercury_dem.network.build import build_network
    from mercury_dem.pipeline.stages import tile_pairs
    from mercury_dem.validate.matching import network_true_errors, rays_histogram

    ms = open_mission(mission_path)
    cfg = Config()
    mcfg = config or cfg.match
    store = RunStore(run_dir)
    images, pairs, info = store.read_plan()
    tiles = sorted(set(images.loc[images["excluded_reason"] == "", "tile_id"].tolist()))
    surface = ms.need_truth().surface()
    rays_all: list[np.ndarray] = []
    errs: list[np.ndarray] = []
    pair_err: list[np.ndarray] = []
    pair_across: list[np.ndarray] = []
    n_pairs = n_matched = n_match_rows = 0
    t_match = 0.0
    build_stats: dict[str, int] = {}
    pair_index: list[np.ndarray] = []
    all_rows: list[dict[str, Any]] = []
    overlaps: list[float] = []
    for t in tiles:
        pl = tile_pairs(images, pairs, t)
        if not pl:
            continue
        ref_ids = images.loc[(images["tile_id"] == t) & (images["excluded_reason"] == ""), "image_id"].tolist()
        involved = sorted({x for p in pl for x in p} | set(ref_ids))
        pix = {i: ms.read_image(i) for i in involved}
        cams = [ms.camera(i) for i in involved]
        poses = [ms.a_priori_pose(i) for i in involved]
        geom = {i: ImageGeometry.of(c, p, r, ms.sun_position(i), datum_radius_m=DATUM_RADIUS_M) for i, c, (p, r) in zip(involved, cams, poses)}
        truth = {i: TruePose(c, *ms.need_truth().true_pose(i)) for i, c in zip(involved, cams)}
        t0 = time.perf_counter()
        m, reps = match_tile(pix, geom, pl, mcfg, tracks=tracks, pointing_sigma_urad=450.0)
        t_match += time.perf_counter() - t0
        n_pairs += len(pl)
        n_matched += sum(r.status == "matched" for r in reps)
        n_match_rows += len(m)
        pa = np.stack([m.sample_a, m.line_a], -1)
        pb = np.stack([m.sample_b, m.line_b], -1)
        pair_err.append(true_errors(m.image_ids, m.image_a, m.image_b, pa, pb, truth, surface.height, datum_radius_m=DATUM_RADIUS_M))
        pair_across.append(true_error_components(m.image_ids, m.image_a, m.image_b, pa, pb, truth, surface.height, datum_radius_m=DATUM_RADIUS_M)[1])
        pair_index.append(m.pair + len(all_rows))
        all_rows.extend(r.as_row() for r in reps)
        overlaps.extend(true_overlap(truth[a], truth[b], surface.height, datum_radius_m=DATUM_RADIUS_M) if a in truth and b in truth else 0.0
                        for a, b in pl)
        built = build_network(
            involved, m, cams, np.array([p for p, _ in poses]), np.array([r for _, r in poses]),
            tolerance_px=cfg.network.merge_tolerance_px, sigma_px=cfg.network.measure_sigma_px,
         datum_radius_m=DATUM_RADIUS_M)
        net = built.network
        for key in ("n_conflicts", "n_conflict_observations", "n_links_pruned", "n_observations"):
            build_stats[key] = build_stats.get(key, 0) + getattr(built.stats, key)
        if net.n_measures == 0:
            continue
        rays_all.append(np.bincount(net.measure_point, minlength=net.n_points))
        errs.append(network_true_errors(involved, net.measure_point, net.measure_image,
                                        np.stack([net.sample, net.line], -1), truth, surface.height, datum_radius_m=DATUM_RADIUS_M))
    rays = np.concatenate(rays_all) if rays_all else np.zeros(0, np.int64)
    hist = rays_histogram(np.repeat(np.arange(rays.size), rays))
    e = np.concatenate(errs) if errs else np.zeros(0)
    e = e[np.isfinite(e) & (e > 0)]
    pe = np.concatenate(pair_err) if pair_err else np.zeros(0)
    classes = summarize(pe, np.concatenate(pair_index) if pair_index else np.zeros(0, np.int64), all_rows, overlaps)
    pe = pe[np.isfinite(pe)]
    out = {
        "tiles": len(tiles), "pairs": n_pairs, "pairs_matched": n_matched, "matches": n_match_rows,
        "match_seconds": t_match, "points": int(rays.size), "measures": int(rays.sum()),
        "mean_rays": float(rays.mean()) if rays.size else float("nan"),
        "share_3plus": float(np.mean(rays >= 3)) if rays.size else float("nan"),
        "rays": hist,
        "pair_median_px": float(np.median(pe)), "pair_p95_px": float(np.percentile(pe, 95)),
        "pair_outliers": float(np.mean(pe > 2.0)),
        "net_median_px": float(np.median(e)), "net_p95_px": float(np.percentile(e, 95)),
        "net_outliers": float(np.mean(e > 2.0)),
        "build": build_stats,
        # the raw pair figures, for studies that group the pairs otherwise (bench_seeds.py)
        "pair_errors": np.concatenate(pair_err) if pair_err else np.zeros(0),
        "pair_errors_across": np.concatenate(pair_across) if pair_across else np.zeros(0),
        "pair_of_error": np.concatenate(pair_index) if pair_index else np.zeros(0, np.int64),
        "pair_rows": all_rows, "pair_overlaps": overlaps,
    }
    if verbose:
        print(f"tracks={'on' if tracks else 'off'}: mission {mission_path}: {out['tiles']} tiles, {n_pairs} pairs, {n_matched} matched, "
              f"{n_match_rows} matches, matching {t_match:.1f} s")
        print(f"points {out['points']}, measures {out['measures']}, mean rays {out['mean_rays']:.2f}, "
              f"points with >= 3 rays {100 * out['share_3plus']:.1f} %")
        print("rays per point: " + ", ".join(f"{k}: {v}" for k, v in hist.items()))
        print(f"pair matches true error: median {out['pair_median_px']:.3f} px, p95 {out['pair_p95_px']:.3f} px, "
              f"> 2 px {100 * out['pair_outliers']:.2f} %")
        print(f"network measures vs their point's first measure: median {out['net_median_px']:.3f} px, "
              f"p95 {out['net_p95_px']:.3f} px, > 2 px {100 * out['net_outliers']:.2f} %")
        print("build_network: " + ", ".join(f"{k} {v}" for k, v in build_stats.items()))
        print("\npair matches by class (every pair of every tile; a pair of two tiles' images is matched in both):\n")
        print(format_summary(classes))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--accuracy", action="store_true", help="run the accuracy study instead of the speed benchmark")
    p.add_argument("--mission", help="run the accuracy study on every overlapping pair of this mission store")
    p.add_argument("--max-pairs", type=int, default=0, help="with --mission: a seeded random sample of the pairs")
    p.add_argument("--breakdown", action="store_true",
                   help="with --mission: where the similar class's measures > 0.5 px come from")
    p.add_argument("--convergence", action="store_true",
                   help="true error vs the views' convergence, with the renderer's noise, photometry and relief varied")
    p.add_argument("--sizes", default="512,1024")
    p.add_argument("--images", type=int, default=4)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--variants", default=",".join(SPEED_VARIANTS),
                   help="speed: the variants of ours run beside the defaults, comma-separated from "
                        f"{', '.join(SPEED_VARIANTS)} (empty: none)")
    p.add_argument("--tracks", nargs=2, metavar=("MISSION", "RUN"),
                   help="rays per point and true errors of every tile network (RUN holds the plan)")
    a = p.parse_args()
    if a.tracks:
        tracks_study(*a.tracks, tracks=False)
        print()
        tracks_study(*a.tracks, tracks=True)
    elif a.convergence:
        convergence_study()
    elif a.mission:
        mission_accuracy(a.mission, a.max_pairs, breakdown=a.breakdown)
    elif a.accuracy:
        accuracy()
    else:
        variants = tuple(v for v in a.variants.split(",") if v)
        bad = [v for v in variants if v not in SPEED_VARIANTS]
        if bad:
            p.error(f"--variants: unknown {', '.join(bad)}; choose from {', '.join(SPEED_VARIANTS)}")
        speed([int(s) for s in a.sizes.split(",")], a.images, a.repeats, variants)


if __name__ == "__main__":
    main()
