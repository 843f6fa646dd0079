"""Benchmark of the streamed merge (issue 33 item 1): a unit merged from its children's stores by parts and adjusted
from the merged store's point blocks, never holding the merged network.

Usage::

    flock /tmp/mercury_bench.lock .venv/bin/python -u workflows/benchmarks/bench_streamed_merge.py \
        --measures 1e6 [--workers 2] [--compare] [--json] [--dir /tmp/streamed_bench] [--keep]

1. children: a synthetic network of ``--measures`` measures (``write_synthetic_network``, seed ``--seed``) cut
   into two overlapping children ("two hemispheres' stores", ``split_synthetic_network``: they share one point
   block on each side of the cut, jittered 0.05 px and 1 m, so the merge joins and averages them);
2. the unit, in its own process (``--unit``): ``stream_merge`` of the two stores (its parts on the workers when
   ``--workers`` > 0) into the merged store, then the blocked adjustment over that store's point blocks (one
   ``BlockShard`` actor per worker reading its blocks itself; in the unit's process with ``--workers 0``);
3. with ``--compare``, today's path in another process: ``merge_networks`` in memory, ``problem_from_network``,
   ``blocked_bundle_adjust`` (in process), and the largest difference of the adjusted rotations.

``--through-unit``: the unit as a run's hemisphere/global unit of ``adjust.streamed_merge_levels`` does it
(``pipeline/stages._adjust_unit_streamed``'s library calls): ``stream_merge``, then
``io.adjusted_network_store.adjust_stored_unit`` (its images with measures, the point priors on the datum, the
blocks read by the shards through the unit's transform; on the workers by ``DaskShardEngine.from_blocks`` with
the stored blocks when ``--workers`` > 0) and the adjusted network written back by blocks; ``--compare`` then
runs the in-memory unit (``merge_networks``, ``drop_unused_images``, ``adjust_unit_network`` over point blocks,
``write_network``) and compares the poses and every column of the two written networks.

Prints (``--json``: one JSON line) the unit process's peak RSS, each worker's, the times, the solution's checksum
(sha256 of the adjusted rotations' bytes) and, with ``--compare``, the in-memory path's peak and the difference;
appends a ``streamed_merge`` record (harness).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import resource
import shutil
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from harness import append_record, measure

CFG_KW: dict[str, Any] = {}
POINTING_SIGMA_URAD = 450.0  # the synthetic networks' injected a-priori pointing error (bigadj.yaml)


def _peak() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _checksum(rot: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(rot, np.float64).tobytes()).hexdigest()[:16]


def _ordered_map(client: Any, window: int) -> Any:
    """``map_parts`` on a Dask client: at most ``window`` parts in flight, results in order."""
    def run(fn: Any, items: list[Any]) -> Any:
        pending: list[Any] = []
        for it in items:
            pending.append(client.submit(fn, it, pure=False))
            if len(pending) >= window:
                f = pending.pop(0)
                yield f.result()
                f.release()
        for f in pending:
            yield f.result()
            f.release()
    return run


def _config(args: argparse.Namespace, extra: dict[str, Any] | None = None) -> Any:
    from mercury_dem.config.adjust import AdjustConfig

    kw: dict[str, Any] = {**CFG_KW, **(extra or {})}
    if args.max_iterations:
        kw["max_iterations"] = args.max_iterations
    return AdjustConfig(**kw)


def _worker_peak() -> int:
    return _peak()


UNIT_CFG_KW: dict[str, Any] = {"blocked_min_measures": 0, "point_prior_center": "datum",
                               "point_prior_recentre_levels": (), "altimetry_levels": ()}


def _unit_inputs(root: Path, ids: list[str]) -> tuple[Any, ...]:
    """Cameras, positions, rotations of ``ids`` (from the source network's geometry) and the datum radius."""
    from mercury_dem.io.synthetic_network_store import BlockedNetwork

    src = BlockedNetwork(root / "src")
    index = {str(i): k for k, i in enumerate(src.store.image_ids)}
    k = np.array([index[i] for i in ids], np.int64)
    im = src.images
    radius = float(np.median(np.linalg.norm(src.store.column_rows("apriori_xyz", 0, min(src.n_points, 5000)), axis=1)))
    return [im.cameras[c] for c in im.image_camera[k]], im.positions[k], im.rotations[k], radius


def _table(root: Path) -> Any:
    from mercury_dem.io.synthetic_network_store import BlockedNetwork
    from mercury_dem.network.blocks import ImageTable

    src = BlockedNetwork(root / "src")
    index = {str(i): k for k, i in enumerate(src.store.image_ids)}
    im = src.images

    def table(ids: Any) -> Any:
        k = np.array([index[str(i)] for i in ids], np.int64)
        return ImageTable(im.cameras, im.image_camera[k], im.positions[k], im.rotations[k])
    return table


def through_unit(args: argparse.Namespace) -> None:
    """The unit's process as a streamed run unit: merge by parts, adjust from the store, write back by blocks."""
    import contextlib

    from mercury_dem.compute import open_client
    from mercury_dem.io.adjusted_network_store import adjust_stored_unit, stored_image_ids
    from mercury_dem.io.merged_network_store import stored_singular_parts, stream_merge

    root = Path(args.dir)
    cfg = _config(args, UNIT_CFG_KW)
    out = root / "merged"
    shutil.rmtree(out, ignore_errors=True)
    shutil.rmtree(root / "adjusted_streamed.zarr", ignore_errors=True)
    rec: dict[str, Any] = {}
    with open_client(workers=args.workers) as client:
        t0 = time.perf_counter()
        mapper = None if args.workers <= 0 else _ordered_map(client, args.workers + 1)
        summary = stream_merge("hemisphere 0", [("a", root / "a"), ("b", root / "b")], out, _table(root),
                               block_points=cfg.blocked_block_points, part_measures=int(args.part_measures),
                               map_parts=mapper)
        rec["merge_seconds"] = round(time.perf_counter() - t0, 2)
        rec["unit_peak_rss_bytes_after_merge"] = _peak()
        t0 = time.perf_counter()
        unused = set(stored_singular_parts(out / "network")["images_without_measures"])
        ids = [i for i in stored_image_ids(out).tolist() if i not in unused]
        cams, pos, rot, radius = _unit_inputs(root, ids)
        factory = None
        if args.workers > 0:
            from mercury_dem.pipeline.shard_engine import DaskShardEngine

            @contextlib.contextmanager
            def factory(blocks: Any, setup: Any, opt: Any) -> Any:
                engine = DaskShardEngine.from_blocks(client, blocks, setup, opt)
                try:
                    yield engine
                    rec["worker_peak_rss_bytes"] = [int(x) for x in engine.call("peak_rss_bytes")]
                finally:
                    engine.close()
        adj = adjust_stored_unit(out, root / "adjusted_streamed.zarr", ids, cams, pos, rot, cfg,
                                 pointing_sigma_urad=POINTING_SIGMA_URAD, datum_radius_m=radius, engine_factory=factory)
        rec["adjust_seconds"] = round(time.perf_counter() - t0, 2)
    np.save(root / "streamed_rotations.npy", adj.rotations)
    s = adj.summary
    rec.update({"merge": summary.to_dict(), "measures": s["measures"], "points": s["points"], "images": s["images"],
                "blocks": summary.n_blocks, "iterations": s["iterations"], "converged": s["converged"],
                "rejected": s["rejected"], "sigma0": s["sigma0"], "engine": s["blocked"]["engine"],
                "checksum": _checksum(adj.rotations), "unit_peak_rss_bytes": _peak()})
    rec.setdefault("worker_peak_rss_bytes", [])
    print(json.dumps(rec))


def unit_in_memory(args: argparse.Namespace) -> None:
    """The in-memory unit: ``merge_networks``, ``adjust_unit_network`` over point blocks, ``write_network``."""
    from mercury_dem.adjust.unit import adjust_unit_network
    from mercury_dem.io.network_store import read_network, write_network
    from mercury_dem.network.merge import merge_networks

    root = Path(args.dir)
    cfg = _config(args, UNIT_CFG_KW)
    t0 = time.perf_counter()
    merged = merge_networks([read_network(root / "a"), read_network(root / "b")]).network.drop_unused_images()
    ids = [str(i) for i in merged.image_ids]
    cams, pos, rot, radius = _unit_inputs(root, ids)
    adj = adjust_unit_network(merged, cams, pos, rot, cfg, pointing_sigma_urad=POINTING_SIGMA_URAD,
                              datum_radius_m=radius, level="hemisphere")
    del merged
    shutil.rmtree(root / "adjusted_in_memory.zarr", ignore_errors=True)
    write_network(adj.network, root / "adjusted_in_memory.zarr")
    np.save(root / "inmemory_rotations.npy", adj.rotations)
    print(json.dumps({"seconds": round(time.perf_counter() - t0, 2), "peak_rss_bytes": _peak(),
                      "checksum": _checksum(adj.rotations), "iterations": adj.summary["iterations"]}))


def _network_differences(a: Path, b: Path) -> dict[str, Any]:
    """The two written networks compared column by column: the floating columns' largest difference (NaN where
    both are NaN), the others equal or not (the shards' sums in another order move the last bits only).
    """
    from mercury_dem.io.network_store import read_network
    from mercury_dem.network.model import MEASURE_COLUMNS, POINT_COLUMNS

    x, y = read_network(a), read_network(b)
    out: dict[str, Any] = {}
    for k in ("image_ids", "point_ids", *POINT_COLUMNS, *MEASURE_COLUMNS):
        u, v = getattr(x, k), getattr(y, k)
        if u.dtype.kind != "f" or u.shape != v.shape:
            out[k] = bool(u.shape == v.shape and np.array_equal(u, v))
            continue
        same_nan = bool(np.array_equal(np.isnan(u), np.isnan(v)))
        fin = np.isfinite(u) & np.isfinite(v)
        out[k] = float(np.abs(u[fin] - v[fin]).max()) if same_nan and fin.any() else (0.0 if same_nan else False)
    return out


def unit(args: argparse.Namespace) -> None:
    """The unit's process: streamed merge, then the blocked adjustment over the merged store."""
    from mercury_dem.adjust.blocked import (
        BlockShard,
        SyncEngine,
        blocked_levenberg_marquardt,
        options_from_config,
        setup_from_config,
    )
    from mercury_dem.compute import open_client
    from mercury_dem.io.merged_network_store import stream_merge
    from mercury_dem.io.synthetic_network_store import BlockedNetwork, StoredBlocks

    root = Path(args.dir)
    cfg = _config(args)
    src_images = BlockedNetwork(root / "src").images
    out = root / "merged"
    shutil.rmtree(out, ignore_errors=True)
    rec: dict[str, Any] = {}
    with open_client(workers=args.workers) as client:
        t0 = time.perf_counter()
        mapper = None if args.workers <= 0 else _ordered_map(client, args.workers + 1)
        summary = stream_merge("hemisphere 0", [("a", root / "a"), ("b", root / "b")], out, lambda ids: src_images,
                               block_points=cfg.blocked_block_points, part_measures=int(args.part_measures),
                               map_parts=mapper)
        rec["merge_seconds"] = round(time.perf_counter() - t0, 2)
        rec["unit_peak_rss_bytes_after_merge"] = _peak()
        if args.merge_only:
            rec.update({"merge": summary.to_dict(), "measures": summary.stats.n_measures, "unit_peak_rss_bytes": _peak(),
                        "worker_peak_rss_bytes": client.run(_worker_peak) if args.workers > 0 else {}})
            rec["worker_peak_rss_bytes"] = list(rec["worker_peak_rss_bytes"].values())
            print(json.dumps(rec))
            return
        t0 = time.perf_counter()
        net = BlockedNetwork(out)
        im = net.images
        setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, cfg,
                                  pointing_sigma_urad=POINTING_SIGMA_URAD, float32=cfg.blocked_float32)
        opt = options_from_config(cfg, summary.median_sigma_px)
        if args.workers <= 0:
            engine: Any = SyncEngine([BlockShard(StoredBlocks(str(net.root), tuple(range(net.n_blocks))), setup, opt)])
        else:
            from mercury_dem.pipeline.shard_engine import DaskShardEngine

            engine = DaskShardEngine(client, str(net.root), net.n_blocks, setup, opt)
        res = blocked_levenberg_marquardt(engine, setup, opt)
        workers_rss = [int(x) for x in engine.call("peak_rss_bytes")]
        rec["adjust_seconds"] = round(time.perf_counter() - t0, 2)
    np.save(root / "streamed_rotations.npy", res.rotations)
    rec.update({
        "merge": summary.to_dict(), "measures": res.measures, "points": res.points, "images": net.n_images,
        "blocks": net.n_blocks, "iterations": res.iterations, "converged": res.converged, "rejected": res.rejected,
        "sigma0": res.sigma0, "checksum": _checksum(res.rotations),
        "unit_peak_rss_bytes": _peak(), "worker_peak_rss_bytes": workers_rss if args.workers > 0 else [],
    })
    print(json.dumps(rec))


def in_memory(args: argparse.Namespace) -> None:
    """Today's path: merge in memory, the problem, ``blocked_bundle_adjust`` in this process."""
    from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust
    from mercury_dem.adjust.network import problem_from_network
    from mercury_dem.io.network_store import read_network
    from mercury_dem.io.synthetic_network_store import BlockedNetwork
    from mercury_dem.network.merge import merge_networks

    root = Path(args.dir)
    cfg = _config(args)
    im = BlockedNetwork(root / "src").images
    t0 = time.perf_counter()
    merged = merge_networks([read_network(root / "a"), read_network(root / "b")]).network
    n = merged.n_images
    problem, _ = problem_from_network(merged, [im.cameras[k] for k in im.image_camera][:n], im.positions[:n],
                                      im.rotations[:n], cfg, pointing_sigma_urad=POINTING_SIGMA_URAD)
    del merged
    res = blocked_bundle_adjust(problem, cfg, block_points=cfg.blocked_block_points)
    np.save(root / "inmemory_rotations.npy", res.rotations)
    print(json.dumps({"seconds": round(time.perf_counter() - t0, 2), "peak_rss_bytes": _peak(),
                      "checksum": _checksum(res.rotations), "iterations": res.iterations}))


def main() -> None:
    """Build the children (or reuse them), run the unit in its own process, print and record the figures."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--measures", type=float, default=1e6)
    ap.add_argument("--workers", type=int, default=0, help="LocalCluster workers (0: all in the unit's process)")
    ap.add_argument("--part-measures", type=float, default=5e5, help="measures per part of the join and merge")
    ap.add_argument("--dir", default="/tmp/streamed_bench")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--compare", action="store_true", help="also run the in-memory merge and compare")
    ap.add_argument("--keep", action="store_true", help="reuse the children of an earlier run of this size")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--max-iterations", type=int, default=0, help="cap the adjustment's iterations (0: the default)")
    ap.add_argument("--merge-only", action="store_true", help="the streamed merge only (no adjustment)")
    ap.add_argument("--through-unit", action="store_true",
                    help="the unit as a streamed run unit: adjust_stored_unit, the network written back by blocks")
    ap.add_argument("--unit", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--in-memory", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.unit:
        return through_unit(args) if args.through_unit else unit(args)
    if args.in_memory:
        return unit_in_memory(args) if args.through_unit else in_memory(args)
    from mercury_dem.io.synthetic_network_store import split_synthetic_network, write_synthetic_network
    from mercury_dem.network.synthetic import SyntheticSpec

    root = Path(args.dir)
    stamp = root / "children.json"
    want = {"measures": args.measures, "seed": args.seed}
    if not (args.keep and stamp.exists() and json.loads(stamp.read_text()) == want):
        shutil.rmtree(root, ignore_errors=True)
        root.mkdir(parents=True)
        t0 = time.perf_counter()
        write_synthetic_network(SyntheticSpec(n_measures=int(args.measures), seed=args.seed), root / "src")
        kids = split_synthetic_network(root / "src", [root / "a", root / "b"], overlap_blocks=1, seed=args.seed + 1)
        stamp.write_text(json.dumps(want))
        print(json.dumps({"children_measures": kids, "seconds": round(time.perf_counter() - t0, 1)}), file=sys.stderr)
    me = [sys.executable, str(Path(__file__).resolve()), "--dir", str(root), "--measures", str(args.measures),
          "--workers", str(args.workers), "--part-measures", str(args.part_measures),
          "--max-iterations", str(args.max_iterations), *(["--merge-only"] if args.merge_only else []),
          *(["--through-unit"] if args.through_unit else [])]
    m = measure([*me, "--unit"])
    rec = json.loads(m.stdout.strip().splitlines()[-1])
    rec["wall_seconds"] = round(m.wall_s, 2)
    rec["unit_process_peak_rss_bytes_harness"] = m.peak_rss_bytes
    if args.compare:
        c = measure([*me, "--in-memory"])
        ref = json.loads(c.stdout.strip().splitlines()[-1])
        diff = float(np.abs(np.load(root / "streamed_rotations.npy") - np.load(root / "inmemory_rotations.npy")).max())
        rec["in_memory"] = {**ref, "process_peak_rss_bytes_harness": c.peak_rss_bytes}
        rec["max_rotation_difference"] = diff
        if args.through_unit:
            rec["network_differences"] = _network_differences(root / "adjusted_streamed.zarr",
                                                              root / "adjusted_in_memory.zarr")
    n = rec["measures"]
    rec["unit_bytes_per_measure"] = round(rec["unit_peak_rss_bytes"] / n, 1)
    if rec["worker_peak_rss_bytes"]:
        rec["worker_bytes_per_measure"] = round(sum(rec["worker_peak_rss_bytes"]) / n, 1)
    append_record("streamed_merge", {"measures": args.measures, "workers": args.workers, "seed": args.seed,
                                     "part_measures": args.part_measures, "compare": args.compare,
                                     "max_iterations": args.max_iterations, "merge_only": args.merge_only,
                                     "through_unit": args.through_unit}, rec)
    if args.json:
        print(json.dumps(rec))
    else:
        for k, v in rec.items():
            print(f"{k}: {v}")
    if not args.keep:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
