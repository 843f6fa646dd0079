"""Synthetic control networks with a known truth, for testing and benchmarking the adjustment.

Geometry meant to look like MESSENGER's: MDIS-like cameras (NAC and WAC, 512 x 512
after summing) 200-1500 km above a 2439.4 km sphere carrying a few hundred
metres to kilometres of smooth relief, looking up to ~25 deg off nadir; image
footprints scattered over a spherical cap sized so each ground point is seen by
about ``coverage`` images; points on the true surface, each measured in 2 to
``max_views`` of the images that see it. Measures are true projections plus
Gaussian noise plus a fraction of gross outliers. The a-priori pointing is the
truth rotated by ``N(0, pointing_sigma_urad)`` per camera axis (the problem states that sigma); a-priori points
are the least-squares intersection of the a-priori rays of their measures
(the datum intersection of one ray when the rays are too close to parallel).

Everything is vectorized (chunks of points), so 5e6 measures take a minute or so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.adjust.schur import inv3
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.camera import FramingCamera, mdis_nac, mdis_wac
from mercury_dem.geometry.pose import angles_from_rotation, intersect_sphere, look_at_rotation, rotation_from_angles


@dataclass(frozen=True)
class SyntheticNetwork:
    """A-priori problem plus the truth it was made from.

    Attributes
    ----------
    problem : the a-priori :class:`AdjustmentProblem`
    true_rotations : (n_img, 3, 3); true_positions : (n_img, 3) m; true_points : (n_pt, 3) m
    outlier : (M,) bool, measures displaced by a gross error
    pointing_error : (n_img, 3) rad, the a-priori pointing error injected (rotation vector, camera frame)
    relief_m, relief_seed : the true surface's relief parameters (:meth:`true_radius`)
    """

    problem: AdjustmentProblem
    true_rotations: NDArray[np.float64]
    true_positions: NDArray[np.float64]
    true_points: NDArray[np.float64]
    outlier: NDArray[np.bool_]
    pointing_error: NDArray[np.float64]
    relief_m: float = 0.0
    relief_seed: int = 0

    def true_radius(self, unit: NDArray[np.float64]) -> NDArray[np.float64]:
        """The true surface's radius (m) along body-fixed unit vectors (N, 3): e.g. simulated altimetry."""
        return DATUM_RADIUS_M + plane_wave_relief(np.asarray(unit, np.float64).reshape(-1, 3), self.relief_m, self.relief_seed)

    def altimetry_shots(self, rng: np.random.Generator, per_point: int = 8, reach_m: float = 700.0,
                        noise_m: float = 1.0) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """Simulated altimetry on the true surface, as (lat deg, lon deg in [0, 360), radius m).

        ``per_point`` shots scattered within ``reach_m`` around each of a random half of the true points, radius
        noise ``noise_m`` (1-sigma).
        """
        pts = self.true_points[rng.random(len(self.true_points)) < 0.5]
        u = pts / np.linalg.norm(pts, axis=1, keepdims=True)
        u = np.repeat(u, per_point, axis=0)
        off = rng.normal(size=u.shape)
        off -= (off * u).sum(1, keepdims=True) * u
        off *= (rng.uniform(0, reach_m, len(u)) / DATUM_RADIUS_M / np.linalg.norm(off, axis=1))[:, None]
        u = (u + off) / np.linalg.norm(u + off, axis=1, keepdims=True)
        r = self.true_radius(u) + rng.normal(0, noise_m, len(u))
        return np.degrees(np.arcsin(u[:, 2])), np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360, r


def plane_wave_relief(unit: NDArray[np.float64], relief_m: float, seed: int) -> NDArray[np.float64]:
    """Smooth heights (N,) from unit vectors: a sum of six plane waves on the sphere."""
    g = np.random.default_rng(seed)
    dirs = g.normal(size=(6, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    freq = g.uniform(20.0, 200.0, 6)  # wavelengths ~75-750 km on Mercury
    phase = g.uniform(0.0, 2 * np.pi, 6)
    amp = relief_m / np.sqrt(np.arange(1, 7))
    return (np.sin((unit @ dirs.T) * freq + phase) * amp).sum(axis=1) / 2.0


def _cap_samples(n: int, cos_alpha: float, rng: np.random.Generator) -> NDArray[np.float64]:
    """Unit vectors (n, 3) uniform over the cap of angular radius alpha about +X."""
    x = 1.0 - rng.random(n) * (1.0 - cos_alpha)
    phi = rng.uniform(0.0, 2 * np.pi, n)
    s = np.sqrt(np.maximum(1.0 - x * x, 0.0))
    return np.stack([x, s * np.cos(phi), s * np.sin(phi)], axis=1)


def footprint_area_m2(camera: FramingCamera, altitude_m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Nadir footprint area of images taken from ``altitude_m``, square metres."""
    return (camera.samples * camera.ifov_rad * altitude_m) * (camera.lines * camera.ifov_rad * altitude_m)


def make_synthetic_network(
    n_measures: int = 100_000,
    *,
    rng: np.random.Generator,
    noise_px: float = 0.25,
    outlier_fraction: float = 0.01,
    outlier_px: tuple[float, float] = (5.0, 50.0),
    pointing_sigma_urad: float = 450.0,
    position_error_m: float = 0.0,
    altitude_km: tuple[float, float] = (200.0, 1500.0),
    wac_fraction: float = 0.1,
    wac_altitude_km: tuple[float, float] = (200.0, 500.0),
    samples: int = 512,
    measures_per_image: int = 100,
    min_views: int = 2,
    max_views: int = 5,
    coverage: float = 5.0,
    max_emission_deg: float = 25.0,
    relief_m: float = 2000.0,
    measure_sigma_px: float = 1.0,
    chunk_points: int = 200_000,
) -> SyntheticNetwork:
    """A synthetic network of about ``n_measures`` measures (the count is approximate).

    Each point is measured in ``min_views`` to ``max_views`` images (fewer when
    fewer see it; points seen by fewer than ``min_views`` are dropped).
    ``measure_sigma_px`` is the sigma written into the problem (what an operator
    would assume), independent of the injected ``noise_px``.
    """
    nac, wac = mdis_nac(samples), mdis_wac(samples)
    cameras = (nac, wac)
    n_img = max(4, int(round(n_measures / measures_per_image)))
    is_wac = rng.random(n_img) < wac_fraction
    alt = np.where(
        is_wac, rng.uniform(*wac_altitude_km, n_img), rng.uniform(*altitude_km, n_img)
    ) * 1e3
    area = np.where(is_wac, footprint_area_m2(wac, alt), footprint_area_m2(nac, alt))
    cap_area = float(area.sum()) / coverage
    cos_alpha = max(-1.0, 1.0 - cap_area / (2 * np.pi * DATUM_RADIUS_M**2))
    # Image targets in the cap; spacecraft above a point displaced by up to max_emission.
    target_u = _cap_samples(n_img, cos_alpha, rng)
    seed = int(rng.integers(1 << 31))
    target = target_u * (DATUM_RADIUS_M + plane_wave_relief(target_u, relief_m, seed))[:, None]
    emission = np.radians(rng.uniform(0.0, max_emission_deg, n_img))
    tangent = np.cross(target_u, rng.normal(size=(n_img, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    offset = alt * np.tan(emission)
    sub = target_u * DATUM_RADIUS_M + tangent * offset[:, None]
    positions = sub / np.linalg.norm(sub, axis=1, keepdims=True) * (DATUM_RADIUS_M + alt)[:, None]
    rot_true = look_at_rotation(positions, target)
    image_camera = is_wac.astype(np.int64)
    # Points on the true surface, uniform in the cap.
    mean_views = (min_views + max_views) / 2.0
    n_pt = max(4, int(n_measures / mean_views * 1.15))
    pt_u = _cap_samples(n_pt, cos_alpha, rng)
    points = pt_u * (DATUM_RADIUS_M + plane_wave_relief(pt_u, relief_m, seed))[:, None]
    # Candidate images: the nearest image targets; visibility by projection.
    tree = cKDTree(target_u)
    k_cand = min(32, n_img)
    wanted = rng.integers(min_views, max_views + 1, n_pt)
    m_img, m_pt, m_px = [], [], []
    for s in range(0, n_pt, chunk_points):
        e = min(s + chunk_points, n_pt)
        _, cand = tree.query(pt_u[s:e], k=k_cand)
        cand = cand.reshape(e - s, k_cand)
        px = np.full(cand.shape + (2,), np.nan)
        vis = np.zeros(cand.shape, bool)
        for k, cam in enumerate(cameras):
            sel = image_camera[cand] == k
            ii = cand[sel]
            rows = np.nonzero(sel)[0] + s
            v = np.matmul(rot_true[ii], (points[rows] - positions[ii])[:, :, None])[:, :, 0]
            p = cam.camera_to_pixel(v)
            ok = (v[:, 2] > 0) & cam.in_image(p, margin=2.0)
            ok &= np.all(np.isfinite(p), axis=1)
            px[sel] = p
            vis[sel] = ok
        keys = np.where(vis, rng.random(vis.shape), 2.0)
        order = np.argsort(keys, axis=1)
        rank = np.empty_like(order)
        np.put_along_axis(rank, order, np.arange(k_cand)[None, :].repeat(e - s, 0), axis=1)
        take = vis & (rank < wanted[s:e, None])
        take &= (take.sum(axis=1) >= min_views)[:, None]
        r_idx, c_idx = np.nonzero(take)
        m_img.append(cand[r_idx, c_idx])
        m_pt.append(r_idx + s)
        m_px.append(px[r_idx, c_idx])
    meas_img = np.concatenate(m_img)
    meas_pt = np.concatenate(m_pt)
    true_px = np.concatenate(m_px)
    # Keep only measured points and images; renumber.
    used_pt, meas_pt = np.unique(meas_pt, return_inverse=True)
    used_img, meas_img = np.unique(meas_img, return_inverse=True)
    points = points[used_pt]
    positions, rot_true, image_camera = positions[used_img], rot_true[used_img], image_camera[used_img]
    n_img, m = len(used_img), len(meas_img)
    measures = true_px + rng.normal(0.0, noise_px, true_px.shape)
    outlier = rng.random(m) < outlier_fraction
    ang = rng.uniform(0, 2 * np.pi, int(outlier.sum()))
    mag = rng.uniform(*outlier_px, int(outlier.sum()))
    measures[outlier] += np.stack([np.cos(ang), np.sin(ang)], axis=1) * mag[:, None]
    # A-priori pose and points.
    eps = rng.normal(0.0, pointing_sigma_urad * 1e-6, (n_img, 3))
    rot_ap = np.matmul(rotation_from_angles(eps), rot_true)
    pos_ap = positions + rng.normal(0.0, position_error_m, positions.shape) if position_error_m > 0 else positions.copy()
    pts_ap = intersect_rays(cameras, image_camera, pos_ap, rot_ap, meas_img, meas_pt, measures, len(points),
                            DATUM_RADIUS_M)
    problem = AdjustmentProblem(
        cameras=cameras, image_camera=image_camera, positions=pos_ap, rotations=rot_ap, points=pts_ap,
        measure_image=meas_img, measure_point=meas_pt, measures=measures, measure_sigma=measure_sigma_px,
        image_ids=tuple(f"SYN{i:07d}" for i in range(n_img)),
        pointing_sigma_urad=pointing_sigma_urad if pointing_sigma_urad > 0 else None,
    )
    return SyntheticNetwork(problem, rot_true, positions, points, outlier, eps, relief_m=float(relief_m),
                            relief_seed=seed)


def intersect_rays(
    cameras: tuple[FramingCamera, ...],
    image_camera: NDArray[np.int64],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    measure_image: NDArray[np.int64],
    measure_point: NDArray[np.int64],
    measures: NDArray[np.float64],
    n_points: int,
    datum_radius_m: float,
) -> NDArray[np.float64]:
    """Least-squares intersection (n_points, 3) of the rays of each point's measures.

    Points whose rays are too close to parallel (or whose intersection lands more
    than 50 km from the datum) fall back to the datum intersection of one ray.
    """
    m = len(measure_image)
    dirs = np.empty((m, 3))
    for k, cam in enumerate(cameras):
        sel = image_camera[measure_image] == k
        v = cam.pixel_to_camera(measures[sel])
        dirs[sel] = np.matmul(rotations[measure_image[sel]].transpose(0, 2, 1), v[:, :, None])[:, :, 0]
    proj = np.eye(3) - dirs[:, :, None] * dirs[:, None, :]  # (M, 3, 3)
    c = positions[measure_image]
    a = np.zeros((n_points, 9))
    b = np.zeros((n_points, 3))
    np.add.at(a, measure_point, proj.reshape(m, 9))  # setup only, once per network
    np.add.at(b, measure_point, np.matmul(proj, c[:, :, None])[:, :, 0])
    a = a.reshape(n_points, 3, 3)
    det = np.linalg.det(a)
    good = det > 1e-9
    x = np.full((n_points, 3), np.nan)
    x[good] = np.matmul(inv3(a[good]), b[good][:, :, None])[:, :, 0]
    first = np.full(n_points, -1)
    first[measure_point[::-1]] = np.arange(m)[::-1]
    hit, _ = intersect_sphere(c[first], dirs[first], datum_radius_m)
    r = np.linalg.norm(x, axis=1)
    bad = ~good | ~np.isfinite(r) | (np.abs(r - datum_radius_m) > 50e3)
    x[bad] = hit[bad]
    return x


def pointing_errors(
    rotations: NDArray[np.float64], true_rotations: NDArray[np.float64], weights: NDArray[np.float64] | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Pointing errors of adjusted against true rotations.

    Returns
    -------
    raw : (n_img, 3) rad, rotation vector of ``R_adj R_true^T`` in each camera frame
    common : (3,) rad, the common rotation of the block, expressed in the body frame
        (weighted mean of the per-image errors rotated into the body frame)
    relative : (n_img, 3) rad, per-image errors after removing the common rotation

    With pointing corrections only and no ground control, the whole block can
    turn a little as one (the datum defect is fixed only weakly, by the pointing
    priors and the point radius constraint); ``relative`` is the part that
    matters for the consistency of the DEM, ``raw`` the absolute pointing.
    """
    err_cam = angles_from_rotation(np.matmul(rotations, true_rotations.transpose(0, 2, 1)))
    err_body = np.matmul(true_rotations.transpose(0, 2, 1), err_cam[:, :, None])[:, :, 0]
    w = np.ones(len(err_cam)) if weights is None else np.asarray(weights, np.float64)
    common = (err_body * w[:, None]).sum(axis=0) / w.sum()
    rel_body = err_body - common
    relative = np.matmul(true_rotations, rel_body[:, :, None])[:, :, 0]
    return err_cam, common, relative
