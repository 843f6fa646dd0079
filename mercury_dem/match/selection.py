"""Which pairs of a tile are matched: wide-convergence pairs only where no narrower route joins them.

Why (issue 21, docs/benchmarks/match.md sessions 5-13): the matches of a pair whose views converge
by more than ~45 deg carry an error of up to a pixel that no refinement removes without a
pixel-scale DEM -- the relief seen from two directions (along the epipolar line) and the
Lommel-Seeliger emission term shading each slope differently in the two views (across it). On
the tiny missions the pairs at >= 45 deg give ~45 % of the similar-illumination measures and most
of its p95. Such a pair is often *redundant*: both images are matched to a third image of the tile
by pairs converging less, whose footprints cover the wide pair's overlap, and the track
propagation (:mod:`mercury_dem.match.propagation`) and the network's tracks
(:mod:`mercury_dem.network.tracks`) join the two images through that third one's points, with the
narrower pairs' errors. Skipping only those keeps every tile's control (a wide pair with no such
route is still matched, as session 6 required) and removes the measures that add error, not
connections.

The decision is made after the narrower pairs are matched (:func:`match.tile.match_tile` runs the
wide pairs last), so a route counts only if both its pairs actually gave matches. Pure functions
of the a-priori geometry and the narrower pairs' match counts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.geometry.pose import image_to_ground, project
from mercury_dem.match.pair import configured_pair_geometry
from mercury_dem.match.pretransform import ImageGeometry

#: How the reason of a pair skipped by this rule begins (``PairReport.reason``): the run counts such pairs
#: apart from the pairs that failed.
REDUNDANT_REASON = "redundant:"

#: Reference grid (per side) on which a route's cover of the wide pair's overlap is measured; the
#: pre-transform's 9 x 9 is too coarse for a share (1/81 steps at thin overlaps).
_COVER_GRID = 17


def pair_convergence(ref: ImageGeometry | None, match: ImageGeometry | None, config: MatchConfig,
                     pointing_sigma_urad: float) -> float:
    """Convergence angle (deg) of a pair at its a-priori overlap centre, as the pair chain computes it
    (:func:`configured_pair_geometry`); NaN when an image has no geometry or the pair no overlap.
    """
    if ref is None or match is None:
        return float("nan")
    pg = configured_pair_geometry(ref, match, config, pointing_sigma_urad)
    return float("nan") if isinstance(pg, str) else float(pg.convergence_deg)


def pair_convergences(pairs: Sequence[tuple[str, str]], geometry: Mapping[str, ImageGeometry],
                      config: MatchConfig, pointing_sigma_urad: float) -> NDArray[np.float64]:
    """:func:`pair_convergence` of every pair (deg, NaN where none)."""
    return np.array([pair_convergence(geometry.get(a), geometry.get(b), config, pointing_sigma_urad)
                     for a, b in pairs], np.float64)


def _inside(ground: NDArray[np.float64], g: ImageGeometry) -> NDArray[np.bool_]:
    """Which ground points (N, 3) an image sees inside its frame (datum, no occlusion)."""
    px, depth = project(g.camera, g.position, g.rotation, ground)
    ok = (depth > 0) & np.all(np.isfinite(px), axis=-1)
    return ok & g.camera.in_image(np.nan_to_num(px, nan=-1e9))


def route_cover(ref: ImageGeometry, match: ImageGeometry, via: ImageGeometry) -> float:
    """Share of a pair's a-priori overlap (reference grid points on the datum seen by ``match``)
    that ``via`` sees too: 0..1, 0 when the pair has no overlap.
    """
    cam = ref.camera
    t = (np.arange(_COVER_GRID) + 0.5) / _COVER_GRID
    ss, ll = np.meshgrid(t * cam.samples - 0.5, t * cam.lines - 0.5)
    px = np.stack([ss.ravel(), ll.ravel()], axis=-1)
    ground, hit = image_to_ground(cam, ref.position, ref.rotation, px, datum_radius_m=ref.datum_radius_m)
    g = ground[hit]
    if g.shape[0] == 0:
        return 0.0
    in_m = _inside(g, match)
    if not in_m.any():
        return 0.0
    return float(np.mean(_inside(g[in_m], via)))


def wide_pairs(convergence: NDArray[np.float64], config: MatchConfig) -> NDArray[np.bool_]:
    """Pairs the route rule applies to: converging by more than ``redundant_convergence_deg``."""
    return np.asarray(np.isfinite(convergence) & (convergence > config.redundant_convergence_deg), bool)


def redundant_reason(
    k: int,
    pairs: Sequence[tuple[str, str]],
    convergence: NDArray[np.float64],
    matched: Sequence[int],
    geometry: Mapping[str, ImageGeometry],
    config: MatchConfig,
) -> str | None:
    """Why wide pair ``k`` need not be matched, or None when it must.

    It need not when a third image x of the tile is matched to both of its images by pairs
    converging by at most ``redundant_convergence_deg`` that gave at least
    ``redundant_route_min_matches`` matches each, and x sees at least ``redundant_route_cover`` of
    the pair's a-priori overlap. ``matched[j]`` is pair j's number of matches (0 for a pair not
    matched or not yet matched).
    """
    a, b = pairs[k]
    limit = config.redundant_convergence_deg
    good: dict[str, set[str]] = {}
    for j, (p, q) in enumerate(pairs):
        if j == k or not (np.isfinite(convergence[j]) and convergence[j] <= limit):
            continue
        if matched[j] < config.redundant_route_min_matches:
            continue
        good.setdefault(p, set()).add(q)
        good.setdefault(q, set()).add(p)
    best, best_cover = "", 0.0
    for x in sorted(good.get(a, set()) & good.get(b, set())):
        if x not in geometry or a not in geometry or b not in geometry:
            continue
        cover = route_cover(geometry[a], geometry[b], geometry[x])
        if cover > best_cover:
            best, best_cover = x, cover
    if best and best_cover >= config.redundant_route_cover:
        return (f"{REDUNDANT_REASON} views converge by {convergence[k]:.0f} deg > redundant_convergence_deg {limit:g}, "
                f"and both images are matched to {best} (covering {100 * best_cover:.0f} % of the overlap) by "
                f"pairs converging less; joined through its points instead")
    return None
