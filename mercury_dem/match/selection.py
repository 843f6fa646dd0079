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
of the a-priori geometry (the pairs' convergences come from the pre-transform's
:class:`~mercury_dem.match.pretransform.PairGeometry`, computed once per pair by the tile and handed
to the pair chain) and the narrower pairs' match counts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.pretransform import ImageGeometry, datum_grid, sees

#: How the reason of a pair skipped by this rule begins (``PairReport.reason``): the run counts such pairs
#: apart from the pairs that failed.
REDUNDANT_REASON = "redundant:"

#: Reference grid (per side) on which a route's cover of the wide pair's overlap is measured; the
#: pre-transform's 9 x 9 is too coarse for a share (1/81 steps at thin overlaps).
_COVER_GRID = 17


def route_cover(ref: ImageGeometry, match: ImageGeometry, via: ImageGeometry) -> float:
    """Share of a pair's a-priori overlap (reference grid points on the datum seen by ``match``)
    that ``via`` sees too: 0..1, 0 when the pair has no overlap.
    """
    _, ground, hit = datum_grid(ref, _COVER_GRID)
    in_m = sees(match, ground[hit])[2]
    if not in_m.any():
        return 0.0
    return float(np.mean(sees(via, ground[hit][in_m])[2]))


def wide_pairs(convergence: NDArray[np.float64], config: MatchConfig) -> NDArray[np.bool_]:
    """Pairs the route rule applies to: converging by more than ``redundant_convergence_deg``."""
    return np.asarray(np.isfinite(convergence) & (convergence > config.redundant_convergence_deg), bool)


def narrow_neighbours(
    pairs: Sequence[tuple[str, str]], convergence: NDArray[np.float64], matched: Sequence[int], config: MatchConfig
) -> dict[str, set[str]]:
    """Image -> the images it is joined to by a pair converging by at most ``redundant_convergence_deg``
    that gave at least ``redundant_route_min_matches`` matches (``matched[j]``: pair j's matches, 0 when
    it has none or was not matched).
    """
    out: dict[str, set[str]] = {}
    for (p, q), c, n in zip(pairs, convergence, matched):
        if np.isfinite(c) and c <= config.redundant_convergence_deg and n >= config.redundant_route_min_matches:
            out.setdefault(p, set()).add(q)
            out.setdefault(q, set()).add(p)
    return out


def redundant_reason(
    a: str,
    b: str,
    convergence_deg: float,
    neighbours: Mapping[str, set[str]],
    geometry: Mapping[str, ImageGeometry],
    config: MatchConfig,
) -> str | None:
    """Why the wide pair (a, b) need not be matched, or None when it must.

    It need not when a third image x is among both images' :func:`narrow_neighbours` and sees at
    least ``redundant_route_cover`` of the pair's a-priori overlap.
    """
    best, best_cover = "", 0.0
    for x in sorted((neighbours.get(a, set()) & neighbours.get(b, set())) - {a, b}):
        if x not in geometry or a not in geometry or b not in geometry:
            continue
        cover = route_cover(geometry[a], geometry[b], geometry[x])
        if cover > best_cover:
            best, best_cover = x, cover
    if best and best_cover >= config.redundant_route_cover:
        return (f"{REDUNDANT_REASON} views converge by {convergence_deg:.0f} deg > redundant_convergence_deg "
                f"{config.redundant_convergence_deg:g}, and both images are matched to {best} (covering "
                f"{100 * best_cover:.0f} % of the overlap) by pairs converging less; joined through its points instead")
    return None
