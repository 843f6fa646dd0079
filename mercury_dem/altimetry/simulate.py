"""Synthetic MLA: laser-altimeter profiles of a synthetic mission's truth surface.

MESSENGER flew an eccentric near-polar orbit (periapsis 200-500 km at high northern latitude,
apoapsis ~15,000 km, 12 h then 8 h) and MLA ranged at 8 Hz only when the range was short
enough (a few hundred to ~1,500 km): dense profiles in the north, sparse to none in the
south. :func:`simulate_altimetry` reproduces that geometry and MLA's error budget:

* **orbit**: Keplerian ellipse about the body (GM of Mercury by default) with the design's
  periapsis/apoapsis altitudes, inclination and periapsis latitude (the argument of periapsis
  follows from ``sin(lat_p) = sin(i) sin(omega)``); one periapsis pass per orbit, its node
  longitude spread over the design's longitudes; the body turns under the pass at its
  rotation rate (Mercury: 58.646 d). Kepler's equation is solved by Newton iterations.
* **shots**: every ``1 / shot_rate_hz`` s (8 Hz: ~400 m apart near periapsis) while the
  range to the surface is below ``max_range_m``; nadir-pointing, so the true bounce point
  is the sub-spacecraft point at radius ``datum + height(lat, lon)`` of the truth surface.
* **errors**: range noise N(0, ``range_noise_m``); one orbit error per profile, constant in
  the orbit frame (along-profile, cross-profile, radial; 1-sigma ``along/cross/radial_sigma_m``),
  added to the spacecraft position the shot is geolocated from; ``bad_fraction`` of the
  shots are bad returns: half flagged noise detections (``flag`` 1, range anywhere in the gate),
  half unflagged wild ranges (N(0, ``wild_sigma_m``) added, as noise that passed the editing).

Nothing here is MDIS-specific and nothing reads a file: the truth surface comes in as a
function ``height(lat, lon) -> metres``. Written for this project because no library simulates
altimeter profiles from an arbitrary height function (pyXover's simulator needs SPICE kernels
of a real mission). Deterministic from the ``rng``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from mercury_dem.exceptions import ConfigError
from mercury_dem.geometry.body import wrap_longitude

#: Mercury's GM, m^3 s^-2 (MESSENGER gravity field GGMES, 2.2031815e13).
MERCURY_GM = 2.2031815e13
#: Mercury's sidereal rotation period, seconds (58.6462 d).
MERCURY_ROTATION_S = 58.6462 * 86400.0
#: The Moon's GM, m^3 s^-2 (GRAIL GL0660B, 4.9028e12), and its sidereal rotation period, seconds (27.3217 d).
MOON_GM = 4.9028e12
MOON_ROTATION_S = 27.321661 * 86400.0
#: (GM, rotation period) of each catalogued body by name, for a simulation of its orbiter.
ORBIT_CONSTANTS: dict[str, tuple[float, float]] = {"MERCURY": (MERCURY_GM, MERCURY_ROTATION_S),
                                                   "MOON": (MOON_GM, MOON_ROTATION_S)}
#: Start of the synthetic clock of the altimetry (seconds, like the images' ET-like times).
START_TIME_S = 2.0e8


@dataclass(frozen=True)
class AltimetryDesign:
    """How the synthetic MLA flies and errs (distances in metres, angles in degrees).

    n_orbits : periapsis passes simulated (one profile each; 0: no altimetry)
    lon_range_deg : (lon_min, lon_max) over which the passes' node longitudes are spread
        (east, may start below 0); None: the whole body
    periapsis_lat_deg, periapsis_alt_m, apoapsis_alt_m, inclination_deg : the orbit
    max_range_m : no shot beyond this range (MLA: ~1,500 km at nadir)
    shot_rate_hz : shots per second (MLA: 8 Hz)
    range_noise_m : 1-sigma range noise
    along_sigma_m, cross_sigma_m, radial_sigma_m : 1-sigma orbit error per profile
    bad_fraction : share of bad returns (half flagged, half wild unflagged ranges)
    wild_sigma_m : 1-sigma of the wild ranges
    orbit_period_s : time between passes (sets the synthetic clock; 12 h)
    area_margin_deg : a regional mission keeps shots within its area plus this margin
    """

    n_orbits: int = 0
    lon_range_deg: tuple[float, float] | None = None
    periapsis_lat_deg: float = 70.0
    periapsis_alt_m: float = 400e3
    apoapsis_alt_m: float = 15_000e3
    inclination_deg: float = 82.5
    max_range_m: float = 1_500e3
    shot_rate_hz: float = 8.0
    range_noise_m: float = 1.0
    along_sigma_m: float = 150.0
    cross_sigma_m: float = 100.0
    radial_sigma_m: float = 3.0
    bad_fraction: float = 0.03
    wild_sigma_m: float = 2000.0
    orbit_period_s: float = 43_200.0
    area_margin_deg: float = 1.0

    def __post_init__(self) -> None:
        if self.n_orbits < 0:
            raise ConfigError(f"altimetry n_orbits must be >= 0, got {self.n_orbits}")
        for name in ("periapsis_alt_m", "max_range_m", "shot_rate_hz", "orbit_period_s"):
            if not getattr(self, name) > 0:
                raise ConfigError(f"altimetry design '{name}' must be > 0, got {getattr(self, name)!r}")
        if not self.apoapsis_alt_m >= self.periapsis_alt_m:
            raise ConfigError("altimetry design: apoapsis_alt_m must be >= periapsis_alt_m")
        if not 0.0 < self.inclination_deg <= 90.0 or not abs(self.periapsis_lat_deg) <= self.inclination_deg:
            raise ConfigError("altimetry design: need 0 < inclination <= 90 deg and |periapsis_lat| <= inclination")
        if not 0.0 <= self.bad_fraction < 1.0:
            raise ConfigError(f"altimetry bad_fraction must be in [0, 1), got {self.bad_fraction}")
        for name in ("range_noise_m", "along_sigma_m", "cross_sigma_m", "radial_sigma_m", "wild_sigma_m"):
            if not getattr(self, name) >= 0:
                raise ConfigError(f"altimetry design '{name}' must be >= 0, got {getattr(self, name)!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True, eq=False)
class SimulatedAltimetry:
    """What :func:`simulate_altimetry` returns.

    shots : DataFrame, one row per shot as an RDR would give it, sorted by time: ``time``
        (s), ``lat``, ``lon``, ``radius_m``, ``profile_id``, ``range_m``, ``sc_lat``,
        ``sc_lon``, ``sc_radius_m`` (the reconstructed, i.e. erroneous, spacecraft position),
        ``flag`` (1 = flagged noise detection), ``sigma_m`` (= the range noise sigma)
    truth : DataFrame aligned with ``shots``: ``true_lat``, ``true_lon``, ``true_radius_m``,
        ``true_range_m``, ``bad`` (0 good, 1 flagged, 2 wild), ``offset_x_m``/``_y_m``/``_z_m``
        (the orbit error added to this shot, body-fixed)
    profiles : DataFrame, one row per profile: ``profile_id``, ``n_shots``, ``along_m``,
        ``cross_m``, ``radial_m`` (the injected orbit error, orbit frame), and at the profile's
        middle shot ``lat_mid``, ``lon_mid``, ``east_m``, ``north_m``, ``up_m`` (the same error in
        the local east/north/up frame there)
    """

    shots: pd.DataFrame
    truth: pd.DataFrame
    profiles: pd.DataFrame


def _kepler_e(mean_anomaly: NDArray[np.float64], e: float) -> NDArray[np.float64]:
    """Eccentric anomaly from the mean anomaly (Newton; |M| <= pi)."""
    ea = mean_anomaly + e * np.sin(mean_anomaly)
    for _ in range(30):
        step = (ea - e * np.sin(ea) - mean_anomaly) / (1.0 - e * np.cos(ea))
        ea = ea - step
        if np.max(np.abs(step), initial=0.0) < 1e-13:
            break
    return ea


def _unit(v: NDArray[np.float64]) -> NDArray[np.float64]:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _in_area(lat: NDArray[np.float64], lon: NDArray[np.float64], area: tuple[float, float, float, float] | None,
             margin: float) -> NDArray[np.bool_]:
    if area is None:
        return np.ones(lat.shape, bool)
    la0, la1, lo0, lo1 = area
    rel = np.mod(lon - (lo0 - margin), 360.0)
    return (lat >= la0 - margin) & (lat <= la1 + margin) & (rel <= (lo1 - lo0) + 2 * margin)


def simulate_altimetry(
    design: AltimetryDesign,
    height: Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]],
    rng: np.random.Generator,
    *,
    datum_radius_m: float,
    area_deg: tuple[float, float, float, float] | None = None,
    gm: float,
    rotation_period_s: float,
) -> SimulatedAltimetry:
    """Simulate MLA-like profiles of a truth surface (see the module docstring for the model).

    Parameters
    ----------
    design : AltimetryDesign
    height : callable (lat_deg (N,), lon_deg (N,)) -> ndarray (N,)
        True height above ``datum_radius_m``, metres (e.g. ``Surface.height``).
    rng : numpy.random.Generator
        The only source of randomness.
    datum_radius_m : float
        Radius heights are measured from, metres.
    area_deg : (lat_min, lat_max, lon_min, lon_max), optional
        Keep only shots within this area (+ ``design.area_margin_deg``): a regional mission.
    gm, rotation_period_s : float
        The body's GM (m^3 s^-2) and sidereal rotation period (s).

    Returns
    -------
    SimulatedAltimetry
    """
    d = design
    r_p = datum_radius_m + d.periapsis_alt_m
    r_a = datum_radius_m + d.apoapsis_alt_m
    a = 0.5 * (r_p + r_a)
    e = (r_a - r_p) / (r_a + r_p)
    p = a * (1.0 - e * e)
    n_mean = math.sqrt(gm / a**3)
    inc = math.radians(d.inclination_deg)
    argp = math.asin(math.sin(math.radians(d.periapsis_lat_deg)) / math.sin(inc))
    # True anomaly where the spacecraft is max_range above the datum (heights are small beside it).
    c = (p / (datum_radius_m + d.max_range_m) - 1.0) / e if e > 0 else 1.0
    nu_max = math.pi if c <= -1.0 else (0.0 if c >= 1.0 else math.acos(c))
    ea_max = 2.0 * math.atan(math.sqrt((1 - e) / (1 + e)) * math.tan(nu_max / 2.0)) if nu_max < math.pi else math.pi
    t_half = (ea_max - e * math.sin(ea_max)) / n_mean
    dt = 1.0 / d.shot_rate_hz
    t_rel = np.arange(-t_half, t_half + 1e-9, dt)
    ea = _kepler_e(n_mean * t_rel, e)
    nu = 2.0 * np.arctan2(np.sqrt(1 + e) * np.sin(ea / 2.0), np.sqrt(1 - e) * np.cos(ea / 2.0))
    r_orb = p / (1.0 + e * np.cos(nu))
    u = argp + nu
    lo0, lo1 = d.lon_range_deg if d.lon_range_deg is not None else (0.0, 360.0)
    n = d.n_orbits
    node = np.radians(lo0 + (np.arange(n) + rng.uniform(0.2, 0.8, n)) * (lo1 - lo0) / max(n, 1))
    spin = 2.0 * np.pi / rotation_period_s
    orbit_err = np.stack([rng.normal(0, d.along_sigma_m, n), rng.normal(0, d.cross_sigma_m, n),
                          rng.normal(0, d.radial_sigma_m, n)], -1)

    cols: dict[str, list[NDArray[Any]]] = {k: [] for k in ("t", "k", "s", "tang", "off")}
    for k in range(n):
        lam = node[k] - spin * t_rel  # the body turns east under the pass: the node drifts west
        cu, su = np.cos(u), np.sin(u)
        s_hat = np.stack([np.cos(lam) * cu - np.sin(lam) * su * math.cos(inc),
                          np.sin(lam) * cu + np.cos(lam) * su * math.cos(inc),
                          su * math.sin(inc)], -1)
        lat = np.degrees(np.arcsin(np.clip(s_hat[:, 2], -1, 1)))
        lon = np.degrees(np.arctan2(s_hat[:, 1], s_hat[:, 0]))
        keep = _in_area(lat, lon, area_deg, d.area_margin_deg)
        if not keep.any():
            continue
        sc = s_hat * r_orb[:, None]
        tang = np.gradient(sc, axis=0)  # along-profile direction (body-fixed), per shot
        idx = np.flatnonzero(keep)
        cols["t"].append(START_TIME_S + k * d.orbit_period_s + t_rel[idx])
        cols["k"].append(np.full(idx.size, k))
        cols["s"].append(sc[idx])
        cols["tang"].append(tang[idx])
    if not cols["t"]:
        return _empty()
    t = np.concatenate(cols["t"])
    profile = np.concatenate(cols["k"]).astype(np.int64)
    sc = np.concatenate(cols["s"])
    radial = _unit(sc)
    along = _unit(np.concatenate(cols["tang"]) - np.sum(np.concatenate(cols["tang"]) * radial, -1)[:, None] * radial)
    cross = np.cross(radial, along)
    true_lat = np.degrees(np.arcsin(np.clip(radial[:, 2], -1, 1)))
    true_lon = wrap_longitude(np.degrees(np.arctan2(radial[:, 1], radial[:, 0])))
    true_r = datum_radius_m + np.asarray(height(true_lat, true_lon), dtype=np.float64)
    sc_r = np.linalg.norm(sc, axis=-1)
    true_range = sc_r - true_r
    ok = true_range <= d.max_range_m
    t, profile, sc, radial, along, cross = t[ok], profile[ok], sc[ok], radial[ok], along[ok], cross[ok]
    true_lat, true_lon, true_r, true_range = true_lat[ok], true_lon[ok], true_r[ok], true_range[ok]
    m = t.size
    err = orbit_err[profile]
    offset = err[:, :1] * along + err[:, 1:2] * cross + err[:, 2:] * radial
    meas_range = true_range + rng.normal(0.0, d.range_noise_m, m)
    bad = np.zeros(m, np.int8)
    draw = rng.random(m)
    bad[draw < d.bad_fraction / 2] = 1
    bad[(draw >= d.bad_fraction / 2) & (draw < d.bad_fraction)] = 2
    gate = rng.uniform(-0.5, 0.5, m) * 20_000.0  # a noise detection anywhere in a 20 km range gate
    meas_range = np.where(bad == 1, true_range + gate, meas_range)
    meas_range = np.where(bad == 2, meas_range + rng.normal(0.0, d.wild_sigma_m, m), meas_range)
    sc_rec = sc + offset
    point = sc_rec - meas_range[:, None] * radial
    rad = np.linalg.norm(point, axis=-1)
    sc_rec_r = np.linalg.norm(sc_rec, axis=-1)
    shots = pd.DataFrame({
        "time": t,
        "lat": np.degrees(np.arcsin(np.clip(point[:, 2] / rad, -1, 1))),
        "lon": wrap_longitude(np.degrees(np.arctan2(point[:, 1], point[:, 0]))),
        "radius_m": rad, "profile_id": profile, "range_m": meas_range,
        "sc_lat": np.degrees(np.arcsin(np.clip(sc_rec[:, 2] / sc_rec_r, -1, 1))),
        "sc_lon": wrap_longitude(np.degrees(np.arctan2(sc_rec[:, 1], sc_rec[:, 0]))),
        "sc_radius_m": sc_rec_r, "flag": (bad == 1).astype(np.int64),
        "sigma_m": np.full(m, max(d.range_noise_m, 1e-3)),
    })
    truth = pd.DataFrame({
        "true_lat": true_lat, "true_lon": true_lon, "true_radius_m": true_r, "true_range_m": true_range,
        "bad": bad, "offset_x_m": offset[:, 0], "offset_y_m": offset[:, 1], "offset_z_m": offset[:, 2],
    })
    # Per profile: the injected error, and the same in east/north/up at the profile's middle shot.
    ids, first, counts = np.unique(profile, return_index=True, return_counts=True)
    mid = first + counts // 2
    lat_r, lon_r = np.radians(true_lat[mid]), np.radians(true_lon[mid])
    east = np.stack([-np.sin(lon_r), np.cos(lon_r), np.zeros_like(lon_r)], -1)
    north = np.stack([-np.sin(lat_r) * np.cos(lon_r), -np.sin(lat_r) * np.sin(lon_r), np.cos(lat_r)], -1)
    up = radial[mid]
    off_mid = offset[mid]
    profiles = pd.DataFrame({
        "profile_id": ids, "n_shots": counts, "along_m": orbit_err[ids, 0], "cross_m": orbit_err[ids, 1],
        "radial_m": orbit_err[ids, 2], "lat_mid": true_lat[mid], "lon_mid": true_lon[mid],
        "east_m": np.sum(off_mid * east, -1), "north_m": np.sum(off_mid * north, -1), "up_m": np.sum(off_mid * up, -1),
    })
    return SimulatedAltimetry(shots=shots, truth=truth, profiles=profiles)


def _empty() -> SimulatedAltimetry:
    shots = pd.DataFrame({c: np.zeros(0) for c in ("time", "lat", "lon", "radius_m", "range_m", "sc_lat", "sc_lon",
                                                   "sc_radius_m", "sigma_m")})
    shots["profile_id"] = np.zeros(0, np.int64)
    shots["flag"] = np.zeros(0, np.int64)
    truth = pd.DataFrame({c: np.zeros(0) for c in ("true_lat", "true_lon", "true_radius_m", "true_range_m", "bad",
                                                   "offset_x_m", "offset_y_m", "offset_z_m")})
    profiles = pd.DataFrame({c: np.zeros(0) for c in ("profile_id", "n_shots", "along_m", "cross_m", "radial_m",
                                                      "lat_mid", "lon_mid", "east_m", "north_m", "up_m")})
    return SimulatedAltimetry(shots, truth, profiles)


def screen_shots(shots: pd.DataFrame, datum_radius_m: float,
                 radius_tolerance_m: float = 25_000.0) -> tuple[pd.DataFrame, dict[str, int]]:
    """Drop what an RDR reader drops (:mod:`mercury_dem.reference.lola`): non-finite, off the body
    (beyond ``datum_radius_m`` ± tolerance), flagged; return the kept shots and the counts by reason.
    """
    lat, lon, rad = (shots[c].to_numpy(np.float64) for c in ("lat", "lon", "radius_m"))
    finite = np.isfinite(lat) & np.isfinite(lon) & np.isfinite(rad) & (np.abs(lat) <= 90)
    in_range = np.abs(rad - datum_radius_m) <= radius_tolerance_m
    unflagged = shots["flag"].to_numpy() == 0 if "flag" in shots else np.ones(len(shots), bool)
    dropped = {"malformed": 0, "bad_time": 0, "non_finite": int(np.sum(~finite)),
               "radius_out_of_range": int(np.sum(finite & ~in_range)),
               "flagged": int(np.sum(finite & in_range & ~unflagged))}
    return shots[finite & in_range & unflagged].reset_index(drop=True), dropped


__all__ = ["AltimetryDesign", "SimulatedAltimetry", "simulate_altimetry", "screen_shots", "MERCURY_GM",
           "MERCURY_ROTATION_S", "MOON_GM", "MOON_ROTATION_S", "ORBIT_CONSTANTS"]
