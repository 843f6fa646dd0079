"""Matching one tile: every pair on a thread pool, then the propagation between them.

Per tile (``match_tile``): every image's features in its own geometry are computed once
(and reused by all pairs where it is the reference); pairs run on a thread pool
(OpenCV releases the GIL) with OpenCV's own threads set to 1 meanwhile. Phase 1 matches
every pair (:func:`mercury_dem.match.pair.match_in_pair_frame`); phase 2 propagates each
image's anchors into its other pairs and phase 3 thins every pair to ``max_matches``
(:mod:`mercury_dem.match.propagation`); each pair is then mapped back to original pixels
(:func:`mercury_dem.match.pair.finish_pair`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.pair import (
    PairState,
    configured_pair_geometry,
    finish_pair,
    match_in_pair_frame,
    record_geometry,
)
from mercury_dem.match.prepare import ImageFeatures, pattern_on, prepare_image
from mercury_dem.match.pretransform import ImageGeometry
from mercury_dem.match.propagation import (
    NO_ANCHORS,
    Anchors,
    anchors_of,
    base_id,
    other_id,
    priorities,
    propagate_into,
    thin,
)
from mercury_dem.match.result import PairFailure, PairReport, PairResult, TileMatches, failed_result, tile_matches
from mercury_dem.match.selection import pair_convergence, redundant_reason, wide_pairs

#: Memory the warped partners of a tile may take between phases 1 and 2 (bytes): within it every
#: pair keeps its partner (and flow) for the propagation, beyond it the propagation warps (and
#: computes the flow) again, trading that time for a worker's memory. A budget, not a measured
#: optimum (the largest tile of the tiny mission, 80 pairs of 256^2 images, needs ~94 MB of it).
_KEEP_WARPED_BYTES = 256 * 2**20
#: Bytes per pixel of a kept warped partner: float32 image (4) + bool valid mask (1).
_WARPED_BYTES_PER_PX = 5
#: ... plus its float32 locally normalized pattern, when the refinement uses one.
_PATTERN_BYTES_PER_PX = 4
#: ... plus the dense flow, when used: float32 (sample, line) displacement (8) + bool usable mask (1).
_FLOW_BYTES_PER_PX = 9


def _n_matches(state: PairResult | PairState) -> int:
    """Matches a pair has after phase 1 (0 for a failed or skipped pair)."""
    return int(state.pa.shape[0]) if isinstance(state, PairState) else int(state.feature_ref.size)


class _OpenCVThreads:
    """Context manager: OpenCV's own thread count set to ``n`` inside, restored after."""

    def __init__(self, n: int) -> None:
        self.n, self.old = n, cv2.getNumThreads()

    def __enter__(self) -> None:
        cv2.setNumThreads(self.n)

    def __exit__(self, *exc: object) -> None:
        cv2.setNumThreads(self.old)


def match_tile(
    images: Mapping[str, NDArray[Any] | None],
    geometry: Mapping[str, ImageGeometry],
    pairs: Sequence[tuple[str, str]],
    config: MatchConfig,
    tracks: bool = True,
    radiometry: Mapping[str, tuple[float, float]] | None = None,
    *,
    pointing_sigma_urad: float,
) -> tuple[TileMatches, list[PairReport]]:
    """Match every pair of a tile.

    Parameters
    ----------
    images : image id -> ndarray (lines, samples) of 12-bit DN (None = unreadable)
    geometry : image id -> a-priori :class:`ImageGeometry` (camera, position, rotation, sun)
    pairs : (ref_id, match_id) pairs, each matched once with the first as reference
    config : MatchConfig (``threads`` pairs run at once)
    tracks : after every pair is matched, propagate each image's matched keypoints (anchors)
        to all its other pairs and prefer multi-pair anchors when thinning to ``max_matches``
        (:mod:`mercury_dem.match.propagation`), so the network gets points of 3+ rays; needs
        ``config.refine``
    radiometry : image id -> (saturation, dn_scale) of its pixels (:func:`image_quality`); missing = 12-bit DN
    pointing_sigma_urad : how wrong the a-priori pointing may be, per axis and image (1 sigma, µrad): sizes each
        pair's guidance window (the run's ``apriori.pointing_sigma_urad`` or the mission's declared one)

    Returns
    -------
    matches : :class:`TileMatches`, indices into ``tuple(images)``, grouped by pair in ``pairs`` order
    reports : one :class:`PairReport` per pair, in ``pairs`` order
    """
    ids = tuple(images)
    index = {k: i for i, k in enumerate(ids)}
    needed: list[str] = []
    for a, b in pairs:
        for x in (a, b):
            if x in index and x in geometry and x not in needed:
                needed.append(x)

    def prep(image_id: str) -> ImageFeatures:
        cam = geometry[image_id].camera
        return prepare_image(images[image_id], (cam.lines, cam.samples), config,
                             radiometry=(radiometry or {}).get(image_id))

    def run(k: int) -> tuple[PairReport, PairResult | PairState]:
        a, b = pairs[k]
        rep = PairReport(ref_id=a, match_id=b)
        missing = [x for x in (a, b) if x not in index or x not in geometry]
        if missing:
            return rep, failed_result(rep, PairFailure.IMAGE_MISSING, f"image {missing[0]} has no {'pixels' if missing[0] not in index else 'geometry'} in this tile")
        t0 = time.perf_counter()
        out = match_in_pair_frame(images[a], images[b], geometry[a], geometry[b], config, prepared[a], prepared[b],
                                  rep, keep_warped=keep_warped, pointing_sigma_urad=pointing_sigma_urad)
        rep.seconds = time.perf_counter() - t0
        return rep, out

    propagate = tracks and config.refine
    # the warped partners are kept for the propagation when they all fit in the budget, else re-warped
    largest = max((geometry[x].camera.lines * geometry[x].camera.samples for x in needed), default=0)
    per_px = (_WARPED_BYTES_PER_PX + (_PATTERN_BYTES_PER_PX if pattern_on(config) else 0)
              + (_FLOW_BYTES_PER_PX if config.flow_refine else 0))
    keep_warped = propagate and len(pairs) * largest * per_px <= _KEEP_WARPED_BYTES
    anchors: dict[str, Anchors] = {}
    # phase1[k]: pair k's report and its current state (or its failed result); each phase
    # replaces the state of its own pair only (the pool's tasks touch distinct k)
    phase1: list[tuple[PairReport, PairResult | PairState]]

    def extend(k: int) -> None:
        rep, st = phase1[k]
        if isinstance(st, PairState):
            t0 = time.perf_counter()
            st = propagate_into(st, anchors.get(base_id(pairs[k], st), NO_ANCHORS),
                                anchors.get(other_id(pairs[k], st), NO_ANCHORS), config, rep)
            phase1[k] = (rep, st)
            rep.seconds += time.perf_counter() - t0

    def finish(k: int) -> PairResult:
        rep, st = phase1[k]
        if isinstance(st, PairResult):
            return st
        t0 = time.perf_counter()
        st = replace(st, warped=None)
        phase1[k] = (rep, st)  # the warped partner is freed now, not at the end of the tile
        if propagate and st.pa.shape[0] > config.max_matches:
            st = thin(st, priority[k], config)
        out = finish_pair(st, config, rep)
        rep.seconds += time.perf_counter() - t0
        return out

    threads = max(1, config.threads)
    # ``threads`` is the whole tile's budget: OpenCV's own threads are set to 1 in either case (at
    # threads == 1 its default pool of one thread per core cost 4-15 % more CPU for ~nothing on a
    # shared machine: docs/benchmarks/match.md, session 11)
    with _OpenCVThreads(1), ThreadPoolExecutor(max_workers=threads) as pool:
        pmap: Any = pool.map if threads > 1 else map  # threads == 1: all in the calling thread
        prepared = dict(zip(needed, pmap(prep, needed)))
        # the wide pairs go last: each is matched only if no narrower route of matched pairs joins its images
        conv = np.full(len(pairs), np.nan)
        if config.redundant_convergence_deg < 180.0:  # ~0.7 ms a pair, on the pool
            conv[:] = list(pmap(lambda p: pair_convergence(geometry.get(p[0]), geometry.get(p[1]), config, pointing_sigma_urad), pairs))
        wide = wide_pairs(conv, config)
        first = [k for k in range(len(pairs)) if not wide[k]]
        done = dict(zip(first, pmap(run, first)))
        if wide.any():
            counts = [_n_matches(done[j][1]) if j in done else 0 for j in range(len(pairs))]

            def run_wide(k: int) -> tuple[PairReport, PairResult | PairState]:
                why = redundant_reason(k, pairs, conv, counts, geometry, config)
                if why is None:
                    return run(k)
                rep = PairReport(ref_id=pairs[k][0], match_id=pairs[k][1])
                pg = configured_pair_geometry(geometry[pairs[k][0]], geometry[pairs[k][1]], config, pointing_sigma_urad)
                if not isinstance(pg, str):  # a wide pair has a geometry (its convergence came from it)
                    record_geometry(rep, pg)
                return rep, failed_result(rep, PairFailure.REDUNDANT, why)

            later = [k for k in range(len(pairs)) if wide[k]]
            done.update(zip(later, pmap(run_wide, later)))
        phase1 = [done[k] for k in range(len(pairs))]
        if propagate:
            anchors = anchors_of(pairs, [st for _, st in phase1])
            list(pmap(extend, range(len(pairs))))
        priority = priorities(pairs, [st for _, st in phase1], index) if propagate else []
        results = list(pmap(finish, range(len(pairs))))
    return tile_matches(ids, index, pairs, results), [r.report for r in results]
