"""Rendered stereo pairs with known terrain for the dense tests (the scene; the fixtures are in conftest.py).

A nadir view and a view tilted 25 deg north of the same site (lat 5, lon 3; the truth ``Surface`` of
seed 42), MDIS-WAC 256^2 at 200 m/pixel, rendered by the mission renderer
(:func:`mercury_dem.synth.render.render_image`) from the true poses, which the tests use as the
adjusted cameras. Parallax/height ratio 0.466 (``tan 25``): one pixel of disparity is ~430 m of height.

Two photometries: ``lambert`` (``lambert_weight=1``: the shading depends on the sun only, so it is
the same in both views) and the renderer's default Lommel-Seeliger/Lambert mix, whose shading changes
with the emission angle and so differs between the views -- a matching error the window model cannot
see (docs/design/dense.md).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from mercury_dem.geometry.body import MERCURY, latlon_to_unit, latlon_to_xyz
from mercury_dem.geometry.camera import mdis_wac
from mercury_dem.geometry.pose import look_at_rotation
from mercury_dem.match.pretransform import ImageGeometry

LAT, LON = 5.0, 3.0
GSD_M = 200.0
SUN_DISTANCE_M = 5.8e10


def site_frame() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Centre (body-fixed m) and local east, north, up unit vectors of the test site."""
    up = latlon_to_unit(LAT, LON)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    return latlon_to_xyz(LAT, LON, 0.0, MERCURY.datum_radius_m), east, np.cross(up, east), up


def sun_at(incidence_deg: float, azimuth_deg: float) -> np.ndarray:
    """Sun position for an incidence and azimuth (deg clockwise from north) at the site."""
    centre, east, north, up = site_frame()
    i, a = np.radians(incidence_deg), np.radians(azimuth_deg)
    return centre + SUN_DISTANCE_M * (np.cos(i) * up + np.sin(i) * (np.sin(a) * east + np.cos(a) * north))


def view(tilt_north_deg: float, sun: np.ndarray, gsd_m: float = GSD_M, samples: int = 256,
         tilt_east_deg: float = 0.0) -> ImageGeometry:
    """A WAC view of the site from the range giving ``gsd_m`` at nadir, tilted north/east, aimed at the centre."""
    cam = mdis_wac(samples)
    centre, east, north, up = site_frame()
    alt = gsd_m / cam.ifov_rad
    tn, te = np.radians(tilt_north_deg), np.radians(tilt_east_deg)
    d = np.cos(tn) * np.cos(te) * up + np.sin(tn) * north + np.sin(te) * np.cos(tn) * east
    c = centre + alt * d / np.linalg.norm(d)
    return ImageGeometry.of(cam, c, look_at_rotation(c, centre, east), sun, MERCURY.datum_radius_m)


@dataclass
class RenderedPair:
    surface: Any
    left_image: np.ndarray
    right_image: np.ndarray
    left: ImageGeometry
    right: ImageGeometry
    settings: Any

    def truth_height(self, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        """The truth at the renderer's resolution (its grid is about one ground pixel)."""
        return np.asarray(self.surface.height(lat, lon, GSD_M))

    def current_surface(self, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
        """A 'current surface estimate': the truth without its detail finer than 1 km (a sparse DEM's view)."""
        return np.asarray(self.surface.height(lat, lon, 1000.0))


@functools.lru_cache(maxsize=1)
def truth_surface() -> Any:
    """The truth surface of seed 42 (built once: ~6 s on the shared machine)."""
    from mercury_dem.synth.terrain import Surface, SurfaceParams

    return Surface(SurfaceParams(seed=42))


def render_pair(settings: Any, incidence_deg: float = 45.0, seed: int = 3,
                right_view: dict[str, float] | None = None) -> RenderedPair:
    """The nadir / 25-deg-north pair rendered with ``settings`` under a sun ``incidence_deg`` from the east
    (``right_view``: other keyword arguments of :func:`view` for the right image).
    """
    pytest.importorskip("numba")
    from mercury_dem.synth.render import render_image

    surface = truth_surface()
    sun = sun_at(incidence_deg, 90.0)
    left = view(0.0, sun)
    right = view(sun=sun, **right_view) if right_view else view(25.0, sun)
    rng = np.random.default_rng(seed)
    imgs = [render_image(surface, g.camera, g.position, g.rotation, g.sun_position, rng, settings).astype(np.float32)
            for g in (left, right)]
    return RenderedPair(surface, imgs[0], imgs[1], left, right, settings)


def chip_of(pair: RenderedPair, chip: Any = None, height_margin_m: float = 800.0) -> Any:
    """The 224^2 chip (collar 16) in the middle of the left image, rectified about the 1-km surface."""
    from mercury_dem.dense.rectify import Chip, rectify_chip

    chip = chip or Chip(16, 16, 224, 224, 16)
    return rectify_chip(pair.left_image, pair.right_image, pair.left, pair.right, chip,
                        surface_height=pair.current_surface, height_margin_m=height_margin_m)


def true_disparity(pair: RenderedPair, rect: Any) -> tuple[np.ndarray, np.ndarray]:
    """The disparity (u_right - u_left) and vertical disparity, rectified pixels (H, W), of the truth surface
    at every rectified left pixel (its left ray intersected with the truth, projected into the right image).
    """
    from mercury_dem.geometry.pose import image_to_ground, project
    from mercury_dem.match.pretransform import apply_homography

    hh, ww = rect.left.shape
    vv, uu = np.mgrid[0:hh, 0:ww]
    rp = np.stack([uu.ravel(), vv.ravel()], -1).astype(np.float64)
    g, _ = image_to_ground(pair.left.camera, pair.left.position, pair.left.rotation,
                           apply_homography(rect.to_left, rp), height=pair.truth_height, tol_m=0.01,
                           datum_radius_m=pair.left.datum_radius_m)
    u2 = apply_homography(np.linalg.inv(rect.to_right), project(pair.right.camera, pair.right.position,
                                                                 pair.right.rotation, g)[0])
    return (u2[:, 0] - rp[:, 0]).reshape(hh, ww), (u2[:, 1] - rp[:, 1]).reshape(hh, ww)
