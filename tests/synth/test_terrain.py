"""The truth surface: deterministic, vectorised, Mercury-like statistics, craters where the table says."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.exceptions import ConfigError
from mercury_dem.synth import craters as cr
from mercury_dem.synth.terrain import Surface, SurfaceParams


@pytest.fixture(scope="module")
def surface() -> Surface:
    return Surface(SurfaceParams(seed=11, crater_d_min_m=4000.0))


def test_deterministic_from_the_seed(surface):
    rng = np.random.default_rng(0)
    lat, lon = rng.uniform(-90, 90, 2000), rng.uniform(0, 360, 2000)
    again = Surface(SurfaceParams(seed=11, crater_d_min_m=4000.0))
    other = Surface(SurfaceParams(seed=12, crater_d_min_m=4000.0))
    assert np.array_equal(surface.height(lat, lon), again.height(lat, lon))
    assert np.array_equal(surface.albedo(lat, lon), again.albedo(lat, lon))
    assert not np.allclose(surface.height(lat, lon), other.height(lat, lon))


def test_shapes_seam_and_poles(surface):
    lat = np.array([[0.0, 10.0], [-89.999, 90.0]])
    lon = np.array([[0.0, 359.9999999], [123.0, 0.0]])
    assert surface.height(lat, lon).shape == (2, 2)
    # Continuous across the 0/360 seam and the same at lon and lon + 360.
    assert surface.height(5.0, 360.0 - 1e-9) == pytest.approx(surface.height(5.0, 0.0), abs=1e-3)
    assert surface.height(5.0, -20.0) == pytest.approx(surface.height(5.0, 340.0), abs=1e-6)
    # The pole is one point whatever the longitude.
    assert surface.height(90.0, 0.0) == pytest.approx(surface.height(90.0, 200.0), abs=1e-3)


def test_global_statistics_like_mercury(surface):
    lat, lon = np.meshgrid(np.arange(-89.75, 90, 0.5), np.arange(0.25, 360, 0.5), indexing="ij")
    h = surface.height(lat, lon, resolution_m=10e3)
    w = np.cos(np.radians(lat))
    lo, hi = np.percentile(h, [0.01, 99.99])
    assert -8000 < lo < -2500 and 2000 < hi < 6500, (lo, hi)
    polar = np.average(h[np.abs(lat) > 65], weights=w[np.abs(lat) > 65])
    equatorial = np.average(h[np.abs(lat) < 30], weights=w[np.abs(lat) < 30])
    assert polar < equatorial - 300  # the poles lie lower on average
    a = surface.albedo(lat, lon, resolution_m=10e3)
    assert 0.1 < np.median(a) < 0.2 and np.percentile(a, 95) / np.percentile(a, 5) > 1.3
    assert abs(np.corrcoef(a.ravel(), h.ravel())[0, 1]) < 0.1  # albedo independent of height


def test_fresh_simple_crater_has_the_bowl_depth(surface):
    t = surface.craters
    sel = np.flatnonzero((t[:, cr.C_KIND] == cr.KIND_SIMPLE) & (t[:, cr.C_AGE] > 0.99) & (t[:, cr.C_AMP] > 0.98))
    k = sel[np.argmax(t[sel, cr.C_RADIUS])]
    cat = surface.crater_catalog()
    lat, lon, d = cat["lat"][k], cat["lon"][k], cat["diameter_m"][k]
    # Rim-to-floor depth / diameter ~ 0.2 (up to overprinting by neighbours and roughness).
    ang = np.degrees(d / 2 / surface.radius_m)
    az = np.linspace(0, 2 * np.pi, 36, endpoint=False)
    rim = surface.height(lat + ang * np.sin(az), lon + ang * np.cos(az) / np.cos(np.radians(lat)))
    floor = surface.height(lat, lon)
    assert 0.13 < (np.median(rim) - floor) / d < 0.27


def test_bad_parameters_are_named():
    with pytest.raises(ConfigError, match="crater_d_min_m"):
        SurfaceParams(crater_d_min_m=-1.0)
    with pytest.raises(ConfigError, match="unknown surface parameters"):
        SurfaceParams.from_dict({"seed": 1, "bogus": 2})


@pytest.mark.parametrize("lat, lon, scale_m", [(12.0, 35.0, 2000.0), (89.7, 10.0, 1500.0), (-2.0, 359.8, 900.0)],
                         ids=["mid", "pole", "seam"])
def test_grid_sampling_equals_point_sampling(surface, lat, lon, scale_m):
    """The renderer's crater-by-crater grid evaluation gives the point-by-point heights and albedo."""
    from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit
    from mercury_dem.geometry.camera import mdis_wac
    from mercury_dem.geometry.pose import look_at_rotation
    from mercury_dem.synth.render import RenderSettings, footprint_grid

    cam = mdis_wac(128)
    up = latlon_to_unit(lat, lon)
    c = up * (DATUM_RADIUS_M + scale_m / cam.ifov_rad)
    r = look_at_rotation(c, up * DATUM_RADIUS_M)
    sun = 5.8e10 * latlon_to_unit(lat - 30.0, lon + 40.0)
    grid = footprint_grid(cam, c, r, sun, surface.radius_m, RenderSettings())
    dirs = grid.directions()
    h, a = surface.sample_grid(grid, dirs)
    assert np.allclose(h, surface.height_unit(dirs, grid.spacing_m), rtol=0, atol=1e-6)
    assert np.allclose(a, surface.albedo_unit(dirs, grid.spacing_m), rtol=0, atol=1e-9)
