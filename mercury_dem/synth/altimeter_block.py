"""A block of laser-altimeter shots along near-polar ground tracks (profiles) over a known surface (a LOLA-like block).

What a user hands ``mercury-dem grid``: tens of thousands of shots along a few dozen
north-south tracks over a small area (LOLA: 28 Hz shots ~20-60 m apart along track,
tracks a few hundred metres apart at mid latitudes), radial noise of a metre or so.
:func:`altimeter_block` draws such a block from a height function and an ``rng``;
:class:`BlockSurface` is a plausible smooth surface for it (a regional slope, long waves,
a few degraded craters), known exactly so a DEM of the block can be checked against it.

Pure numpy, deterministic from the ``rng``; the body comes in as its datum radius.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.geometry.body import latlon_to_xyz

HeightFunction = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


@dataclass(frozen=True)
class BlockSurface:
    """A smooth surface about (lat0, lon0): heights in metres above the datum sphere of radius ``datum_radius_m``.

    height = regional slope (``slope`` m/m towards the north-east) + two long waves
    (``wave_m`` amplitude, 6 and 9 km wavelengths) + ``n_craters`` degraded bowls with
    rims (1.5-4 km across, depth 0.08 x diameter, positions and sizes from ``seed``),
    the largest slopes ~0.1-0.2 (about 8 deg on the bowls' walls).
    """

    lat0: float
    lon0: float
    datum_radius_m: float
    slope: float = 0.01
    wave_m: float = 40.0
    n_craters: int = 6
    seed: int = 0

    def _craters(self) -> NDArray[np.float64]:
        """(n, 3): centre east/north offsets (m) and diameter (m)."""
        rng = np.random.default_rng(self.seed)
        return np.column_stack([rng.uniform(-10e3, 10e3, self.n_craters), rng.uniform(-10e3, 10e3, self.n_craters),
                                rng.uniform(1.5e3, 4e3, self.n_craters)])

    def __call__(self, lat: ArrayLike, lon: ArrayLike) -> NDArray[np.float64]:
        la = np.asarray(lat, dtype=np.float64)
        dlon = (np.asarray(lon, dtype=np.float64) - self.lon0 + 180.0) % 360.0 - 180.0
        m_per_deg = math.pi * self.datum_radius_m / 180.0
        north = (la - self.lat0) * m_per_deg
        east = dlon * m_per_deg * math.cos(math.radians(self.lat0))
        h = self.slope * (east + north) / math.sqrt(2.0)
        h = h + self.wave_m * (np.sin(2 * math.pi * east / 6e3 + 0.4) * np.cos(2 * math.pi * north / 9e3 - 0.3))
        for ce, cn, d in self._craters():
            r = np.hypot(east - ce, north - cn) / (0.5 * d)  # radius in crater radii
            depth = 0.08 * d
            bowl = -depth * np.exp(-((r / 0.75) ** 2) * 1.5)
            rim = 0.25 * depth * np.exp(-(((r - 1.0) / 0.3) ** 2))
            h = h + bowl + rim
        return np.asarray(h, dtype=np.float64)


@dataclass(frozen=True)
class AltimeterBlock:
    """Shots of :func:`altimeter_block`: ``xyz`` (N, 3) body-fixed metres; ``lat``/``lon`` degrees (east, [0, 360));
    ``height`` m above the datum, noise included; ``profile_id`` (N,) the profile of each shot; ``profile_lon`` the
    profiles' longitudes at the block's centre latitude (degrees, dropped profiles excluded).
    """

    xyz: NDArray[np.float64]
    lat: NDArray[np.float64]
    lon: NDArray[np.float64]
    height: NDArray[np.float64]
    profile_id: NDArray[np.int64]
    profile_lon: NDArray[np.float64]


def altimeter_block(rng: np.random.Generator, datum_radius_m: float, height: HeightFunction, *,
                    lat_range: tuple[float, float], lon_range: tuple[float, float], n_profiles: int, n_shots: int,
                    noise_m: float = 1.0, spacing_jitter: float = 0.3, tilt_deg: float = 1.5,
                    drop_profiles: Sequence[int] = ()) -> AltimeterBlock:
    """Shots along ``n_profiles`` near-polar ground tracks (profiles) across a latitude/longitude block.

    Parameters
    ----------
    rng : the randomness (profile positions, shot times, noise)
    datum_radius_m : the body's datum sphere (heights are above it)
    height : truth height (m) as a function of latitude, longitude (degrees)
    lat_range, lon_range : the block, degrees; ``lon_range`` may cross 0 (e.g. (-0.4, 0.4)) or 180
    n_profiles : profiles, evenly spread in longitude over the block then moved by up to
        ``spacing_jitter`` x their spacing; ``drop_profiles`` (indices) are left out (gaps)
    n_shots : shots in all, shared evenly by the kept profiles, at random times along each
        (mean spacing the track's length over its shots)
    noise_m : 1-sigma radial noise added to the heights
    tilt_deg : the profiles' angle to the meridians (a near-polar orbit's ground track): a profile's
        longitude drifts by tan(tilt_deg) degrees per degree of latitude from the block's centre
    """
    lat0, lat1 = lat_range
    lon0, lon1 = lon_range
    spacing = (lon1 - lon0) / n_profiles
    centres = lon0 + (np.arange(n_profiles) + 0.5) * spacing
    centres = centres + rng.uniform(-spacing_jitter, spacing_jitter, n_profiles) * spacing
    keep = np.setdiff1d(np.arange(n_profiles), np.asarray(drop_profiles, dtype=np.int64))
    centres = np.sort(centres)[keep]
    per_profile = n_shots // keep.size
    lat = np.sort(rng.uniform(lat0, lat1, (keep.size, per_profile)), axis=1)
    mid = 0.5 * (lat0 + lat1)
    lon = centres[:, None] + math.tan(math.radians(tilt_deg)) * (lat - mid)
    # every shot stays inside the block's longitudes: the drift is clipped, not the profile moved
    lon = np.clip(lon, lon0, lon1)
    profile = np.repeat(keep, per_profile)
    lat = lat.ravel()
    lon = lon.ravel()
    h = height(lat, lon) + rng.normal(0.0, noise_m, lat.size)
    lon360 = np.mod(lon, 360.0)
    return AltimeterBlock(xyz=latlon_to_xyz(lat, lon360, h, datum_radius_m), lat=lat, lon=lon360, height=h,
                          profile_id=profile, profile_lon=np.mod(centres, 360.0))
