"""Adjust a stored network by point blocks, in this process or on a Dask cluster (``mercury-dem adjust-network``).

The stage runner of :mod:`mercury_dem.adjust.blocked`: reads the store's image
geometry, makes the engine (one in-process shard, or one actor per Dask worker that
reads its own blocks), runs the loop and returns a JSON-able summary: sizes,
iterations, seconds (per iteration too), the peak memory of every process, and, when
the store has a truth, the pointing error in pixels and the share of gross outliers
rejected. The adjusted network is not written back yet (see docs/design/adjust.md).
"""

from __future__ import annotations

import resource
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from mercury_dem.adjust.blocked import (
    BlockShard,
    SyncEngine,
    blocked_levenberg_marquardt,
    options_from_config,
    setup_from_config,
)
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.synthetic_network_store import BlockedNetwork, StoredBlocks
from mercury_dem.validate.synthetic_network import pointing_errors

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient, DaskClient


def _peak_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def adjust_blocked_store(store: str | Path, config: AdjustConfig, client: ComputeClient | None = None, *,
                         pointing_sigma_urad: float) -> dict[str, Any]:
    """Adjust the point-blocked network store at ``store`` (``mercury-dem synth-network``'s) by blocks and return
    the run's record; ``client`` None runs in this process, else on its Dask workers. ``pointing_sigma_urad``: how
    wrong the stored a-priori rotations may be, per axis (1 sigma, µrad).

    Not to be confused with :func:`mercury_dem.adjust.unit.adjust_unit_network`, which adjusts one merged unit's
    in-memory network (the cascade, adjust-isis). Raises :class:`~mercury_dem.exceptions.StoreError` for a store
    that lacks the image geometry or point blocks, or is damaged.
    """
    t0 = time.perf_counter()
    net = BlockedNetwork(store)
    im = net.images
    setup = setup_from_config(im.cameras, im.image_camera, im.positions, im.rotations, config,
                              pointing_sigma_urad=pointing_sigma_urad, float32=config.blocked_float32)
    opt = options_from_config(config)
    engine, where = _engine(net, setup, opt, config, client)
    load_s = time.perf_counter() - t0
    res = blocked_levenberg_marquardt(engine, setup, opt)
    summaries = engine.call("summary")
    shard_rss = [int(x) for x in engine.call("peak_rss_bytes")]
    shard_busy = [float(x) for x in engine.call("busy")]
    client_rss = _peak_rss()
    acc = np.sum([s["accepted_per_image"] for s in summaries], axis=0)
    sq = sum(s["sum_sq_px"] for s in summaries)
    n_px = sum(s["n_px"] for s in summaries)
    its = [e["seconds"] for e in res.log]
    record: dict[str, Any] = {
        "store": str(store), "engine": where, "measures": res.measures, "points": res.points, "images": net.n_images,
        "blocks": net.n_blocks, "float32": bool(config.blocked_float32), "recompute_w": bool(config.blocked_recompute_w), "iterations": res.iterations, "converged": res.converged, "reason": res.reason,
        "seconds": round(time.perf_counter() - t0, 3), "load_seconds": round(load_s, 3),
        "setup_seconds": round(res.setup_seconds, 3),
        "seconds_per_iteration": [round(x, 3) for x in its],
        "linear_method": res.linear_method, "linear_iterations": [e["linear_iterations"] for e in res.log],
        "sigma0": res.sigma0, "rms_px": float(np.sqrt(sq / n_px)) if n_px else float("nan"),
        "rejected": res.rejected, "underdetermined_points": int(sum(s["underdetermined_points"] for s in summaries)),
        "weak_images": int(np.sum(acc < config.min_image_measures)),
        "peak_memory_bytes": max([client_rss, *shard_rss]),
        "peak_memory_bytes_client": client_rss, "peak_memory_bytes_shards": shard_rss,
        # each shard's seconds computing in its blocks (load excluded): the rest of an iteration is the
        # client's (sums, the camera solve) and the messages
        "shard_busy_seconds": [round(x, 3) for x in shard_busy],
    }
    true_rot = net.truth_images()
    if true_rot is not None:
        record["truth"] = _truth_record(im, res.rotations, true_rot, acc, summaries)
    record["log"] = [{k: (round(v, 6) if isinstance(v, float) else v) for k, v in e.items()} for e in res.log]
    return record


def _engine(net: BlockedNetwork, setup: Any, opt: Any, config: AdjustConfig,
            client: ComputeClient | None) -> tuple[Any, str]:
    """The blocks' engine: one in-process shard (``client`` None or in-process), else one actor per Dask worker
    reading its own blocks; and how to name it in the record.
    """
    from mercury_dem.compute import runs_in_process

    if runs_in_process(client):
        return SyncEngine([BlockShard(StoredBlocks(str(net.root), tuple(range(net.n_blocks))), setup, opt)]), "sync"
    from mercury_dem.pipeline.shard_engine import DaskShardEngine

    engine = DaskShardEngine(cast("DaskClient", client), str(net.root), net.n_blocks, setup, opt,
                             config.blocked_tree_min_workers)
    return engine, f"dask ({len(engine.actors)} workers)"


def _truth_record(im: Any, rotations: Any, true_rot: Any, acc: Any, summaries: list[dict[str, Any]]) -> dict[str, Any]:
    """The adjusted pointing against the store's truth in pixels (all images, images of 30 measures or more,
    a priori), and the share of the gross outliers and of the good measures rejected.
    """
    raw, _, _ = pointing_errors(rotations, true_rot)
    ifov = np.array([im.cameras[k].ifov_rad for k in im.image_camera])
    bore = np.linalg.norm(raw[:, :2], axis=1) / ifov
    sel = acc >= 30
    raw0, _, _ = pointing_errors(im.rotations, true_rot)
    n_out = sum(s["outliers"] for s in summaries)
    n_good = sum(s["good"] for s in summaries)
    perr = np.concatenate([s["point_error_m"] for s in summaries])
    return {
        "pointing_error_px_rms": float(np.sqrt(np.mean(bore**2))),
        "pointing_error_px_rms_images_ge30": float(np.sqrt(np.mean(bore[sel] ** 2))) if sel.any() else float("nan"),
        "apriori_pointing_error_px_rms": float(np.sqrt(np.mean((np.linalg.norm(raw0[:, :2], axis=1) / ifov) ** 2))),
        "outliers": n_out,
        "outliers_rejected_share": sum(s["outliers_rejected"] for s in summaries) / n_out if n_out else float("nan"),
        "good_rejected_share": sum(s["good_rejected"] for s in summaries) / n_good if n_good else float("nan"),
        "point_error_m_median": float(np.median(perr)) if perr.size else float("nan"),
        "point_error_m_p90": float(np.percentile(perr, 90)) if perr.size else float("nan"),
    }
