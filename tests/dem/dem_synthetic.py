"""Synthetic point clouds on a known smooth surface (helpers for tests/dem)."""

from __future__ import annotations

import numpy as np

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz

NOISE_M = 20.0  # 1-sigma radial noise injected into the points


def truth_height(lat, lon):
    """A smooth known surface: metres above the 2439.4 km datum."""
    la, lo = np.radians(lat), np.radians(lon)
    return 1500.0 * np.sin(2 * la) * np.cos(3 * lo) + 800.0 * np.cos(la) * np.sin(2 * lo + 0.3)


def sample_cloud(rng, n, lat_range=(-90.0, 90.0), lon_range=(0.0, 360.0), noise=NOISE_M, outlier_fraction=0.0):
    """n points uniform in area inside a lat/lon box, on the truth surface plus noise (and outliers)."""
    z = rng.uniform(np.sin(np.radians(lat_range[0])), np.sin(np.radians(lat_range[1])), n)
    lat = np.degrees(np.arcsin(z))
    lon = rng.uniform(lon_range[0], lon_range[1], n)
    h = truth_height(lat, lon) + rng.normal(0.0, noise, n)
    out = rng.random(n) < outlier_fraction
    h[out] += rng.choice([-3000.0, 3000.0], int(out.sum()))
    return latlon_to_xyz(lat, lon, h, datum_radius_m=DATUM_RADIUS_M)
