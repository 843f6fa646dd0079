"""The dense stereo stage of a run (issue 31; docs/design/dense.md): pairs, chips per tile, the cloud, the dense DEM.

After the DEM stage (the sparse ``dem.zarr`` and, where the mission has altimetry, the registration):

1. **Pairs**, once, in the driver: the overlap graph's edges among the images the global adjustment controlled,
   with their adjusted geometry (``global/0/solution.parquet``), through
   :func:`mercury_dem.dense.pairs.select_stereo_pairs`; each selected pair belongs to the tile of its left image
   (the plan's tile, as in matching), capped per tile (``dense.max_pairs_per_tile``); every candidate and the
   reason of each rejection go into the report.
2. **One Dask task per tile** (:func:`mercury_dem.pipeline.dense_tile.run_dense_tile`): the tile's pairs in rank order, each left image cut into
   chips (:func:`mercury_dem.dense.chip.chip_grid`), each chip through
   :func:`mercury_dem.dense.chip.dense_chip` about the sparse DEM (``surface_height``), with the tile's height
   margin (``dense.height_margin_factor`` x the robust scatter of the tile's tie points about the sparse DEM,
   at least ``dense.min_height_margin_m``). A chip or pair that fails is recorded with its reason and its kind
   (:class:`mercury_dem.dense.failures.DenseFailure`; a failed tile: :class:`~mercury_dem.pipeline.results.UnitFailure`)
   and the others go on; the report counts both by kind. Memory per task: the tile's images (float32) + one chip's SGM cost volumes (stated,
   ``memory_bytes``).
3. **The cloud**: ``dense.zarr/tile_XXX/`` (columnar: ``lat``, ``lon``, ``height``, ``sigma_h_m``, ``miss_m``,
   ``angle_deg``, ``score``, ``pair`` (index into ``dense.zarr``'s ``pairs`` attribute), ``left_px``,
   ``right_px``, ``sigma_match_px`` (the matcher's own disparity sigma) and ``m_per_px`` (height per pixel of
   disparity), from which ``sigma_h_m`` is made), written atomically by its task, marked ``complete`` in its attributes with the tile's summary;
   a resumed run skips complete tiles.
4. **The dense DEM** ``dem_dense.zarr``: the cloud gridded by the DEM stage's gridding (``dem.method``, ...)
   at ``dense.grid_pixel_factor`` x the pairs' median pixel scale; where no dense point reaches, the sparse DEM
   resampled (bilinear) as fallback; layers ``elevation``, ``precision_m``, ``source`` (0 none, 1 dense,
   2 sparse fallback) and the gridding's own (:mod:`mercury_dem.pipeline.dense_dem`); its products
   (:mod:`mercury_dem.pipeline.dense_products`) and, with a truth, its validation.

Stages never call each other: this one reads what the earlier ones committed.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TextIO

import numpy as np

from mercury_dem.compute.failures import lost_to_the_cluster, raise_if_run_stopping
from mercury_dem.config import Config
from mercury_dem.exceptions import MercuryDemError
from mercury_dem.io.dense_store import CLOUD_COLUMNS, read_cloud, set_pair_records, tile_complete, tile_group_name
from mercury_dem.io.run_store import DEM_DENSE_FILE, DENSE_FILE, RunStore
from mercury_dem.pipeline.dense_inputs import (
    SparseSurface,
    adjusted_geometry,
    criteria_of,
    matcher_of,
    open_sparse_surface,
)
from mercury_dem.pipeline.dense_tile import run_dense_tile, tile_task
from mercury_dem.pipeline.results import UnitFailure

if TYPE_CHECKING:
    from mercury_dem.compute.client import ComputeClient

__all__ = ["CLOUD_COLUMNS", "SparseSurface", "adjusted_geometry", "criteria_of", "matcher_of", "open_sparse_surface",
           "read_cloud", "run_dense_stage", "run_dense_tile", "tile_complete", "tile_group_name"]

#: Per-tile counts summed into the stage's block.
_TILE_COUNTS = ("chips", "chips_failed", "chips_capped", "chip_parts", "chip_parts_failed", "points",
                "interior_pixels")


@dataclass(frozen=True)
class PairSelection:
    """The stage's pairs: every candidate's row, the selected ones' indices by tile and their records."""

    rows: list[Any]
    per_tile: dict[int, list[int]]
    pair_index: dict[int, int]
    records: list[dict[str, Any]]

    def tile_pairs(self, tile: int) -> list[tuple[int, str, str]]:
        """(pair index, left, right) of a tile's selected pairs, in rank order."""
        return [(self.pair_index[i], self.rows[i].left, self.rows[i].right) for i in self.per_tile[tile]]

    def block(self) -> dict[str, Any]:
        """The report's ``dense.pairs``: counts, rejections by reason, every candidate's row."""
        n = len(self.pair_index)
        return {"candidates": len(self.rows), "selected": n, "rejected": len(self.rows) - n,
                "rejected_by_reason": rejection_counts(self.rows), "table": [r.to_dict() for r in self.rows]}

    def pixel_scales_m(self) -> Any:
        """The coarser image's pixel scale of each selected pair (the dense grid's rule)."""
        return np.array([max(self.rows[i].pixel_scale_left_m, self.rows[i].pixel_scale_right_m)
                         for i in self.pair_index])


def rejection_counts(rows: list[Any]) -> dict[str, int]:
    """Candidates rejected, by reason (a candidate may fail several tests: each counts)."""
    from mercury_dem.dense.pairs import SELECTED

    reasons: dict[str, int] = {}
    for r in rows:
        if r.status == SELECTED:
            continue
        for key in r.rejections:  # dense.pairs.PairRejection values, set where each test failed
            reasons[key] = reasons.get(key, 0) + 1
    return reasons


def select_pairs(store: RunStore, mission: Any, config: Config) -> PairSelection:
    """The overlap graph's edges among the controlled images through the pair rule, capped per tile."""
    from mercury_dem.dense.pairs import SELECTED, select_stereo_pairs
    from mercury_dem.dense.rules import cap_per_tile

    geometry = adjusted_geometry(store, mission)
    images, overlaps, _ = store.read_plan()
    tile_of = dict(zip(images["image_id"].astype(str), images["tile_id"].astype(int)))
    candidates = [(str(a), str(b)) for a, b in zip(overlaps["image_i"], overlaps["image_j"])
                  if str(a) in geometry and str(b) in geometry]
    rows = select_stereo_pairs(geometry, criteria_of(config), candidates)
    rows, per_tile = cap_per_tile(rows, tile_of, config.dense.max_pairs_per_tile, config.dense.tiles)
    ranked = sorted((i for i, r in enumerate(rows) if r.status == SELECTED), key=lambda i: rows[i].rank)
    pair_index = {i: k for k, i in enumerate(ranked)}
    records = [{"index": pair_index[i], **rows[i].to_dict()} for i in ranked]
    records = [{k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()}
               for r in json.loads(json.dumps(records, default=float))]
    return PairSelection(rows, per_tile, pair_index, records)


def tile_margins(store: RunStore, config: Config, body: Any) -> tuple[dict[int, float], float]:
    """Each tile's height margin and the run's (:func:`mercury_dem.dense.rules.height_margins`)."""
    from mercury_dem.dem.cloud import point_cloud
    from mercury_dem.dense.rules import height_margins
    from mercury_dem.io.network_store import read_network

    tie = point_cloud(read_network(store.network_path("global", 0)), adjusted=True)
    d = config.dense
    surface = open_sparse_surface(store.dem_path)
    return height_margins(tie, surface.sample, body.datum_radius_m, config.tiling.tile_size_deg,
                          d.height_margin_factor, d.min_height_margin_m)


def run_tiles(store: RunStore, config: Config, client: ComputeClient, pairs: PairSelection, margins: dict[int, float],
              run_margin: float, rep: Any) -> list[dict[str, Any]]:
    """One task per tile on ``client``; their summaries (a lost task recorded as a failed tile), in tile order."""
    from mercury_dem.compute import as_completed

    futures = [client.submit(tile_task, store.location, t, pairs.tile_pairs(t), config, margins.get(t, run_margin),
                             key=f"dense-tile-{t}", pure=False, retries=config.execution.retries)
               for t in sorted(pairs.per_tile)]
    tiles: list[dict[str, Any]] = []
    for fut in as_completed(client, futures):
        try:
            s = fut.result()
        except Exception as exc:  # noqa: BLE001 - a lost task after its retries: recorded, the rest goes on
            raise_if_run_stopping(exc, f"dense tile task {getattr(fut, 'key', '?')}", store.location)
            if lost_to_the_cluster(exc):
                raise  # cancelled by the cluster (no worker, the scheduler gone): the run's failure, not the tile's
            s = {"tile": None, "ok": False, "error": f"dense tile task {getattr(fut, 'key', '?')}: {exc}",
                 "failure": UnitFailure.UNEXPECTED.value}
        tiles.append(s)
        rep.message(f"dense: tile {s.get('tile')}: " + (f"{s.get('points', 0)} points from {s.get('chips', 0)} "
                    f"chips in {s.get('seconds', 0):.1f} s" if s.get("ok") else f"FAILED ({s.get('error')})"))
    tiles.sort(key=lambda s: (s.get("tile") is None, s.get("tile") or 0))
    return tiles


def tiles_block(tiles: list[dict[str, Any]], margins: dict[int, float], run_margin: float) -> dict[str, Any]:
    """The report's per-stage sums of the tiles' summaries; failed tiles and failed pairs/chips also counted by
    kind (``tiles.failed_by_kind``, ``failures_by_kind``; an entry of an older run without one: ``unrecorded``).
    """
    ok = [s for s in tiles if s.get("ok")]
    failed = [s for s in tiles if not s.get("ok")]
    failures = [f for s in ok for f in s.get("failures", [])]
    return {
        "tiles": {"run": len(tiles), "failed": failed, "failed_by_kind": kind_counts(failed)},
        **{k: int(sum(s.get(k, 0) for s in ok)) for k in _TILE_COUNTS},
        "holes": _sum_dicts(s.get("holes", {}) for s in ok),
        "removed": _sum_dicts(s.get("removed", {}) for s in ok),
        "failures": failures,
        "failures_by_kind": kind_counts(failures),
        "height_margin_m": {"run": run_margin, "per_tile": {str(k): v for k, v in sorted(margins.items())}},
        "memory_bytes_max_task": max((s["memory_bytes"]["total"] for s in ok if "memory_bytes" in s), default=0),
        "tile_seconds": {str(s["tile"]): s.get("seconds") for s in ok},
    }


# --------------------------------------------------------------------------- the driver
def run_dense_stage(store: RunStore, mission: Any, config: Config, client: ComputeClient,
                    stream: TextIO | None = sys.stdout) -> dict[str, Any]:
    """Select the pairs, run the tiles on ``client``, grid the dense DEM, make its products; returns the report's
    ``dense`` block (with ``validation``: the dense DEM and the sparse DEM on the dense grid against the truth,
    when known).
    """
    from mercury_dem.progress import Reporter

    rep = Reporter(stream)
    t0 = time.perf_counter()
    pairs = select_pairs(store, mission, config)
    rep.message(f"dense: {len(pairs.rows)} candidate pairs, {len(pairs.pair_index)} selected over "
                f"{len(pairs.per_tile)} tiles")
    margins, run_margin = tile_margins(store, config, mission.body)
    dense_path = store.root / DENSE_FILE
    set_pair_records(dense_path, pairs.records)
    tiles = run_tiles(store, config, client, pairs, margins, run_margin, rep)
    out: dict[str, Any] = {"path": str(dense_path), "pairs": pairs.block(), **tiles_block(tiles, margins, run_margin)}
    scales = pairs.pixel_scales_m()
    if out["points"] == 0 or scales.size == 0:
        out["dem"] = {"error": "no dense point: no dense DEM (see dense.pairs and dense.failures)"}
    else:
        out.update(dense_dem_and_products(store, mission, config, client, pairs, rep))
        rep.message(f"dense stage: {out['points']} points, {out['chips']} chips ({out['chips_failed']} failed), "
                    f"dense DEM at {out['dem']['pixels_per_degree']:g} pixel/deg")
    out["seconds"] = round(time.perf_counter() - t0, 2)
    return out


def dense_dem_and_products(store: RunStore, mission: Any, config: Config, client: ComputeClient, pairs: PairSelection,
                           rep: Any) -> dict[str, Any]:
    """The dense DEM at the grid rule's resolution, its validation against the truth (when known), its products,
    its comparison with the run's references and the orthoimages on it: the report's ``dem``, ``validation``,
    ``products``, ``reference``, ``ortho``.
    """
    from mercury_dem.dem.cloud import point_cloud
    from mercury_dem.dem.dense_grid import dense_grid_ppd
    from mercury_dem.io.network_store import read_network
    from mercury_dem.pipeline.dense_dem import block_holes, grid_dense_dem, rmse_ratio, validate_dense_dem
    from mercury_dem.pipeline.dense_products import reference_comparison, write_dense_products

    body = mission.body
    scales = pairs.pixel_scales_m()
    ppd = dense_grid_ppd(scales, config.dense.grid_pixel_factor, body.datum_radius_m)
    t = time.perf_counter()
    alt = mission.altimetry
    shots = mission.read_altimetry(columns=["lat", "lon", "radius_m"]) if alt is not None and alt.n_shots else None
    out: dict[str, Any] = {"dem": grid_dense_dem(store, config, ppd, client, body, rep,
                                                 median_pixel_scale_m=float(np.median(scales)), shots=shots)}
    out["dem"]["seconds"] = round(time.perf_counter() - t, 2)
    path = store.root / DEM_DENSE_FILE
    out["dem"]["hole_fraction"] = block_holes(path, adjusted_geometry(store, mission).values(), body.datum_radius_m)
    truth = mission.truth.surface().height if mission.truth is not None else None
    if truth is not None:
        tie = point_cloud(read_network(store.network_path("global", 0)), adjusted=True)
        out["validation"] = validate_dense_dem(path, truth, tie, body.datum_radius_m)
        out["dem"]["rmse_ratio_dense_over_sparse"] = rmse_ratio(out["validation"])
    try:
        rep.message("dense: products of the dense DEM (GeoTIFF/COG, PDS, ISIS, statistics, browse)")
        out["products"] = write_dense_products(store, config, truth)
        out["reference"] = reference_comparison(path, config)
        rep.message("dense: orthoimages of the pairs' images on the dense DEM, mosaics of the dense tiles")
        out["ortho"] = dense_orthoimages(store, config, pairs, float(out["dem"]["pixel_m"]))
    except (MercuryDemError, OSError, ValueError) as exc:  # the DEM stands without its products: said, not hidden
        raise_if_run_stopping(exc, "dense products", store.location)
        out["products"] = {"error": f"dense products: {type(exc).__name__}: {exc}"}
    return out


def dense_orthoimages(store: RunStore, config: Config, pairs: PairSelection, dtm_pixel_m: float) -> dict[str, Any]:
    """The selected pairs' images orthorectified on the dense DEM at their native scale, and each dense tile's
    mosaic at its images' native scale and at the DTM's (``RUN/products/dense/ortho/``,
    :func:`mercury_dem.pipeline.ortho_stage.make_orthoimages`); the report's summary of them.
    """
    from mercury_dem.io.run_store import DENSE_PRODUCTS_DIR
    from mercury_dem.pipeline.ortho_stage import ORTHO_DIR, make_orthoimages

    images = sorted({x for i in pairs.pair_index for x in (pairs.rows[i].left, pairs.rows[i].right)})
    s = make_orthoimages(store.root, out_dir=store.products_dir / DENSE_PRODUCTS_DIR / ORTHO_DIR, images=images,
                         tiles=sorted(pairs.per_tile), dem_path=store.root / DEM_DENSE_FILE,
                         tile_size_deg=config.tiling.tile_size_deg, polar_cut_lat=config.dem.polar_cut_lat,
                         overwrite=True, dtm_pixel_m=dtm_pixel_m)
    return {"dir": s["out"], "images": len(s["images"]), "skipped": s["skipped"],
            "mosaics": {t: ({"skipped": m["skipped"]} if "skipped" in m else
                            {"path": m["path"], "pixel_m": m["pixel_m"], "images": len(m["images"]),
                             "valid_fraction": m["valid_fraction"],
                             "dtm": {k: v for k, v in (m.get("dtm") or {}).items()
                                     if k in ("path", "pixel_m", "valid_fraction", "skipped")}})
                        for t, m in s["mosaics"].items()},
            "seconds": s["seconds"]}


def kind_counts(entries: list[dict[str, Any]]) -> dict[str, int]:
    """Failure entries counted by their ``failure`` (``unrecorded`` without one: an older run), most first."""
    counts: dict[str, int] = {}
    for e in entries:
        k = str(e.get("failure") or "unrecorded")
        counts[k] = counts.get(k, 0) + 1
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def _sum_dicts(ds: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for dd in ds:
        for k, v in dd.items():
            out[k] = out.get(k, 0) + int(v)
    return out
