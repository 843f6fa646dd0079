"""Gridding a point cloud into an equirectangular DEM, one map chunk at a time (pure).

Frames and units
----------------
* Points: body-fixed XYZ, metres, shape (N, 3). Their radius ``|p|`` is what is
  gridded; heights are ``radius - datum_radius_m`` (the body's datum, carried by the index and the grid).
* Neighbour search: over the points' *footprints* on the datum sphere
  (``p / |p| * datum_radius_m``), queried with pixel centres on the same sphere,
  by the compiled bucket search of :mod:`mercury_dem.dem.buckets` (search and
  reduction fused per pixel); a ``scipy.spatial.cKDTree`` of the same footprints
  is the exact fallback for pixels far from every point and the independent
  reference path (``grid_pixels(..., use_kdtree=True)``). Distances are horizontal
  chords (equal to great-circle distances to better than 1 mm below 50 km), and the
  seam at 0/360 degrees and the poles need no special case. Using the raw 3-D
  points instead would make a point 3 km above the datum 3 km "farther" from
  every pixel, biasing the neighbours towards low ground.
* Grid: rows run north to south, columns west to east; pixel (i, j) has its
  centre at ``lat = lat_max - (i + 0.5) / ppd``, ``lon = lon_min + (j + 0.5) / ppd``
  (degrees, planetocentric, east-positive), computed from the *global* indices so
  a pixel's value never depends on the chunk it is computed in.

Methods
-------
``median11`` (Becker et al. 2016): the k (11) nearest points, discard those
farther than ``sigma_filter`` standard deviations from their median radius,
return the median of the rest. After sorting the k radii the kept points are a
contiguous run (an interval about the median): its bounds are two counts, its
median two reads (compiled per pixel; vectorized over pixels on the kd-tree path).

``shepard`` (Becker et al. 2015): modified Shepard (Franke & Nielson) weights
``w = ((R - d) / (R d))**2`` for the points within the search radius ``R``; where
there is none, the ``shepard_fallback_neighbours`` (5) nearest points with
inverse-square-distance weights (the modified weight would give the farthest of
them weight zero).

Both honour ``max_distance_m``: a pixel whose nearest point is farther has no value
(NaN); 0 means "from the points' spacing" (:mod:`mercury_dem.dem.spacing`, resolved here
when the caller has not: the stage resolves it once for all chunks). The smoothing (``dem.filters``) needs a halo of
``passes * (size // 2)`` pixels, which :func:`grid_chunk` computes itself, so a
chunk's result is identical whatever the chunking.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.extent import points_box
from mercury_dem.dem.spacing import BOX_SAMPLE, no_value_distance_m, probe_lattice
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import latlon_to_unit

if TYPE_CHECKING:
    from mercury_dem.dem.buckets import SphereBuckets

# The compiled kernels (mercury_dem.dem.buckets, .filters: numba) are imported by the functions that
# run them: GridSpec, LAYERS and PointIndex stay importable without numba (the forked dem.zarr writer
# of mercury_dem.pipeline.store_writer needs only those).

#: Pixels handled per kd-tree query batch (bounds the (P, k) work arrays).
QUERY_BATCH = 1 << 17

#: Output layers of a gridded chunk, with their dtypes.
LAYERS: dict[str, Any] = {
    "elevation": np.float32,
    "radius": np.float32,
    "point_count": np.int32,
    "distance_to_nearest_point": np.float32,
    "spread": np.float32,
}


@dataclass(frozen=True)
class GridSpec:
    """An equirectangular grid (rows north to south) in planetocentric degrees."""

    pixels_per_degree: float
    lat_min: float = -90.0
    lat_max: float = 90.0
    lon_min: float = 0.0
    lon_max: float = 360.0
    #: The body's datum sphere (m): pixel sizes and distances are measured on it. Keyword-only, no default.
    datum_radius_m: float = field(kw_only=True)

    def __post_init__(self) -> None:
        for name, span in (("latitude", self.lat_max - self.lat_min), ("longitude", self.lon_max - self.lon_min)):
            n = span * self.pixels_per_degree
            if span <= 0 or abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 1:
                raise GridError(
                    f"the DEM grid's {name} span {span} deg is not a whole number of pixels at "
                    f"{self.pixels_per_degree} pixel/deg; change dem.pixels_per_degree or the grid bounds"
                )

    @classmethod
    def from_config(cls, cfg: DemConfig, datum_radius_m: float) -> GridSpec:
        """The grid of a :class:`~mercury_dem.config.dem.DemConfig` (unset bounds: the globe's)."""
        return cls(cfg.pixels_per_degree, *cfg.bounds(), datum_radius_m=datum_radius_m)

    @property
    def shape(self) -> tuple[int, int]:
        """(rows, columns)."""
        return (
            int(round((self.lat_max - self.lat_min) * self.pixels_per_degree)),
            int(round((self.lon_max - self.lon_min) * self.pixels_per_degree)),
        )

    @property
    def is_global_lon(self) -> bool:
        """True when the columns wrap around the planet (the halo wraps at the seam)."""
        return abs(self.lon_max - self.lon_min - 360.0) < 1e-9

    @property
    def pixel_size_m(self) -> float:
        """North-south pixel size on the datum sphere, metres."""
        return 2.0 * math.pi * self.datum_radius_m / 360.0 / self.pixels_per_degree

    def lat_centres(self, rows: NDArray[np.integer] | None = None) -> NDArray[np.float64]:
        """Latitudes (deg) of the pixel centres of global row indices (all rows by default)."""
        i = np.arange(self.shape[0]) if rows is None else np.asarray(rows)
        return np.asarray(self.lat_max - (i + 0.5) / self.pixels_per_degree, dtype=np.float64)

    def lon_centres(self, cols: NDArray[np.integer] | None = None) -> NDArray[np.float64]:
        """Longitudes (deg) of the pixel centres of global column indices (all by default)."""
        j = np.arange(self.shape[1]) if cols is None else np.asarray(cols)
        return np.asarray(self.lon_min + (j + 0.5) / self.pixels_per_degree, dtype=np.float64)

    def chunks(self, chunk_size: int) -> list[tuple[int, int, int, int]]:
        """Chunk bounds ``(row0, row1, col0, col1)`` tiling the grid, row-major."""
        nr, nc = self.shape
        return [
            (r, min(r + chunk_size, nr), c, min(c + chunk_size, nc))
            for r in range(0, nr, chunk_size)
            for c in range(0, nc, chunk_size)
        ]


@dataclass(frozen=True)
class PointIndex:
    """A point cloud ready for gridding: footprints bucketed on the datum sphere + radii.

    Build it once (:func:`build_point_index`) and share it by every chunk (on Dask:
    scattered once to each worker). The points are held in bucket order
    (``buckets.order`` maps back to the input rows). A kd-tree of the same footprints
    (``tree``) is built on first use only: the exact fallback of the bucket search
    for pixels far from every point, and the coverage's nearest-point map.
    """

    buckets: SphereBuckets
    #: The body's datum sphere (m): footprints lie on it, heights are measured from it. No default: an index
    #: without it once gridded a Moon DEM as "radius minus Mercury's datum" on Dask workers.
    datum_radius_m: float

    @property
    def radius(self) -> NDArray[np.float64]:
        """(N,) radii |p| of the points, metres (bucket order)."""
        return self.buckets.radius

    @property
    def footprint(self) -> NDArray[np.float64]:
        """(N, 3) footprints on the datum sphere, body-fixed metres (bucket order)."""
        return self.buckets.xyz

    @property
    def n_points(self) -> int:
        return self.buckets.n_points

    @cached_property
    def tree(self) -> Any:
        """kd-tree of the footprints (``scipy.spatial.cKDTree``, same order as ``radius``), built on first use
        (scipy imported here: the bucket path of a plain ``mercury-dem grid`` never needs it).
        """
        from scipy.spatial import cKDTree

        # Sliding-midpoint (unbalanced) tree: builds in about half the time, queries as fast.
        return cKDTree(self.footprint, balanced_tree=False)

    def __getstate__(self) -> dict[str, Any]:
        # Ship the buckets and the datum, not the tree: a worker rebuilds the tree if it ever needs it.
        # The datum must travel: left out, the unpickled index read the class attribute of a field
        # default, and heights on Dask workers were measured from the wrong body's sphere.
        return {"buckets": self.buckets, "datum_radius_m": self.datum_radius_m}

    def __sizeof__(self) -> int:
        """Bytes held by the index's arrays (``sys.getsizeof``, hence ``dask.sizeof``, count them)."""
        b = self.buckets
        arrays = (b.xyz, b.radius, b.order, b.band_ncell, b.band_first, b.cell_start)
        return object.__sizeof__(self) + sum(int(a.nbytes) for a in arrays)


def build_point_index(points_xyz: NDArray[np.floating], datum_radius_m: float) -> PointIndex:
    """Validate a point cloud and index it.

    Parameters
    ----------
    points_xyz : ndarray of shape (N, 3), body-fixed metres
    datum_radius_m : the body's datum sphere: footprints lie on it, heights are measured from it

    Raises
    ------
    GridError
        If the cloud is empty, not (N, 3), or holds non-finite or zero-radius points.
    """
    p = np.asarray(points_xyz, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise GridError(f"the point cloud must have shape (N, 3) body-fixed metres, got {p.shape}")
    if p.shape[0] == 0:
        raise GridError("the point cloud is empty: nothing to grid (did the adjustment keep any points?)")
    from mercury_dem.dem.buckets import build_buckets, footprints

    f = footprints(p, datum_radius_m)
    bad = f["bad"]
    if bad.any():
        nonfinite = bad == 1
        if nonfinite.any():
            raise GridError(
                f"the point cloud holds {int(nonfinite.sum())} non-finite points "
                f"(first at row {int(np.argmax(nonfinite))})"
            )
        raise GridError(f"the point cloud holds {int((bad == 2).sum())} points at the body centre")
    return PointIndex(buckets=build_buckets(p, datum_radius_m, prepared=f), datum_radius_m=float(datum_radius_m))


def _threads(cfg: DemConfig) -> int:
    """kd-tree query threads (``dem.query_threads``; -1 = all cores). Results do not depend on it."""
    t = int(getattr(cfg, "query_threads", -1))
    return -1 if t == 0 else t


def _median11(
    index: PointIndex, q: NDArray[np.float64], cfg: DemConfig, search_r: float
) -> dict[str, NDArray[Any]]:
    """median11 on query points q (P, 3); returns flat per-pixel layers (radius float64)."""
    k = min(int(cfg.neighbours), index.n_points)
    d, idx = index.tree.query(q, k=k, workers=_threads(cfg))
    d = d.reshape(len(q), k)
    idx = idx.reshape(len(q), k)
    rs = np.sort(index.radius[idx], axis=1)
    if k % 2:
        med = rs[:, k // 2]
    else:
        med = 0.5 * (rs[:, k // 2 - 1] + rs[:, k // 2])
    c = rs - med[:, None]  # centred: no cancellation at 2.4e6 m
    sd = np.sqrt(np.mean(c * c, axis=1) - np.mean(c, axis=1) ** 2)
    band = cfg.sigma_filter * sd
    lo = np.count_nonzero(c < -band[:, None], axis=1)
    hi = np.count_nonzero(c <= band[:, None], axis=1)
    n = hi - lo
    ok = n > 0
    a = np.where(ok, lo + (n - 1) // 2, 0)
    b = np.where(ok, lo + n // 2, 0)
    kept_med = 0.5 * (np.take_along_axis(c, a[:, None], 1)[:, 0] + np.take_along_axis(c, b[:, None], 1)[:, 0])
    value = med + np.where(ok, kept_med, 0.0)
    # Spread: standard deviation of the kept run, from prefix sums of the centred radii.
    z = np.zeros((len(q), 1))
    cs = np.concatenate([z, np.cumsum(c, axis=1)], axis=1)
    cs2 = np.concatenate([z, np.cumsum(c * c, axis=1)], axis=1)
    nn = np.maximum(n, 1)
    s1 = (np.take_along_axis(cs, hi[:, None], 1) - np.take_along_axis(cs, lo[:, None], 1))[:, 0] / nn
    s2 = (np.take_along_axis(cs2, hi[:, None], 1) - np.take_along_axis(cs2, lo[:, None], 1))[:, 0] / nn
    spread = np.where(n >= 2, np.sqrt(np.maximum(s2 - s1 * s1, 0.0)), np.nan)
    count = np.count_nonzero(d <= search_r, axis=1)
    return {"radius": value, "nearest": d[:, 0], "spread": spread, "count": count, "count_capped": count == k}


def _weighted_mean(w: NDArray[np.float64], r: NDArray[np.float64], d: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Weighted mean and weighted standard deviation of radii r (rows = pixels), weights w >= 0.

    A point exactly on the pixel centre (d == 0) takes all the weight (mean of such points).
    Radii are centred on the first column before summing (no cancellation at 2.4e6 m).
    Spread is NaN where fewer than two points carry weight.
    """
    exact = d == 0.0
    any_exact = exact.any(axis=1)
    if any_exact.any():
        w = w.copy()
        w[any_exact] = exact[any_exact]
    ref = r[:, :1]
    c = r - ref
    sw = w.sum(axis=1)
    m = np.einsum("ij,ij->i", w, c) / sw
    c -= m[:, None]
    var = np.einsum("ij,ij->i", w, c * c) / sw
    nused = np.count_nonzero(w > 0, axis=1)
    return ref[:, 0] + m, np.where(nused >= 2, np.sqrt(var), np.nan)


def _shepard(index: PointIndex, q: NDArray[np.float64], cfg: DemConfig, search_r: float) -> dict[str, NDArray[Any]]:
    """Modified Shepard IDW on query points q (P, 3); flat per-pixel layers (radius float64)."""
    P = len(q)
    kmax = min(int(cfg.shepard_max_points), index.n_points)
    d, idx = index.tree.query(q, k=kmax, distance_upper_bound=search_r, workers=_threads(cfg))
    d = d.reshape(P, kmax)
    idx = idx.reshape(P, kmax)
    count = np.count_nonzero(np.isfinite(d), axis=1)
    # Neighbours come sorted by distance, misses (inf) last: keep only the columns some pixel uses.
    kc = max(int(count.max()), 1)
    d, idx = d[:, :kc], idx[:, :kc]
    value = np.full(P, np.nan)
    spread = np.full(P, np.nan)
    nearest = np.where(count > 0, d[:, 0], np.inf)
    has = count > 0
    if has.any():
        dh = d[has]
        inside = np.isfinite(dh)
        r = index.radius[np.where(inside, idx[has], 0)]
        with np.errstate(divide="ignore", invalid="ignore"):
            w = ((search_r - dh) / (search_r * dh)) ** 2
        w[~inside] = 0.0
        w[dh == 0.0] = 0.0  # (set by _weighted_mean's exact rule)
        value[has], spread[has] = _weighted_mean(w, r, dh)
    miss = ~has
    if miss.any():
        kf = min(int(cfg.shepard_fallback_neighbours), index.n_points)
        df, idf = index.tree.query(q[miss], k=kf, workers=_threads(cfg))
        df = df.reshape(-1, kf)
        idf = idf.reshape(-1, kf)
        with np.errstate(divide="ignore"):
            wf = 1.0 / (df * df)
        wf[df == 0.0] = 0.0
        value[miss], spread[miss] = _weighted_mean(wf, index.radius[idf], df)
        nearest[miss] = df[:, 0]
    return {"radius": value, "nearest": nearest, "spread": spread, "count": count, "count_capped": count == kmax}


def _search_radius(index: PointIndex, cfg: DemConfig) -> float:
    """Radial search radius R (m): ``search_radius_factor`` x the north-south pixel size."""
    return cfg.search_radius_factor * 2.0 * math.pi * index.datum_radius_m / 360.0 / cfg.pixels_per_degree


def _give_up_angle(index: PointIndex, cfg: DemConfig, k: int) -> float:
    """Largest cap (radians) the bucket search scans before leaving a pixel to the kd-tree.

    Twice the no-value distance or 8 x the starting cap, whichever is larger: pixels
    beyond it are in gaps far from every point, rare, and cheaper for the tree.
    """
    a_gap = 2.0 * math.asin(min(1.0, cfg.max_distance_m / (2.0 * index.datum_radius_m)))
    return min(math.pi, max(2.0 * a_gap, 8.0 * index.buckets.start_angle(k)))


def _kdtree_pixels(index: PointIndex, lat: NDArray[np.float64], lon: NDArray[np.float64], cfg: DemConfig,
                   search_r: float) -> dict[str, NDArray[Any]]:
    """The same layers from kd-tree queries (the exact fallback of the bucket search)."""
    P = lat.size
    out: dict[str, NDArray[Any]] = {"radius": np.empty(P), "count": np.empty(P, dtype=np.int32),
                                    "nearest": np.empty(P), "spread": np.empty(P)}
    kernel = _median11 if cfg.method == "median11" else _shepard
    for s in range(0, P, QUERY_BATCH):
        sl = slice(s, min(s + QUERY_BATCH, P))
        q = latlon_to_unit(lat[sl], lon[sl]) * index.datum_radius_m
        res = kernel(index, q, cfg, search_r)
        count = res["count"]
        capped = res["count_capped"]
        if capped.any():  # the k-NN query saw only k of them: count them all
            count = count.copy()
            count[capped] = index.tree.query_ball_point(q[capped], r=search_r, return_length=True,
                                                           workers=_threads(cfg))
        out["radius"][sl] = res["radius"]
        out["count"][sl] = count
        out["nearest"][sl] = res["nearest"]
        out["spread"][sl] = res["spread"]
    return out


def grid_pixels(
    index: PointIndex, lat_deg: NDArray[np.floating], lon_deg: NDArray[np.floating], cfg: DemConfig,
    *, use_kdtree: bool = False,
) -> dict[str, NDArray[Any]]:
    """Grid the point cloud at arbitrary pixel centres (no smoothing).

    Parameters
    ----------
    index : PointIndex
    lat_deg, lon_deg : ndarray of shape (P,), planetocentric degrees
    cfg : DemConfig (method, neighbours, sigma_filter, search_radius_factor,
        shepard_*, max_distance_m, pixels_per_degree, query_threads)
    use_kdtree : compute every pixel with scipy's kd-tree and numpy (the independent
        reference implementation; slower) instead of the compiled bucket search

    Returns
    -------
    dict of (P,) arrays: ``height`` (float64, m above the datum, NaN = no value),
    ``point_count`` (int32, points within the search radius),
    ``distance_to_nearest_point`` (float64, m), ``spread`` (float64, m, NaN when
    fewer than two points were used).
    """
    lat = np.asarray(lat_deg, dtype=np.float64).ravel()
    lon = np.asarray(lon_deg, dtype=np.float64).ravel()
    cfg = config_with_no_value_distance(cfg, index)
    if use_kdtree:
        res = _kdtree_pixels(index, lat, lon, cfg, _search_radius(index, cfg))
        return _layers(res, cfg, index.datum_radius_m)
    return _bucket_pixels(index, lat, lon, cfg, grid=False)


def typical_gap_m(index: PointIndex, cfg: DemConfig) -> float:
    """The points' typical gap ``g`` (m): the median distance from the probe places (:func:`probe_lattice`
    over the points' bounding box) to their nearest point, by the gridding's own exact search.
    """
    pts = index.footprint
    box = points_box(pts[:: max(1, pts.shape[0] // BOX_SAMPLE)])
    lat, lon = probe_lattice(box)
    # the nearest point only, searched without giving up (no no-value distance yet): exact, as for a pixel
    probe_cfg = dataclasses.replace(cfg, method="median11", neighbours=1,
                                    max_distance_m=4.0 * index.datum_radius_m)
    d = grid_pixels(index, lat, lon, probe_cfg)["distance_to_nearest_point"]
    return float(np.median(d))


def config_with_no_value_distance(cfg: DemConfig, index: PointIndex) -> DemConfig:
    """``cfg`` with ``max_distance_m`` resolved from the points' spacing when it is 0 (else ``cfg`` itself).

    Deterministic for a given cloud and configuration (a fixed lattice, an exact search): a resumed
    stage resolves the same distance as the first try.
    """
    if cfg.max_distance_m > 0:
        return cfg
    pixel_m = 2.0 * math.pi * index.datum_radius_m / 360.0 / cfg.pixels_per_degree
    d = no_value_distance_m(typical_gap_m(index, cfg), cfg.no_value_spacing_factor, pixel_m)
    return dataclasses.replace(cfg, max_distance_m=d)


def _bucket_pixels(index: PointIndex, lat: NDArray[np.float64], lon: NDArray[np.float64], cfg: DemConfig, *,
                   grid: bool) -> dict[str, NDArray[Any]]:
    """:func:`grid_pixels` by the bucket search; ``grid=True``: every (lat[i], lon[j]), row-major."""
    from mercury_dem.dem.buckets import NEEDS_FALLBACK, median11_search, shepard_search

    search_r = _search_radius(index, cfg)
    if cfg.method == "median11":
        k = min(int(cfg.neighbours), index.n_points)
        res = median11_search(index.buckets, lat, lon, k, cfg.sigma_filter, search_r,
                              _give_up_angle(index, cfg, k), _threads(cfg), grid=grid)
    else:
        kf = min(int(cfg.shepard_fallback_neighbours), index.n_points)
        res = shepard_search(index.buckets, lat, lon, min(int(cfg.shepard_max_points), index.n_points), kf,
                             search_r, _give_up_angle(index, cfg, kf), _threads(cfg), grid=grid)
    far = np.flatnonzero(res.pop("status") == NEEDS_FALLBACK)
    if far.size:
        if grid:
            flat = far // lon.size, far % lon.size
            fb = _kdtree_pixels(index, lat[flat[0]], lon[flat[1]], cfg, search_r)
        else:
            fb = _kdtree_pixels(index, lat[far], lon[far], cfg, search_r)
        for key, v in fb.items():
            res[key][far] = v
    return _layers(res, cfg, index.datum_radius_m)


def _layers(res: dict[str, NDArray[Any]], cfg: DemConfig, datum_radius_m: float) -> dict[str, NDArray[Any]]:
    gap = res["nearest"] > cfg.max_distance_m
    return {
        "height": np.where(gap, np.nan, res["radius"] - datum_radius_m),
        "point_count": res["count"].astype(np.int32, copy=False),
        "distance_to_nearest_point": res["nearest"],
        "spread": np.where(gap, np.nan, res["spread"]),
    }


def _near_pixels_only(index: PointIndex, lat: NDArray[np.float64], lon: NDArray[np.float64], cfg: DemConfig
                      ) -> dict[str, NDArray[Any]]:
    """:func:`_bucket_pixels` on the grid ``lat`` x ``lon`` (row-major), searching only the pixels that a point
    can give a value or a count: those whose nearest point lies within the no-value distance or the count's
    search radius (the larger, +1e-6). Why: on a patchy cloud (the dense stereo cloud) most pixels are far
    from every point, and the bucket search scans a cap set by the cloud's global density before handing each
    of them to the kd-tree; one nearest-point query per pixel (scipy's kd-tree) sorts them out first.

    The pixels searched get exactly :func:`_bucket_pixels`'s values (each pixel's search is independent of
    the others); the others are no value (``height`` and ``spread`` NaN, ``point_count`` 0), as the full
    search would make them, with ``distance_to_nearest_point`` +inf: farther than the reach, not measured
    (the kd-tree's query is bounded by the reach: unbounded, a pixel thousands of km from a patchy cloud
    visits most of the tree, and the demo's 900 x 1800 grid took over a minute per chunk).
    """
    la, lo = (a.ravel() for a in np.meshgrid(lat, lon, indexing="ij"))
    q = latlon_to_unit(la, lo) * index.datum_radius_m
    reach = max(cfg.max_distance_m, _search_radius(index, cfg)) * (1.0 + 1e-6)
    nearest, _ = index.tree.query(q, k=1, distance_upper_bound=reach, workers=_threads(cfg))
    near = np.flatnonzero(nearest <= reach)
    out: dict[str, NDArray[Any]] = {
        "height": np.full(la.size, np.nan), "point_count": np.zeros(la.size, np.int32),
        "distance_to_nearest_point": np.asarray(nearest, np.float64), "spread": np.full(la.size, np.nan)}
    if near.size:
        for key, v in _bucket_pixels(index, la[near], lo[near], cfg, grid=False).items():
            out[key][near] = v
    return out


def grid_chunk(
    index: PointIndex, grid: GridSpec, bounds: tuple[int, int, int, int], cfg: DemConfig, *,
    near_points_only: bool = False,
) -> dict[str, NDArray[Any]]:
    """Grid one map chunk, smoothing included, independent of the chunking.

    The chunk ``bounds = (row0, row1, col0, col1)`` (global pixel indices, end
    exclusive) is gridded with a halo of ``smoothing_passes * (smoothing_size // 2)``
    pixels; halo columns wrap across the 0/360 seam on a global grid, halo pixels
    outside the grid count as "no value" exactly as in a single-chunk run.

    ``near_points_only``: search only the pixels within reach of a point (:func:`_near_pixels_only`: the
    same elevations; for a patchy cloud whose other pixels are gaps by definition).

    Returns
    -------
    dict of (row1 - row0, col1 - col0) arrays named as :data:`LAYERS`:
    ``elevation`` (float32, m above the body's datum, NaN = no value),
    ``radius`` (float32, m), ``point_count`` (int32), ``distance_to_nearest_point``
    (float32, m), ``spread`` (float32, m).
    """
    r0, r1, c0, c1 = bounds
    nr, nc = grid.shape
    cfg = config_with_no_value_distance(cfg, index)
    if not (0 <= r0 < r1 <= nr and 0 <= c0 < c1 <= nc):
        raise GridError(f"chunk bounds {bounds} are outside the grid of shape {grid.shape}")
    h = cfg.smoothing_passes * (cfg.smoothing_size // 2)
    rows = np.arange(r0 - h, r1 + h)
    cols = np.arange(c0 - h, c1 + h)
    row_ok = (rows >= 0) & (rows < nr)
    if grid.is_global_lon:
        cols = np.mod(cols, nc)
        col_ok = np.ones(cols.shape, dtype=bool)
    else:
        col_ok = (cols >= 0) & (cols < nc)
    rr, cc = rows[row_ok], cols[col_ok]
    shape = (rr.size, cc.size)
    if near_points_only:
        res = _near_pixels_only(index, grid.lat_centres(rr), grid.lon_centres(cc), cfg)
    else:
        res = _bucket_pixels(index, grid.lat_centres(rr), grid.lon_centres(cc), cfg, grid=True)
    # The in-grid rows (columns) of the haloed block are one run, starting at ro (co).
    ro = int(np.argmax(row_ok))
    co = int(np.argmax(col_ok))
    height = np.full((rows.size, cols.size), np.nan)
    height[ro : ro + shape[0], co : co + shape[1]] = res["height"].reshape(shape)
    if cfg.smoothing_passes > 0 and cfg.smoothing_size > 1:
        from mercury_dem.dem.filters import smooth_height

        height = smooth_height(height, cfg.smoothing_size, cfg.smoothing_passes)
    height = height[h : h + r1 - r0, h : h + c1 - c0]

    def core_of(a: NDArray[Any]) -> NDArray[Any]:
        """The chunk's own pixels of an unsmoothed layer (computed on the in-grid block)."""
        return a.reshape(shape)[h - ro : h - ro + r1 - r0, h - co : h - co + c1 - c0]

    return {
        "elevation": height.astype(np.float32),
        "radius": (index.datum_radius_m + height).astype(np.float32),
        "point_count": core_of(res["point_count"]).astype(np.int32),
        "distance_to_nearest_point": core_of(res["distance_to_nearest_point"]).astype(np.float32),
        "spread": core_of(res["spread"]).astype(np.float32),
    }
