"""The block footprint of the dense DEM's hole fraction: which grid pixels the images see, and holes within it."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from mercury_dem.dense.footprint import hole_fractions, views_per_pixel
from mercury_dem.geometry.body import latlon_to_xyz
from mercury_dem.geometry.camera import mdis_nac
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.products.ortho import image_footprint

R = 2_439_400.0


def _nadir(lat: float, lon: float, altitude_m: float) -> SimpleNamespace:
    cam = mdis_nac(64, distortion=False)
    c = latlon_to_xyz(lat, lon, height_m=altitude_m, datum_radius_m=R)
    return SimpleNamespace(camera=cam, position=c, rotation=look_at_rotation(c, latlon_to_xyz(lat, lon, 0.0, R)))


def test_views_follow_each_image_frame_and_count_the_overlap() -> None:
    """Each image's seen pixels span its footprint traced by its edge rays (products.ortho.image_footprint,
    an independent ray-sphere path) to a grid pixel; the overlap of two images counts 2, far ground 0."""
    a, b = _nadir(0.0, 100.0, 200e3), _nadir(0.0, 100.1, 200e3)
    step = 0.002
    lat = np.arange(-0.3, 0.3 + step / 2, step)
    lon = np.arange(99.7, 100.4 + step / 2, step)
    h = np.zeros((lat.size, lon.size))
    h[0, 0] = np.nan  # a NaN height is taken at the median height
    views = views_per_pixel(lat, lon, h, [a, b], R)
    for g, k in ((a, 0), (b, 1)):
        flat, flon = image_footprint(g.camera, g.position, g.rotation, datum_radius_m=R, height_range_m=(0.0, 0.0))
        seen = views_per_pixel(lat, lon, h, [g], R).astype(bool)
        cols = lon[seen.any(axis=0)]
        rows = lat[seen.any(axis=1)]
        assert abs(cols.min() - flon.min()) <= step and abs(cols.max() - flon.max()) <= step, k
        assert abs(rows.min() - flat.min()) <= step and abs(rows.max() - flat.max()) <= step, k
    i0 = int(np.argmin(np.abs(lat)))
    assert views[i0, int(np.argmin(np.abs(lon - 100.05)))] == 2
    assert views[i0, int(np.argmin(np.abs(lon - 99.71)))] == 0 and views.max() == 2


def test_hole_fractions_count_only_the_footprint() -> None:
    fp = np.zeros((4, 5), bool)
    fp[1:3, 1:4] = True  # 6 pixels
    full = np.ones((4, 5))
    patchy = full.copy()
    patchy[1, 1] = np.nan  # one hole inside
    patchy[0, :] = np.nan  # holes outside do not count
    out = hole_fractions(fp, {"full": full, "patchy": patchy})
    assert out == {"footprint_pixels": 6, "full": 0.0, "patchy": 1 / 6}
    assert hole_fractions(np.zeros((2, 2), bool), {"x": full[:2, :2]}) == {"footprint_pixels": 0, "x": None}
