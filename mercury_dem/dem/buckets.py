"""Gridding by neighbour search on the datum sphere (numba): the median11 and Shepard kernels and their calls.

Why not only ``scipy.spatial.cKDTree``
--------------------------------------
Gridding asks, for every pixel centre of a map, for the k (11) nearest points or the
points within 1.41 pixel, then reduces them (1-sigma median, Shepard weights). With a
kd-tree that is one generic query returning ``(P, k)`` distance/index arrays, then a
second pass in numpy over those arrays. Profiling the DEM stage showed the query
(about 60 %) and the ``(P, k)`` post-processing dominating; ``cKDTree`` cannot fuse
the reduction into the search. A bucket grid on the sphere, searched and reduced in
one compiled loop per pixel, does both with no ``(P, k)`` arrays at all. The kd-tree
remains the exact fallback for the rare pixels this search gives up on (far from
every point, see ``ang_max``) and for the tests' independent checks.

The parts, one job per module
-----------------------------
- :mod:`mercury_dem.dem.index`: the bucket index (:func:`build_buckets`, :class:`SphereBuckets`,
  its :class:`~mercury_dem.dem.index.SearchTables`);
- :mod:`mercury_dem.dem.search`: the compiled cap search (runs of points, top-k, exact k-NN);
- :mod:`mercury_dem.dem.reduce`: the per-pixel reductions (1-sigma filtered median, weighted mean);
- this module: the two parallel kernels that fuse them per pixel, and :func:`median11_search`,
  :func:`shepard_search` that call them.

The kernels take four arguments: the index tables, the pixel centres (:class:`Centres`),
the method's settings (:class:`Median11Params`, :class:`ShepardParams`) and the output
arrays (:class:`Outputs`), each a NamedTuple numba passes whole.

A pixel's result depends only on its own centre and the index (the scan order is
fixed by the index), never on which other pixels are computed with it, so chunked
maps are bit-identical to whole ones.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba
import numpy as np
from numba import prange
from numpy.typing import NDArray

from mercury_dem.dem.index import (
    CELL_ASPECT,
    POINTS_PER_CELL,
    SearchTables,
    SphereBuckets,
    build_buckets,
    footprints,
    run_parallel,
)
from mercury_dem.dem.reduce import filtered_median, weighted_mean
from mercury_dem.dem.search import (
    BUFFER,
    Centres,
    angle_upper_bound,
    cap_ranges,
    collect_within,
    fill_centres,
    knn_exact,
    knn_unordered,
    pixel_centre,
    scan_ranges,
    top_k,
)

__all__ = ["CELL_ASPECT", "GROW", "NEEDS_FALLBACK", "OK", "POINTS_PER_CELL", "Centres", "Median11Params", "Outputs",
           "SearchTables", "ShepardParams", "SphereBuckets", "build_buckets", "footprints", "median11_search",
           "shepard_search"]

#: Pixels per parallel work item of the kernels (each item allocates its scratch once).
BLOCK = 256

#: First k-NN cap of a pixel: this factor x the previous pixel's k-th distance (the
#: neighbouring pixel's k-th distance is rarely much shorter); the triangle-inequality
#: bound is the second try, then doubling.
GROW = 1.15

#: Status of a pixel in the kernels' output.
OK, NEEDS_FALLBACK = 0, 1


class Outputs(NamedTuple):
    """The kernels' (P,) outputs: radius (m), count within ``search_r``, chord to the nearest point (m),
    spread (m), status (``OK`` / ``NEEDS_FALLBACK``).
    """

    radius: NDArray[np.float64]
    count: NDArray[np.int32]  # type: ignore[assignment]  # shadows tuple.count; the search's output name
    nearest: NDArray[np.float64]
    spread: NDArray[np.float64]
    status: NDArray[np.uint8]


class Median11Params(NamedTuple):
    """Settings of the median11 kernel: k nearest, sigma of the filter, count radius (m), the caps
    (radians: least, first, last) and the sphere radius (m), the first cap's growth factor.
    """

    k: int
    sigma: float
    search_r: float
    a_min: float
    a0: float
    ang_max: float
    rs: float
    grow: float


class ShepardParams(NamedTuple):
    """Settings of the Shepard kernel: at most ``kmax`` points within ``search_r`` (m), else the
    ``kfb`` nearest; the caps (radians: the search radius's, the fallback's first, the last) and
    the sphere radius (m).
    """

    kmax: int
    kfb: int
    search_r: float
    a_r: float
    a0: float
    ang_max: float
    rs: float


def _median11_body(t: SearchTables, cen: Centres, prm: Median11Params, out: Outputs) -> None:  # pragma: no cover
    k, sigma, a_min, a0, ang_max, rs, grow = prm.k, prm.sigma, prm.a_min, prm.a0, prm.ang_max, prm.rs, prm.grow
    radius = t.radius
    out_r, out_count, out_near, out_spread, status = out
    ncol = cen.u.size
    P = cen.phi.size if cen.paired else cen.phi.size * ncol
    nblk = (P + BLOCK - 1) // BLOCK
    r2count = prm.search_r * prm.search_r
    for blk in prange(nblk):
        ranges = np.empty((2 * t.band_invw.size + 2, 2), dtype=np.int64)
        dk2 = np.empty(max(k, BUFFER))
        ik = np.empty(max(k, BUFFER), dtype=np.int64)
        bd2 = np.empty(BUFFER)
        bi = np.empty(BUFFER, dtype=np.int64)
        rr = np.empty(k)
        rs_scratch = np.empty(k)
        t2 = np.inf
        dprev = -1.0  # k-th distance at the previous pixel of the block (chord, m), -1 = none
        px = py = pz = 0.0
        for p in range(blk * BLOCK, min(P, (blk + 1) * BLOCK)):
            phi, u, qx, qy, qz, icp = pixel_centre(p, cen)
            a_first = a0
            cap2_first = -1.0
            bound = -1.0
            if dprev >= 0.0:
                # The first try is a little above the previous k-th distance: it usually holds k
                # (its squared chord is known: no angle round trip). The previous pixel's k nearest
                # lie within dprev + |q - q_prev| of this one (triangle inequality): a cap that
                # surely holds k points, the second try (its angle computed only if needed).
                g = grow * dprev
                a_first = angle_upper_bound(g, rs)
                if a_first < a_min:
                    a_first = a_min
                elif a_first >= ang_max:  # never beyond the last cap: the kd-tree decision is that cap's
                    a_first = ang_max
                else:
                    cap2_first = g * g
                bound = (dprev + math.sqrt((qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2)) * (1.0 + 1e-9)
            done, cnt, d2near, d2k = knn_unordered(t, phi, icp, u, qx, qy, qz, ranges, dk2, ik, bd2, bi, k, a_first,
                                              cap2_first, -a0, bound, a_min, ang_max, rs, r2count, t2)
            if not done:
                status[p] = NEEDS_FALLBACK
                t2 = np.inf
                dprev = -1.0
                continue
            t2 = 1.5 * d2k
            dprev = math.sqrt(d2k)
            px, py, pz = qx, qy, qz
            status[p] = OK
            for i in range(k):
                rr[i] = radius[ik[i]]
            v, sp = filtered_median(rr, rs_scratch, k, sigma)
            out_r[p] = v
            out_spread[p] = sp
            out_count[p] = cnt
            out_near[p] = math.sqrt(d2near)


def _shepard_body(t: SearchTables, cen: Centres, prm: ShepardParams, out: Outputs) -> None:  # pragma: no cover
    kmax, kfb, search_r, a_r, a0, ang_max, rs = prm
    xyz, radius = t.xyz, t.radius
    out_r, out_count, out_near, out_spread, status = out
    ncol = cen.u.size
    P = cen.phi.size if cen.paired else cen.phi.size * ncol
    nblk = (P + BLOCK - 1) // BLOCK
    r2 = search_r * search_r
    kb = max(kmax, kfb)
    for blk in prange(nblk):
        ranges = np.empty((2 * t.band_invw.size + 2, 2), dtype=np.int64)
        dk2 = np.empty(kb)
        ik = np.empty(kb, dtype=np.int64)
        bd2 = np.empty(BUFFER)
        bi = np.empty(BUFFER, dtype=np.int64)
        sc = (ranges, dk2, ik, bd2, bi)
        d = np.empty(kb)
        w = np.empty(kb)
        for p in range(blk * BLOCK, min(P, (blk + 1) * BLOCK)):
            q = pixel_centre(p, cen)
            phi, u, qx, qy, qz, icp = q
            nr = cap_ranges(t, phi, icp, u, a_r, ranges)
            m, cnt = collect_within(xyz, ranges, nr, qx, qy, qz, r2, r2, bd2, bi)
            if m > bd2.size:
                m, cnt = scan_ranges(xyz, ranges, nr, qx, qy, qz, kmax, r2, r2, dk2, ik)
            else:
                m = top_k(bd2, bi, m, kmax, dk2, ik)
            if m > 0:
                for i in range(m):
                    d[i] = math.sqrt(dk2[i])
                    w[i] = ((search_r - d[i]) / (search_r * d[i])) ** 2 if d[i] > 0 else 0.0
            else:
                done, _ = knn_exact(t, q, sc, kfb, a0, a0, ang_max, rs, r2, np.inf)
                if not done:
                    status[p] = NEEDS_FALLBACK
                    continue
                m = kfb
                for i in range(m):
                    d[i] = math.sqrt(dk2[i])
                    w[i] = 1.0 / dk2[i] if dk2[i] > 0 else 0.0
            status[p] = OK
            v, sp = weighted_mean(radius, ik, d, w, m)
            out_r[p] = v
            out_spread[p] = sp
            out_count[p] = cnt
            out_near[p] = d[0]


_median11_kernel = numba.njit(parallel=True, cache=True, nogil=True)(_median11_body)
_shepard_kernel = numba.njit(parallel=True, cache=True, nogil=True)(_shepard_body)


def _outputs(P: int) -> Outputs:
    return Outputs(np.empty(P), np.zeros(P, dtype=np.int32), np.empty(P), np.empty(P), np.zeros(P, dtype=np.uint8))


def _pixel_centres(lat_deg: NDArray[np.floating], lon_deg: NDArray[np.floating], b: SphereBuckets, grid: bool
                   ) -> tuple[int, Centres]:
    """(number of pixels, the kernels' centre tables) for a list of centres or a grid of them."""
    lat = np.ascontiguousarray(np.ravel(lat_deg), dtype=np.float64)
    lon = np.ascontiguousarray(np.ravel(lon_deg), dtype=np.float64)
    if not grid and lat.size != lon.size:
        raise ValueError(f"{lat.size} latitudes but {lon.size} longitudes")
    nr, nc = lat.size, lon.size
    cen = Centres(np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nr), np.empty(nc), np.empty(nc), np.empty(nc),
                  not grid)
    fill_centres(lat, lon, b.sphere_radius, b.lon0, cen)
    return (lat.size * lon.size if grid else lat.size), cen


def median11_search(
    b: SphereBuckets, lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], k: int, sigma: float,
    search_r: float, ang_max: float, threads: int = -1, *, grid: bool = False,
) -> dict[str, NDArray[np.generic]]:
    """median11 at pixel centres (degrees): k nearest, 1-sigma filter about the median radius.

    The centres are ``(lat_deg[p], lon_deg[p])`` (P,) or, with ``grid=True``, every
    ``(lat_deg[i], lon_deg[j])`` row by row (P = rows x columns; the trigonometry of the
    centres is then done once per row and per column). Returns dict of (P,) arrays:
    ``radius`` (m), ``count`` (points within ``search_r``), ``nearest`` (chord to the
    nearest point, m), ``spread`` (m; NaN under two kept points), ``status`` (``OK`` or
    ``NEEDS_FALLBACK`` where the k nearest are beyond ``ang_max`` radians: the other
    outputs are then undefined).
    """
    P, cen = _pixel_centres(lat_deg, lon_deg, b, grid)
    out = _outputs(P)
    a_r = 2.0 * math.asin(min(1.0, search_r / (2.0 * b.sphere_radius)))
    a_min = min(a_r * (1 + 1e-6), math.pi)
    a0 = min(max(b.start_angle(k), a_min), math.pi)
    prm = Median11Params(int(k), float(sigma), float(search_r), a_min, a0, max(a0, min(ang_max, math.pi)),
                         b.sphere_radius, GROW)
    run_parallel(_median11_kernel, threads, b.tables(), cen, prm, out)
    return out._asdict()


def shepard_search(
    b: SphereBuckets, lat_deg: NDArray[np.float64], lon_deg: NDArray[np.float64], kmax: int, kfb: int,
    search_r: float, ang_max: float, threads: int = -1, *, grid: bool = False,
) -> dict[str, NDArray[np.generic]]:
    """Modified Shepard at pixel centres (degrees); centres and outputs as :func:`median11_search`.

    Weights ``((R - d) / (R d))**2`` over the (at most ``kmax`` nearest) points within
    ``R = search_r``; where none, the ``kfb`` nearest with weights ``1 / d**2``.
    """
    P, cen = _pixel_centres(lat_deg, lon_deg, b, grid)
    out = _outputs(P)
    a_r = min(2.0 * math.asin(min(1.0, search_r / (2.0 * b.sphere_radius))), math.pi)
    a0 = min(max(b.start_angle(kfb), a_r), math.pi)
    prm = ShepardParams(int(kmax), int(kfb), float(search_r), a_r, a0, max(a0, min(ang_max, math.pi)),
                        b.sphere_radius)
    run_parallel(_shepard_kernel, threads, b.tables(), cen, prm, out)
    return out._asdict()
