"""Gridding: recovery of a known surface, the vectorized 1-sigma filter, Shepard, gaps, chunk invariance."""

from __future__ import annotations

import numpy as np
import pytest
from dem_synthetic import NOISE_M, sample_cloud, truth_height

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.grid import GridSpec, build_point_index, grid_chunk, grid_pixels
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz

REGION = dict(pixels_per_degree=4.0, lat_min=-30.0, lat_max=30.0, lon_min=100.0, lon_max=160.0)


def _whole(index, cfg):
    g = GridSpec.from_config(cfg, datum_radius_m=DATUM_RADIUS_M)
    return g, grid_chunk(index, g, (0, g.shape[0], 0, g.shape[1]), cfg)


def _error(g, res):
    lat, lon = np.meshgrid(g.lat_centres(), g.lon_centres(), indexing="ij")
    return res["elevation"] - truth_height(lat, lon)


def test_median11_recovers_surface_despite_outliers(regional_cloud):
    cfg = DemConfig(method="median11", **REGION)
    g, res = _whole(build_point_index(regional_cloud, datum_radius_m=DATUM_RADIUS_M), cfg)
    err = _error(g, res)
    assert np.isfinite(err).all()
    rmse = float(np.sqrt(np.mean(err**2)))
    # Median of ~11 points with sigma = 20 m, then a 3x3 mean: well under the point noise;
    # the 1 % of +-3 km outliers must leave no trace (max error a few sigma).
    assert rmse < 0.5 * NOISE_M
    assert np.abs(err).max() < 4 * NOISE_M
    # Spread is the scatter of the kept points: of the order of the noise, never of the outliers.
    assert 0.3 * NOISE_M < np.nanmedian(res["spread"]) < 1.5 * NOISE_M
    assert res["elevation"].dtype == np.float32


def test_shepard_recovers_clean_surface():
    cloud = sample_cloud(np.random.default_rng(3), 150_000, (-35, 35), (95, 165))
    cfg = DemConfig(method="shepard", smoothing_passes=0, **REGION)
    g, res = _whole(build_point_index(cloud, datum_radius_m=DATUM_RADIUS_M), cfg)
    err = _error(g, res)
    assert np.isfinite(err).all()
    # IDW of ~6 points in the 1.41 px radius (or 5 fallback neighbours): below the point noise.
    assert np.sqrt(np.mean(err**2)) < NOISE_M
    assert np.abs(err).max() < 5 * NOISE_M


def _naive_median11(r, sigma):
    """Per-pixel reference implementation of the 1-sigma filter (a loop, for the test only)."""
    out = np.empty(len(r))
    for i, row in enumerate(r):
        m = np.median(row)
        kept = row[np.abs(row - m) <= sigma * row.std()]
        out[i] = np.median(kept) if kept.size else m
    return out


@pytest.mark.parametrize("k", [11, 6, 1])
def test_vectorized_filter_equals_per_pixel_filter(k):
    rng = np.random.default_rng(5)
    n = 2000
    lat = rng.uniform(-5, 5, n)
    lon = rng.uniform(0, 10, n)
    h = rng.normal(0, 100, n) + np.where(rng.random(n) < 0.2, 2000.0, 0.0)
    index = build_point_index(latlon_to_xyz(lat, lon, h, datum_radius_m=DATUM_RADIUS_M), datum_radius_m=DATUM_RADIUS_M)
    cfg = DemConfig(method="median11", neighbours=k, pixels_per_degree=2, max_distance_m=1e9)
    qlat, qlon = rng.uniform(-4, 4, 300), rng.uniform(1, 9, 300)
    got = grid_pixels(index, qlat, qlon, cfg)["height"]
    from mercury_dem.geometry.body import latlon_to_unit

    _, idx = index.tree.query(latlon_to_unit(qlat, qlon) * DATUM_RADIUS_M, k=k)
    idx = idx.reshape(300, k)
    want = _naive_median11(index.radius[idx], cfg.sigma_filter) - DATUM_RADIUS_M
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-6)


def test_shepard_weights_and_fallback_exact():
    # Three points on the equator near lon 0; pixel size 1 deg at 1 ppd.
    deg = 2 * np.pi * DATUM_RADIUS_M / 360
    lat = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    lon = np.array([0.0, 0.5, 10.0, 11.0, 12.0, 13.0])
    h = np.array([100.0, 200.0, 0.0, 10.0, 20.0, 30.0])
    index = build_point_index(latlon_to_xyz(lat, lon, h, datum_radius_m=DATUM_RADIUS_M), datum_radius_m=DATUM_RADIUS_M)
    cfg = DemConfig(method="shepard", pixels_per_degree=1, smoothing_passes=0, max_distance_m=1e9)
    R = 1.4142 * deg
    # Pixel at lon 0.25: both near points inside R at 0.25 deg -> equal weights -> 150.
    out = grid_pixels(index, np.array([0.0, 0.0, 0.0]), np.array([0.25, 0.1, 5.5]), cfg)
    assert out["height"][0] == pytest.approx(150.0, abs=1e-6)
    d1, d2 = 0.1 * deg, 0.4 * deg
    w1, w2 = ((R - d1) / (R * d1)) ** 2, ((R - d2) / (R * d2)) ** 2
    assert out["height"][1] == pytest.approx((w1 * 100 + w2 * 200) / (w1 + w2), abs=1e-3)
    assert list(out["point_count"][:2]) == [2, 2]
    # Pixel at lon 5.5: none within R -> the 5 nearest with inverse-square-distance weights.
    dist = np.abs(np.array([0.0, 0.5, 10.0, 11.0, 12.0]) - 5.5) * deg
    w = 1 / dist**2
    assert out["height"][2] == pytest.approx(np.sum(w * h[:5]) / np.sum(w), abs=1e-2)
    assert out["point_count"][2] == 0
    # Distances are chords on the datum sphere (= arcs to 1 mm below 50 km).
    chord = 2 * DATUM_RADIUS_M * np.sin(np.radians(4.5) / 2)
    assert out["distance_to_nearest_point"][2] == pytest.approx(chord, rel=1e-9)


@pytest.mark.parametrize("method", ["median11", "shepard"])
def test_region_without_points_is_nan_and_counted(method):
    # Points only west of lon 180: the eastern hemisphere is a gap beyond max_distance.
    cloud = sample_cloud(np.random.default_rng(2), 20_000, lon_range=(0.0, 180.0))
    cfg = DemConfig(method=method, pixels_per_degree=1, max_distance_m=100_000.0)
    g, res = _whole(build_point_index(cloud, datum_radius_m=DATUM_RADIUS_M), cfg)
    lon = g.lon_centres()
    far = (lon > 185.0) & (lon < 355.0)
    low = np.abs(g.lat_centres()) < 60.0  # 5 deg of longitude is > 100 km there
    assert np.isnan(res["elevation"][np.ix_(low, far)]).all()
    assert (res["point_count"][np.ix_(low, far)] == 0).all()
    inner = (lon > 5.0) & (lon < 175.0)
    assert np.isfinite(res["elevation"][5:-5, inner]).all()
    # Distances in the gap are real distances (about the gap geometry), not NaN.
    assert np.isfinite(res["distance_to_nearest_point"]).all()


@pytest.mark.parametrize("method", ["median11", "shepard"])
def test_chunking_gives_identical_arrays(global_cloud, method):
    index = build_point_index(global_cloud, datum_radius_m=DATUM_RADIUS_M)
    cfg = DemConfig(method=method, pixels_per_degree=1, smoothing_passes=2, max_distance_m=400_000.0)
    g = GridSpec.from_config(cfg, datum_radius_m=DATUM_RADIUS_M)
    nr, nc = g.shape

    def mosaic(n_side):
        rows = np.linspace(0, nr, n_side + 1).astype(int)
        cols = np.linspace(0, nc, n_side + 1).astype(int)
        out = {}
        for a in range(n_side):
            for b in range(n_side):
                res = grid_chunk(index, g, (rows[a], rows[a + 1], cols[b], cols[b + 1]), cfg)
                for k, v in res.items():
                    out.setdefault(k, np.zeros((nr, nc), v.dtype))[rows[a]:rows[a + 1], cols[b]:cols[b + 1]] = v
        return out

    one, four, sixteen = mosaic(1), mosaic(2), mosaic(4)
    for k in one:
        np.testing.assert_array_equal(one[k], four[k], err_msg=k)
        np.testing.assert_array_equal(one[k], sixteen[k], err_msg=k)
    assert np.isfinite(one["elevation"]).mean() > 0.9


def test_bad_point_clouds():
    with pytest.raises(GridError, match="empty"):
        build_point_index(np.zeros((0, 3)), datum_radius_m=DATUM_RADIUS_M)
    with pytest.raises(GridError, match=r"\(N, 3\)"):
        build_point_index(np.zeros((10, 2)), datum_radius_m=DATUM_RADIUS_M)
    bad = np.ones((4, 3))
    bad[2, 1] = np.nan
    with pytest.raises(GridError, match="non-finite"):
        build_point_index(bad, datum_radius_m=DATUM_RADIUS_M)


def test_grid_spec_rejects_fractional_pixels():
    with pytest.raises(GridError, match="whole number of pixels"):
        GridSpec(pixels_per_degree=0.77, datum_radius_m=DATUM_RADIUS_M)
    g = GridSpec(4.0, -10, 10, 350, 370, datum_radius_m=DATUM_RADIUS_M)
    assert g.shape == (80, 80)
    assert g.lat_centres()[0] == pytest.approx(10 - 0.125)
    assert g.lon_centres()[-1] == pytest.approx(370 - 0.125)


@pytest.mark.parametrize("method", ["median11", "shepard"])
@pytest.mark.parametrize(
    "lat_range, lon_range",
    [((-90.0, 90.0), (0.0, 360.0)),  # global: poles in the caps
     ((-30.0, 30.0), (340.0, 380.0)),  # regional across the 0/360 seam (cells cover its longitudes only)
     ((60.0, 90.0), (0.0, 360.0))],  # a polar cap
)
def test_bucket_search_equals_kdtree(method, lat_range, lon_range):
    """The compiled bucket search finds the same neighbours as scipy's kd-tree (independent path)."""
    cloud = sample_cloud(np.random.default_rng(4), 30_000, lat_range, lon_range, outlier_fraction=0.02)
    index = build_point_index(cloud, datum_radius_m=DATUM_RADIUS_M)
    cfg = DemConfig(method=method, pixels_per_degree=2, max_distance_m=300_000.0)
    rng = np.random.default_rng(9)
    lat = rng.uniform(-90, 90, 4000)
    lon = rng.uniform(0, 360, 4000)
    fast = grid_pixels(index, lat, lon, cfg)
    ref = grid_pixels(index, lat, lon, cfg, use_kdtree=True)
    for key in fast:
        np.testing.assert_allclose(fast[key], ref[key], rtol=0, atol=1e-6, err_msg=key)
    assert np.isfinite(fast["height"]).sum() > 100


def test_sort11_network_sorts():
    """The 11-value sorting network of the median11 kernel sorts every 0/1 input (hence, by the
    0-1 principle, every input) and random radii with ties exactly as np.sort does."""
    import itertools

    from mercury_dem.dem.reduce import _sort11

    for bits in itertools.product((0.0, 1.0), repeat=11):
        r = np.array(bits)
        _sort11(r)
        assert np.all(np.diff(r) >= 0), bits
    rng = np.random.default_rng(2)
    for _ in range(200):
        r = DATUM_RADIUS_M + np.round(rng.normal(0, 50, 11), 1)  # rounded: ties occur
        want = np.sort(r)
        _sort11(r)
        np.testing.assert_array_equal(r, want)


def test_smallest_set_breaks_ties_by_point_index():
    """The k-NN selection of the median11 kernel keeps the k smallest distances, ties at the k-th
    place broken by point index (as the sorted (distance, index) order does), whether the
    distances are distinct or heavily tied (duplicated points)."""
    from mercury_dem.dem.search import _smallest_set

    rng = np.random.default_rng(5)
    k = 11
    n_tie_cases = 0
    for trial in range(3000):
        m = int(rng.integers(k, k + 9))  # the drop-the-largest range (m - k <= 8)
        if trial % 2:
            d2 = rng.integers(0, 6, m).astype(float)  # few values: ties everywhere
        else:
            d2 = rng.uniform(0.0, 1.0, m)
        idx = rng.permutation(1000)[:m].astype(np.int64)
        want = sorted(zip(d2, idx))[:k]
        n_tie_cases += m > k and want[-1][0] == sorted(zip(d2, idx))[k][0]
        dk2 = np.empty(m)
        ik = np.empty(m, dtype=np.int64)
        lo, hi = _smallest_set(d2.copy(), idx.copy(), m, k, dk2, ik)
        assert sorted(zip(dk2[:k], ik[:k])) == want
        assert (lo, hi) == (want[0][0], want[-1][0])
    assert n_tie_cases > 100  # the tie path was exercised


@pytest.mark.parametrize("method", ["median11", "shepard"])
def test_near_points_only_grids_the_same_values_on_a_patchy_cloud(method):
    """Two small patches on a wide grid (the dense stereo cloud's case): searching only the pixels within reach
    of a point gives every layer as the full search does there, and the far pixels are gaps (no count, distance
    +inf: beyond the reach, where the full search finds them too).
    """
    rng = np.random.default_rng(11)
    cloud = np.concatenate([sample_cloud(rng, 20_000, (-5, 0), (110, 116)),
                            sample_cloud(rng, 8_000, (12, 15), (140, 143))])
    cfg = DemConfig(method=method, neighbours=32, max_distance_m=10_000.0, **REGION)
    index = build_point_index(cloud, datum_radius_m=DATUM_RADIUS_M)
    g = GridSpec.from_config(cfg, datum_radius_m=DATUM_RADIUS_M)
    reach = max(cfg.max_distance_m, cfg.search_radius_factor * 2 * np.pi * DATUM_RADIUS_M / 360 / 4.0)
    for bounds in [(0, g.shape[0], 0, g.shape[1]), (100, 140, 30, 90)]:
        full = grid_chunk(index, g, bounds, cfg)
        near = grid_chunk(index, g, bounds, cfg, near_points_only=True)
        far = full["distance_to_nearest_point"] > reach * (1 + 1e-6)
        assert np.array_equal(np.isinf(near["distance_to_nearest_point"]), far)
        for name, a in full.items():
            b = near[name].copy()
            if name == "distance_to_nearest_point":
                b[far] = a[far]
            np.testing.assert_array_equal(b, a, err_msg=f"{method} {bounds} {name}")
        assert (full["point_count"][far] == 0).all() and np.isnan(full["elevation"][far]).all()
    assert 0.02 < np.isfinite(full["elevation"]).mean() < 0.3  # patchy: most pixels are gaps
    assert far.mean() > 0.5
