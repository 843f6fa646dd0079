"""Planning a synthetic MESSENGER-like mission: true poses, sun, and SPICE-like a-priori errors.

:func:`plan_mission` turns a :class:`~mercury_dem.synth.presets.MissionDesign`
and a seed into one row per image of TRUE geometry: instrument, image size,
spacecraft position and body->camera rotation, sun position, time. Images of a
pass cover the area about once; different passes differ in pixel scale (up to
the design's max/min ratio), incidence (sun elevation), sun azimuth, emission,
view azimuth and image twist, which gives the stereo convergence and the
matching difficulty of real data.

:func:`perturb_poses` gives the a-priori ("SPICE") poses: the true rotation
turned by a random small rotation of ``pointing_sigma_urad`` per camera axis
(``R_apriori = rotation_from_angles(omega) @ R_true``, the adjustment's own
parameterisation) and the true position moved by ``position_sigma`` per axis.

:func:`catalog_from_poses` derives what an image label carries from the
a-priori pose (centre latitude/longitude on the datum, pixel scale, angles,
tile id) — never from the truth.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from mercury_dem.geometry.body import DATUM_RADIUS_M, MERCURY, Body, latlon_to_unit, xyz_to_latlon
from mercury_dem.geometry.camera import FramingCamera, camera_preset
from mercury_dem.geometry.pose import look_at_rotation, rotation_from_angles
from mercury_dem.mission.catalog import ROTATION_COLUMNS, build_catalog
from mercury_dem.mission.radiometry import DN12
from mercury_dem.synth.presets import MissionDesign

#: Range of Mercury's distance from the sun, metres (0.31-0.47 AU).
SUN_DISTANCE_M = (4.6e10, 7.0e10)
#: Seconds between consecutive images (sets the synthetic clock; MET-like ids).
IMAGE_INTERVAL_S = 600.0
START_TIME_S = 2.0e8



def fibonacci_sphere(n: int) -> NDArray[np.float64]:
    """``n`` nearly uniform unit vectors (golden-angle spiral), shape (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5**0.5) * k
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


def _random_rotation(rng: np.random.Generator) -> NDArray[np.float64]:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _pass_centres(design: MissionDesign, rng: np.random.Generator, spacing_m: float, radius_m: float) -> NDArray[np.float64]:
    """Image centres (lat, lon) of one pass, shape (n, 2)."""
    if design.area_deg is None:
        n = max(1, int(round(4.0 * np.pi * radius_m**2 / spacing_m**2)))
        u = fibonacci_sphere(n) @ _random_rotation(rng).T
        lat, lon, _ = xyz_to_latlon(u, 1.0)
        return np.stack([lat, lon], -1)
    la0, la1, lo0, lo1 = design.area_deg
    spacing_deg = np.degrees(spacing_m / radius_m)
    n_lat = max(1, int(np.ceil((la1 - la0) / spacing_deg)))
    step_lat = (la1 - la0) / n_lat
    out = []
    shift = rng.uniform(-0.2, 0.2, 2)
    for i in range(n_lat):
        lat_c = la0 + (i + 0.5 + shift[0]) * step_lat
        width = (lo1 - lo0) * np.cos(np.radians(lat_c))
        n_lon = max(1, int(np.ceil(width / spacing_deg)))
        step_lon = (lo1 - lo0) / n_lon
        for k in range(n_lon):
            jit = rng.uniform(-0.15, 0.15, 2)
            out.append((lat_c + jit[0] * step_lat, lo0 + (k + 0.5 + shift[1] + jit[1]) * step_lon))
    c = np.array(out)
    c[:, 0] = np.clip(c[:, 0], -89.0, 89.0)
    return c


def plan_mission(design: MissionDesign, seed: int, radius_m: float = DATUM_RADIUS_M) -> pd.DataFrame:
    """True geometry of every image of a design.

    Returns
    -------
    DataFrame, one row per image: image_id, instrument, samples, lines, time (s),
    true_position_x/_y/_z (m), true_rotation_00.._22 (body->camera), sun_x/_y/_z (m),
    target_lat, target_lon (aim point, deg), design_pixel_scale_m, design_incidence_deg,
    design_emission_deg, pass_id (-1 for isolated images).
    """
    rng = np.random.default_rng([seed, 0x4D15])
    lo, hi = design.pixel_scale_m
    median_w = design.samples * np.sqrt(lo * hi)
    targets: list[tuple[float, float, int]] = []
    gap_units = latlon_to_unit([g[0] for g in design.gaps], [g[1] for g in design.gaps]).reshape(-1, 3)
    gap_cos = np.cos(np.radians([g[2] for g in design.gaps]))
    for p in range(design.passes):
        for lat, lon in _pass_centres(design, rng, design.spacing_factor * median_w, radius_m):
            if gap_units.size and np.any(gap_units @ latlon_to_unit(lat, lon) > gap_cos):
                continue
            targets.append((lat, lon, p))
    for lat, lon in design.isolated:
        targets.append((lat, lon, -1))
    n = len(targets)
    t = np.array(targets)
    lat, lon, pass_id = t[:, 0], np.mod(t[:, 1], 360.0), t[:, 2].astype(np.int64)
    scale = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
    camp = np.asarray(design.sun_campaigns, dtype=np.float64).reshape(-1, 4)
    c = camp[np.where(pass_id >= 0, pass_id, 0) % len(camp)]
    inc = np.clip(rng.uniform(c[:, 2], c[:, 3]), *design.incidence_deg)
    sun_az = np.radians(c[:, 0] + rng.uniform(-1.0, 1.0, n) * c[:, 1])
    emi = rng.uniform(*design.emission_deg, n)
    view_az = rng.uniform(0.0, 2 * np.pi, n)
    twist = rng.uniform(0.0, 2 * np.pi, n)
    pick_nac = rng.random(n) < design.nac_fraction
    sun_dist = rng.uniform(*SUN_DISTANCE_M, n)
    nac = camera_preset("MDIS-NAC", design.samples)
    wac = camera_preset("MDIS-WAC", design.samples)
    slant_nac = scale / nac.ifov_rad
    use_nac = pick_nac & (slant_nac <= design.nac_max_slant_m)
    slant = np.where(use_nac, slant_nac, scale / wac.ifov_rad)

    up = latlon_to_unit(lat, lon)
    east = np.stack([-np.sin(np.radians(lon)), np.cos(np.radians(lon)), np.zeros(n)], -1)
    pole = np.linalg.norm(east, axis=-1) < 1e-9
    east[pole] = (1.0, 0.0, 0.0)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    north = np.cross(up, east)
    target = up * radius_m

    def direction(angle_deg: NDArray[np.float64], az: NDArray[np.float64]) -> NDArray[np.float64]:
        a = np.radians(angle_deg)[:, None]
        return np.cos(a) * up + np.sin(a) * (np.cos(az)[:, None] * east + np.sin(az)[:, None] * north)

    position = target + slant[:, None] * direction(emi, view_az)
    sun = target + sun_dist[:, None] * direction(inc, sun_az)
    rot = look_at_rotation(position, target, np.array([0.0, 0.0, 1.0]))
    rot = rotation_from_angles(np.stack([np.zeros(n), np.zeros(n), twist], -1)) @ rot

    time = START_TIME_S + IMAGE_INTERVAL_S * np.arange(n)
    df = pd.DataFrame({
        "instrument": np.where(use_nac, "MDIS-NAC", "MDIS-WAC"),
        "samples": design.samples,
        "lines": design.samples,
        "target_lat": lat,
        "target_lon": lon,
        "design_pixel_scale_m": scale,
        "design_incidence_deg": inc,
        "design_emission_deg": emi,
        "pass_id": pass_id,
    })
    df.insert(0, "time", time)
    met = np.round(time).astype(np.int64)
    df.insert(0, "image_id", [f"{'EN' if i == 'MDIS-NAC' else 'EW'}{m:010d}{'M' if i == 'MDIS-NAC' else 'G'}"
                              for i, m in zip(df["instrument"], met)])
    for k, ax in enumerate("xyz"):
        df[f"true_position_{ax}"] = position[:, k]
    for k, col in enumerate(ROTATION_COLUMNS):
        df["true_" + col] = rot.reshape(-1, 9)[:, k]
    for k, ax in enumerate("xyz"):
        df[f"sun_{ax}"] = sun[:, k]
    return df


def true_poses(plan: pd.DataFrame) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """True positions (N, 3) and rotations (N, 3, 3) of a plan."""
    c = plan[[f"true_position_{a}" for a in "xyz"]].to_numpy(dtype=np.float64)
    r = plan[["true_" + col for col in ROTATION_COLUMNS]].to_numpy(dtype=np.float64).reshape(-1, 3, 3)
    return c, r


def perturb_poses(
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    pointing_sigma_urad: float,
    position_sigma_m: float,
    rng: np.random.Generator,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """A-priori poses: (positions (N, 3), rotations (N, 3, 3), pointing errors omega (N, 3) rad).

    ``R_apriori = rotation_from_angles(omega) @ R_true`` with omega ~ N(0, sigma^2) per camera axis;
    ``C_apriori = C_true + N(0, position_sigma^2)`` per body axis.
    """
    n = positions.shape[0]
    omega = rng.normal(0.0, pointing_sigma_urad * 1e-6, (n, 3))
    dpos = rng.normal(0.0, position_sigma_m, (n, 3))
    return positions + dpos, rotation_from_angles(omega) @ rotations, omega


def mission_cameras(plan: pd.DataFrame) -> tuple[dict[str, FramingCamera], list[str]]:
    """The camera table of a plan (one MDIS preset per instrument and image size) and each image's camera id."""
    ids = [f"{inst}@{int(s)}" for inst, s in zip(plan["instrument"].astype(str), plan["samples"])]
    cameras = {k: camera_preset(k.partition("@")[0], int(k.partition("@")[2])) for k in sorted(set(ids))}
    return cameras, ids


def catalog_from_poses(
    plan: pd.DataFrame,
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    tile_size_deg: float = 10.0,
    body: Body = MERCURY,
) -> pd.DataFrame:
    """The image catalog of a plan from its A-PRIORI poses (the mission's one catalog builder)."""
    cameras, cam_ids = mission_cameras(plan)
    n = len(plan)
    return build_catalog(
        plan["image_id"].astype(str).to_numpy(), plan["instrument"].astype(str).to_numpy(), cameras, cam_ids,
        plan["time"].to_numpy(np.float64), positions, rotations,
        plan[[f"sun_{a}" for a in "xyz"]].to_numpy(np.float64), body, tile_size_deg, [DN12] * n,
    )


__all__ = [
    "plan_mission",
    "perturb_poses",
    "true_poses",
    "catalog_from_poses",
    "mission_cameras",
    "fibonacci_sphere",
]
