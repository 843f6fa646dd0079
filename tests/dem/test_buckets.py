"""The bucket index of the gridding search (dem/index.py): its sort and its longitude extent, against plain numpy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mercury_dem.dem import index as B
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz


def _cloud(kind: str, rng: np.random.Generator) -> np.ndarray:
    if kind == "regional":  # several sort chunks (SORT_CHUNK points each)
        n = 2 * B.SORT_CHUNK + 1234
        lat, lon = rng.uniform(-12, 9, n), rng.uniform(40, 61, n)
    elif kind == "seam":  # across 0/360: the cells' origin is not 0
        n = 30_000
        lat, lon = rng.uniform(-5, 5, n), np.mod(rng.uniform(-15, 10, n), 360)
    elif kind == "global":
        n = 50_000
        lat, lon = np.degrees(np.arcsin(rng.uniform(-1, 1, n))), rng.uniform(0, 360, n)
    elif kind == "two_blobs":  # empty bands between two groups of points
        n = 20_000
        lat = np.where(np.arange(n) % 2, rng.uniform(-40, -35, n), rng.uniform(20, 22, n))
        lon = rng.uniform(100, 130, n)
    else:  # duplicated points: equal keys, the stable order keeps input order
        base = rng.uniform(0, 3, (500, 2))
        lat, lon = np.repeat(base[:, 0], 7), np.repeat(base[:, 1], 7)
    return latlon_to_xyz(lat, lon, rng.normal(0, 2000, lat.size), datum_radius_m=DATUM_RADIUS_M)


@pytest.mark.parametrize("kind", ["regional", "seam", "global", "two_blobs", "duplicates"])
def test_bucket_order_is_the_stable_sort_by_cell(kind):
    """The three-pass bucketing gives exactly a stable sort of the points by cell (computed
    here in numpy from the index's band/cell layout and footprint angles), each cell's first
    point, and the sorted points' radii and footprints."""
    pts = _cloud(kind, np.random.default_rng(len(kind)))
    b = B.build_buckets(pts, DATUM_RADIUS_M)
    f = B.footprints(pts, DATUM_RADIUS_M)  # the index's own footprint latitudes/longitudes
    r, lat, lon = f["radius"], f["lat"], f["lon"]
    nb = b.band_ncell.size
    band = np.clip(np.floor((lat - b.lat0) / b.band_h).astype(np.int64), 0, nb - 1)
    nc = b.band_ncell[band]
    j = np.floor(np.mod(lon - b.lon0, 2 * np.pi) / (b.lon_span / nc)).astype(np.int64)
    cell = b.band_first[band] + np.clip(j, 0, nc - 1)
    np.testing.assert_array_equal(b.order, np.argsort(cell, kind="stable"))
    counts = np.bincount(cell, minlength=int(b.band_first[-1]))
    np.testing.assert_array_equal(b.cell_start, np.concatenate([[0], np.cumsum(counts)]))
    np.testing.assert_array_equal(b.radius, r[b.order])
    np.testing.assert_allclose(b.xyz, pts[b.order] * (DATUM_RADIUS_M / r[b.order])[:, None], rtol=1e-15)
    if kind == "two_blobs":
        assert np.count_nonzero(np.bincount(band, minlength=nb) == 0) > 10  # empty bands were sorted too


def test_lon_extent_from_bins_equals_a_pass_over_the_points():
    """The longitude span from each bin's least/greatest longitude is the maximum over the
    points of (lon - origin) mod 2 pi, and the whole turn when a bin straddles the origin."""
    rng = np.random.default_rng(3)
    for lo, hi in ((-15, 10), (40, 61), (300, 359.9), (-170, 100)):
        lon = np.radians(np.mod(rng.uniform(lo, hi, 5000), 360))
        lat = np.zeros_like(lon)
        c = B._coarse_edge(lon.size)
        _, bin_lo, bin_hi, _, _ = B._occupancy(lat, lon, c, int(math.ceil(math.pi / c)),
                                               int(math.ceil(2 * math.pi / c)), B.LON_BINS)
        origin, span = B._lon_extent(bin_lo, bin_hi)
        want = np.max(np.mod(lon - origin, 2 * math.pi))
        if hi - lo < 300:
            assert want <= span <= want * (1 + 2e-12) + 2e-12
        u = np.mod(lon - origin, 2 * math.pi)
        assert np.all(u < span)
    bin_lo = np.full(B.LON_BINS, np.inf)
    bin_hi = np.full(B.LON_BINS, -np.inf)
    bin_lo[10], bin_hi[10] = 0.0869, 0.0880  # holds points on both sides of an origin at 0.0873
    assert B._max_from(bin_lo, bin_hi, 0.0873) == 2 * math.pi
