"""A small synthetic world for the matching tests: cratered terrain, poses, sun and a renderer.

Kept deliberately simple and local to the tests (Lambert shading on a height
field of parabolic craters with rims and a band-limited albedo, no cast
shadows, 2 x 2 supersampling, Gaussian noise): the truth errors of matches are
computed against exactly this surface. The mission renderer of
``mercury_dem.synth`` is used instead when it exists (see ``conftest.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_unit, latlon_to_xyz, xyz_to_latlon
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import image_to_ground, look_at_rotation, rotation_from_angles

SUN_DISTANCE_M = 5.8e10


class ToySurface:
    """Craters and albedo on a local patch around (lat0, lon0); flat datum far away."""

    def __init__(self, lat0: float = 10.0, lon0: float = 40.0, seed: int = 7, extent_m: float = 60e3,
                 n_craters: int = 260) -> None:
        rng = np.random.default_rng(seed)
        self.lat0, self.lon0 = lat0, lon0
        self.k = DATUM_RADIUS_M * np.pi / 180.0
        self.coslat = np.cos(np.radians(lat0))
        # Crater radii: power law between 120 m and 2.5 km.
        u = rng.random(n_craters)
        rmin, rmax = 120.0, 2500.0
        r = rmin * (1 - u * (1 - (rmin / rmax) ** 1.5)) ** (-1 / 1.5)
        self.cr = r
        self.cx = rng.uniform(-extent_m / 2, extent_m / 2, n_craters)
        self.cy = rng.uniform(-extent_m / 2, extent_m / 2, n_craters)
        self.depth = 0.18 * r
        self.rim = 0.04 * r
        # Albedo: sum of random plane waves, wavelengths 60 m .. 4 km.
        m = 48
        lam = np.exp(rng.uniform(np.log(60.0), np.log(4000.0), m))
        th = rng.uniform(0, 2 * np.pi, m)
        self.kx = 2 * np.pi / lam * np.cos(th)
        self.ky = 2 * np.pi / lam * np.sin(th)
        self.ph = rng.uniform(0, 2 * np.pi, m)
        self.amp = 0.5 * (lam / 4000.0) ** 0.35 / np.sqrt(m)

    def xy(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        dlon = (np.asarray(lon) - self.lon0 + 180.0) % 360.0 - 180.0
        return dlon * self.k * self.coslat, (np.asarray(lat) - self.lat0) * self.k

    def height_xy(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """Height and its gradient (h, dh/dx, dh/dy) at local east/north metres (1-D arrays)."""
        h = np.zeros_like(x)
        hx = np.zeros_like(x)
        hy = np.zeros_like(x)
        if x.size == 0:
            return h, hx, hy
        # Only craters whose reach (3 radii) touches the points' bounding box.
        sel = ((self.cx + 3 * self.cr >= x.min()) & (self.cx - 3 * self.cr <= x.max())
               & (self.cy + 3 * self.cr >= y.min()) & (self.cy - 3 * self.cr <= y.max()))
        cx, cy, cr, depth, rim = self.cx[sel], self.cy[sel], self.cr[sel], self.depth[sel], self.rim[sel]
        for s in range(0, x.size, 16384):
            xs, ys = x[s : s + 16384, None], y[s : s + 16384, None]
            dx, dy = xs - cx, ys - cy
            d2 = (dx * dx + dy * dy) / cr**2
            near = d2 < 9.0
            d = np.sqrt(d2)
            inside = d < 1.0
            e = np.exp(-((d - 1.0) ** 2) / 0.09)
            val = np.where(inside, depth * (d2 - 1.0) + rim, rim * e)
            # dval/dd
            dv = np.where(inside, 2.0 * depth * d, rim * e * (-2.0 * (d - 1.0) / 0.09))
            with np.errstate(divide="ignore", invalid="ignore"):
                ddx = np.where(d > 0, dx / (d * cr**2), 0.0)
                ddy = np.where(d > 0, dy / (d * cr**2), 0.0)
            val, dv = np.where(near, val, 0.0), np.where(near, dv, 0.0)
            h[s : s + 16384] = val.sum(1)
            hx[s : s + 16384] = (dv * ddx).sum(1)
            hy[s : s + 16384] = (dv * ddy).sum(1)
        return h, hx, hy

    def height(self, lat: NDArray[np.float64], lon: NDArray[np.float64]) -> NDArray[np.float64]:
        x, y = self.xy(lat, lon)
        return self.height_xy(np.ravel(x), np.ravel(y))[0].reshape(np.shape(x))

    def albedo_xy(self, x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.zeros_like(x)
        for s in range(0, x.size, 16384):
            arg = x[s : s + 16384, None] * self.kx + y[s : s + 16384, None] * self.ky + self.ph
            out[s : s + 16384] = (self.amp * np.sin(arg)).sum(1)
        return 0.12 * np.exp(out)

    def enu(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        up = latlon_to_unit(self.lat0, self.lon0)
        east = np.cross([0.0, 0.0, 1.0], up)
        east /= np.linalg.norm(east)
        return east, np.cross(up, east), up


@dataclass(frozen=True)
class View:
    camera: FramingCamera
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]  # true
    sun: NDArray[np.float64]


def sun_position(surface: ToySurface, incidence_deg: float, azimuth_deg: float) -> NDArray[np.float64]:
    e, n, u = surface.enu()
    i, a = np.radians(incidence_deg), np.radians(azimuth_deg)
    d = np.cos(i) * u + np.sin(i) * (np.sin(a) * e + np.cos(a) * n)
    return latlon_to_xyz(surface.lat0, surface.lon0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M) + SUN_DISTANCE_M * d


def make_view(surface: ToySurface, camera: FramingCamera, altitude_m: float, offset_east_m: float = 0.0,
              offset_north_m: float = 0.0, twist_deg: float = 0.0, incidence_deg: float = 45.0,
              azimuth_deg: float = 90.0, aim_east_m: float = 0.0, aim_north_m: float = 0.0) -> View:
    """A camera above the patch centre (offset), looking at the centre (offset by aim), twisted about the boresight."""
    e, n, u = surface.enu()
    centre = latlon_to_xyz(surface.lat0, surface.lon0, height_m=0.0, datum_radius_m=DATUM_RADIUS_M)
    c = centre + altitude_m * u + offset_east_m * e + offset_north_m * n
    target = centre + aim_east_m * e + aim_north_m * n
    r = look_at_rotation(c, target, n)
    r = rotation_from_angles(np.array([0.0, 0.0, np.radians(twist_deg)])) @ r
    return View(camera, c, r, sun_position(surface, incidence_deg, azimuth_deg))


def render(surface: ToySurface, view: View, rng: np.random.Generator, supersample: int = 2,
           noise_dn: float = 2.0, gain_dn: float = 9000.0) -> NDArray[np.uint16]:
    """12-bit image of the surface: Lambert shading x albedo, supersampled, Gaussian noise."""
    cam = view.camera
    k = supersample
    off = (np.arange(k) + 0.5) / k - 0.5
    ss, ll = np.meshgrid(np.arange(cam.samples, dtype=np.float64), np.arange(cam.lines, dtype=np.float64))
    e, n, u = surface.enu()
    px = np.concatenate([np.stack([(ss + ox).ravel(), (ll + oy).ravel()], -1) for oy in off for ox in off])
    g, hit = image_to_ground(cam, view.position, view.rotation, px, height=surface.height, tol_m=0.01, max_iter=12, datum_radius_m=DATUM_RADIUS_M)
    g = np.where(hit[:, None], g, 0.0)
    lat, lon, _ = xyz_to_latlon(g, datum_radius_m=DATUM_RADIUS_M)
    x, y = surface.xy(lat, lon)
    _, hx, hy = surface.height_xy(x, y)
    normal = -hx[:, None] * e - hy[:, None] * n + u
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    to_sun = view.sun - g
    to_sun /= np.linalg.norm(to_sun, axis=-1, keepdims=True)
    cosi = np.clip(np.sum(normal * to_sun, axis=-1), 0.0, None)
    val = np.where(hit, surface.albedo_xy(x, y) * cosi, 0.0)
    acc = val.reshape(k * k, *ss.shape).mean(axis=0)
    img = acc * gain_dn + rng.normal(0.0, noise_dn, ss.shape) + 20.0
    return np.clip(np.rint(img), 0, 4095).astype(np.uint16)


def perturb(rotation: NDArray[np.float64], sigma_rad: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """An a-priori rotation: the true one with a random pointing error (per axis sigma)."""
    return rotation_from_angles(rng.normal(0.0, sigma_rad, 3)) @ rotation
