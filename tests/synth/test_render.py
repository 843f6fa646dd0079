"""Renderer: geometry of what is seen (where the true camera projects it), shadows, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_nac, mdis_wac
from mercury_dem.geometry.pose import look_at_rotation, project, rotation_from_angles
from mercury_dem.synth.render import RenderSettings, render_image, render_reflectance


class SpotOnHill:
    """A test surface: a Gaussian hill with an albedo spot on its flank (all in closed form)."""

    radius_m = DATUM_RADIUS_M

    def __init__(self, hill_lat: float, hill_lon: float, spot_lat: float, spot_lon: float,
                 hill_height_m: float = 3000.0, hill_sigma_m: float = 25e3, spot_radius_m: float = 2500.0,
                 spot: bool = True) -> None:
        self.hill = latlon_to_unit(hill_lat, hill_lon)
        self.spot = latlon_to_unit(spot_lat, spot_lon)
        self.h, self.s, self.r, self.with_spot = hill_height_m, hill_sigma_m, spot_radius_m, spot

    def _dist(self, u: np.ndarray, c: np.ndarray) -> np.ndarray:
        return 2 * np.arcsin(np.clip(np.linalg.norm(u - c, axis=-1) / 2, 0, 1)) * self.radius_m

    def height_unit(self, units, resolution_m=None):
        u = np.asarray(units, float)
        return self.h * np.exp(-((self._dist(u, self.hill) / self.s) ** 2))

    def albedo_unit(self, units, resolution_m=None):
        u = np.asarray(units, float)
        a = np.full(u.shape[:-1], 0.1)
        if self.with_spot:
            a = a + 0.3 * np.exp(-((self._dist(u, self.spot) / self.r) ** 2))
        return a


def _oblique_pose(cam, lat, lon, scale_m, emission_deg, azimuth_deg, twist_deg=30.0):
    up = latlon_to_unit(lat, lon)
    east = np.array([-np.sin(np.radians(lon)), np.cos(np.radians(lon)), 0.0])
    north = np.cross(up, east)
    e, a = np.radians(emission_deg), np.radians(azimuth_deg)
    view = np.cos(e) * up + np.sin(e) * (np.cos(a) * east + np.sin(a) * north)
    target = up * DATUM_RADIUS_M
    c = target + view * scale_m / cam.ifov_rad
    r = rotation_from_angles([0, 0, np.radians(twist_deg)]) @ look_at_rotation(c, target)
    return c, r


def _sun(lat, lon, incidence_deg, azimuth_deg):
    up = latlon_to_unit(lat, lon)
    east = np.array([-np.sin(np.radians(lon)), np.cos(np.radians(lon)), 0.0])
    north = np.cross(up, east)
    i, a = np.radians(incidence_deg), np.radians(azimuth_deg)
    return up * DATUM_RADIUS_M + 5.8e10 * (np.cos(i) * up + np.sin(i) * (np.cos(a) * east + np.sin(a) * north))


@pytest.mark.parametrize("camera", [mdis_nac(256), mdis_wac(256)], ids=["NAC", "WAC"])
def test_spot_appears_where_the_true_camera_projects_it(camera):
    """An albedo spot on a 3 km hill, seen at 40 deg emission, is where project() puts it (< 0.25 px).

    The hill displaces the spot by several pixels from where the datum would put
    it, so this checks the intersection with the height field, the distortion
    and the pixel convention together.
    """
    lat, lon, spot_lat, spot_lon = 3.0, 359.5, 3.1, 359.6
    c, r = _oblique_pose(camera, lat, lon, 400.0, 40.0, 60.0)
    sun = _sun(lat, lon, 45.0, 200.0)
    settings = RenderSettings(shadows=False)
    with_spot = render_reflectance(SpotOnHill(lat, lon, spot_lat, spot_lon), camera, c, r, sun, settings)
    plain = render_reflectance(SpotOnHill(lat, lon, spot_lat, spot_lon, spot=False), camera, c, r, sun, settings)
    ratio = np.where(plain > 0, with_spot / np.where(plain > 0, plain, 1) - 1.0, 0.0)
    surf = SpotOnHill(lat, lon, spot_lat, spot_lon)
    h = surf.height_unit(surf.spot)
    expected, _ = project(camera, c, r, latlon_to_xyz(spot_lat, spot_lon, h, datum_radius_m=DATUM_RADIUS_M)[None])
    datum_only, _ = project(camera, c, r, latlon_to_xyz(spot_lat, spot_lon, 0.0, datum_radius_m=DATUM_RADIUS_M)[None])
    assert np.linalg.norm(expected - datum_only) > 3.0  # the test can tell heights apart
    # Centroid of the spot in a window around its expected place.
    s0, l0 = np.round(expected[0]).astype(int)
    win = 12
    sub = ratio[l0 - win:l0 + win + 1, s0 - win:s0 + win + 1]
    w = np.clip(sub - 0.05 * sub.max(), 0, None)
    ll, ss = np.mgrid[l0 - win:l0 + win + 1, s0 - win:s0 + win + 1]
    centroid = np.array([(w * ss).sum() / w.sum(), (w * ll).sum() / w.sum()])
    assert np.linalg.norm(centroid - expected[0]) < 0.25, (centroid, expected)


def test_shadow_falls_on_the_anti_sun_side():
    """A 2 km hill under a sun 10 deg above the eastern horizon shades the ground west of it."""
    cam = mdis_wac(256)
    lat, lon = 0.0, 10.0
    surf = SpotOnHill(lat, lon, lat, lon, hill_height_m=2000.0, hill_sigma_m=5000.0, spot=False)
    c, r = _oblique_pose(cam, lat, lon, 250.0, 0.0, 0.0, twist_deg=0.0)
    sun = _sun(lat, lon, 80.0, 0.0)  # azimuth 0 = east
    img = render_reflectance(surf, cam, c, r, sun, RenderSettings())
    flat = render_reflectance(surf, cam, c, r, sun, RenderSettings(shadows=False))

    def at(dlon_km):
        x = latlon_to_xyz(lat, lon + np.degrees(dlon_km * 1e3 / DATUM_RADIUS_M), 0.0, datum_radius_m=DATUM_RADIUS_M)[None]
        px, _ = project(cam, c, r, x)
        s, l = np.round(px[0]).astype(int)
        return img[l, s], flat[l, s]

    west, west_flat = at(-12.0)
    east, _ = at(12.0)
    far_west, far_west_flat = at(-60.0)
    assert west < 0.05 * west_flat  # in the hill's shadow
    assert east > 0.5 * west_flat  # lit
    assert far_west == pytest.approx(far_west_flat, rel=1e-6)  # beyond the shadow


def test_rendering_is_bit_identical_for_the_same_seed():
    from mercury_dem.synth.terrain import Surface, SurfaceParams

    surf = Surface(SurfaceParams(seed=3, crater_d_min_m=5000.0))
    cam = mdis_wac(128)
    c, r = _oblique_pose(cam, -20.0, 100.0, 1500.0, 25.0, 10.0)
    sun = _sun(-20.0, 100.0, 60.0, 120.0)
    a = render_image(surf, cam, c, r, sun, np.random.default_rng(7))
    b = render_image(surf, cam, c, r, sun, np.random.default_rng(7))
    d = render_image(surf, cam, c, r, sun, np.random.default_rng(8))
    assert a.dtype == np.uint16 and a.shape == (128, 128) and a.max() <= 4095
    assert np.array_equal(a, b)
    assert not np.array_equal(a, d)  # the noise comes from the rng
    assert np.std(a.astype(float)) > 30  # there is a scene, not a flat field


def test_flat_ground_is_drawn_without_holes():
    """Every sub-sample of an oblique view of smooth ground is covered by a triangle (no gaps on shared edges)."""
    from mercury_dem.synth import raster as rs
    from mercury_dem.synth.render import footprint_grid, sun_direction

    cam = mdis_nac(256)
    surf = SpotOnHill(-40.0, 123.0, -40.0, 123.0, hill_height_m=800.0, hill_sigma_m=20e3, spot=False)
    c, r = _oblique_pose(cam, -40.0, 123.0, 300.0, 42.0, 200.0, twist_deg=17.0)
    sun = _sun(-40.0, 123.0, 30.0, 80.0)
    settings = RenderSettings(supersample=3)
    grid = footprint_grid(cam, c, r, sun, surf.radius_m, settings)
    points = grid.directions() * (surf.radius_m + surf.height_unit(grid.directions()))[..., None]
    uv, depth = rs.project_nodes(points, c, r, cam.focal_length_mm, cam.pixel_size_mm, cam.boresight_sample,
                                 cam.boresight_line, np.asarray(cam.distortion_x), np.asarray(cam.distortion_y), 3)
    tri, w1, w2 = rs.rasterize(uv, depth, 256 * 3, 256 * 3)
    assert (tri >= 0).all()
    assert w1.min() > -1e-6 and w2.min() > -1e-6 and (w1 + w2).max() < 1 + 1e-6
    img = render_reflectance(surf, cam, c, r, sun, settings)
    assert (img > 0).all() and sun_direction(grid, sun) @ grid.centre > 0.8


def test_psf_box_equals_gaussian_filter_then_box():
    from scipy.ndimage import gaussian_filter

    from mercury_dem.synth.raster import psf_box

    img = np.random.default_rng(3).random((48, 64))
    for ss, sigma in ((2, 0.6), (3, 1.1), (1, 0.0), (2, 0.0)):
        ref = gaussian_filter(img, sigma * ss, mode="nearest") if sigma > 0 else img
        ref = ref.reshape(48 // ss, ss, 64 // ss, ss).mean(axis=(1, 3)) if 48 % ss == 0 and 64 % ss == 0 else None
        if ref is None:
            continue
        assert np.allclose(psf_box(img, sigma, ss), ref, atol=1e-12)
