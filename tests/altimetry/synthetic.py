"""A synthetic truth for the registration tests: an analytic surface, a DEM of it moved by a known
rigid transform, and altimetry profiles of the true surface with known per-profile offsets.

Written independently of :mod:`mercury_dem.altimetry` (its own ENU frames and inverse mapping),
so a sign or frame error there is not shared by the truth.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

R_DATUM = 2_439_400.0


def unit(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    return np.stack([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)], axis=-1)


def enu(lat, lon):
    la, lo = np.radians(lat), np.radians(lon)
    e = np.array([-np.sin(lo), np.cos(lo), 0.0])
    n = np.array([-np.sin(la) * np.cos(lo), -np.sin(la) * np.sin(lo), np.cos(la)])
    u = np.array([np.cos(la) * np.cos(lo), np.cos(la) * np.sin(lo), np.sin(la)])
    return np.stack([e, n, u], axis=1)


class Surface:
    """A sum of plane waves on the sphere (wavelengths 25-150 km, ~1 km relief)."""

    def __init__(self, rng: np.random.Generator, n_waves: int = 12):
        self.k = rng.normal(size=(n_waves, 3))
        self.k /= np.linalg.norm(self.k, axis=1)[:, None]
        lam = rng.uniform(25e3, 150e3, n_waves)
        self.freq = 2 * np.pi * R_DATUM / lam  # radians of phase per radian of arc
        self.amp = 900.0 * (lam / 150e3) ** 1.0 / np.sqrt(n_waves / 4)
        self.phase = rng.uniform(0, 2 * np.pi, n_waves)

    def height(self, lat, lon):
        u = unit(np.asarray(lat, float), np.asarray(lon, float))
        proj = u @ self.k.T
        return np.sum(self.amp * np.sin(self.freq * proj + self.phase), axis=-1)


@dataclass
class Rigid:
    """D(p) = c + Rot (p - c) + E t, rotation about the local up axis at c."""

    centre: tuple[float, float]
    t_enu: np.ndarray
    angle_up_deg: float = 0.0
    tilt_east_deg: float = 0.0

    def parts(self):
        E = enu(*self.centre)
        c = R_DATUM * E[:, 2]
        a = np.radians(self.angle_up_deg)
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        b = np.radians(self.tilt_east_deg)
        Rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
        Rot = E @ (Rz @ Rx) @ E.T
        return c, Rot, E @ np.asarray(self.t_enu, float)

    def inverse(self, y):
        c, Rot, t = self.parts()
        return c + (y - c - t) @ Rot  # Rot^-1 = Rot^T


def moved_dem(surface: Surface, D: Rigid, lat, lon):
    """Heights of the surface moved by D, on the grid (lat, lon): the ray through each node meets D(surface)."""
    LA, LO = np.meshgrid(lat, lon, indexing="ij")
    u = unit(LA, LO)
    rho = np.full(LA.shape, R_DATUM)
    for _ in range(30):
        y = D.inverse(rho[..., None] * u)
        r = np.linalg.norm(y, axis=-1)
        la = np.degrees(np.arcsin(y[..., 2] / r))
        lo = np.degrees(np.arctan2(y[..., 1], y[..., 0])) % 360
        F = r - R_DATUM - surface.height(la, lo)
        rho = rho - F
        if np.max(np.abs(F)) < 1e-3:
            break
    return rho - R_DATUM


@dataclass
class Profiles:
    lat: np.ndarray
    lon: np.ndarray
    radius: np.ndarray
    profile_id: np.ndarray
    offset_enu: np.ndarray  # (n_profiles, 3) injected error of each track (measured - true), metres


def profiles(surface: Surface, rng, bounds, n_profiles=40, spacing_deg=0.01, noise_m=1.0,
             sigma_h_m=150.0, sigma_v_m=5.0):
    """Near-polar tracks across the bounds, with a 3-D error per track and Gaussian range noise."""
    lat0, lat1, lon0, lon1 = bounds
    lats, lons, rads, tracks, offs = [], [], [], [], []
    for k in range(n_profiles):
        lo_start = rng.uniform(lon0, lon1)
        incl = rng.uniform(-0.15, 0.15)  # degrees of longitude per degree of latitude
        la = np.arange(lat0, lat1, spacing_deg) + rng.uniform(0, spacing_deg)
        lo = lo_start + incl * (la - la.mean())
        inside = (lo > lon0) & (lo < lon1)
        la, lo = la[inside], lo[inside]
        if la.size < 2:
            continue
        o = np.array([rng.normal(0, sigma_h_m), rng.normal(0, sigma_h_m), rng.normal(0, sigma_v_m)])
        p = unit(la, lo) * (R_DATUM + surface.height(la, lo))[:, None]
        E = enu(la.mean(), lo.mean())
        p = p + E @ o
        r = np.linalg.norm(p, axis=1)
        lats.append(np.degrees(np.arcsin(p[:, 2] / r)))
        lons.append(np.degrees(np.arctan2(p[:, 1], p[:, 0])) % 360)
        rads.append(r + rng.normal(0, noise_m, r.size))
        tracks.append(np.full(la.size, len(offs)))
        offs.append(o)
    return Profiles(np.concatenate(lats), np.concatenate(lons), np.concatenate(rads), np.concatenate(tracks),
                    np.array(offs))
