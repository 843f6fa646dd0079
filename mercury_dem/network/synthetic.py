"""Synthetic control networks of any size, generated point block by point block (issue #17).

A pure, seeded generator: :func:`make_images` draws the whole image set at once
(at the reference's size that is 10^5 images, a few tens of MB), and
:func:`point_block` draws the points of one block of the ground, their measures
and a-priori coordinates. Blocks are equal-area cells of the covered cap, each
drawn from its own random stream (``default_rng([seed, 1, block])``), so a block
is the same whichever order (or process) makes it and the whole network never
has to be in memory: :mod:`mercury_dem.io.synthetic_network_store` streams the
blocks into a network store.

Geometry as :mod:`mercury_dem.validate.synthetic_network` (whose helpers it
reuses): MDIS-like NAC and WAC framing cameras (512 x 512 after summing)
200-1500 km (WAC 200-500 km) above a 2439.4 km sphere with smooth relief,
looking up to 25 deg off nadir at targets in a spherical cap sized so that a
ground point is seen by ``coverage`` images on average; the cap becomes the
whole sphere when the footprints cover it ``coverage`` times. What is new here is
the size and the statistics of the reference (Becker et al. 2016, seed 000:
100,432 images, 12.6 M points, 94.7 M measures, i.e. ~7.5 measures per point and
~940 per image): each point wants ``2 + Poisson(mean_views - 2)`` measures,
clipped to ``max_views`` (15) and to the images that see it, points seen fewer
than twice are dropped. Measures are true projections + N(0, ``noise_px``), a
fraction ``outlier_fraction`` displaced by 5-50 px in a random direction. The
a-priori pointing is the truth rotated by N(0, ``pointing_error_rad``) per
axis (the per-image error of MESSENGER's reconstructed pointing is a few
hundred microradians); a-priori points are the intersections of the a-priori
rays (:func:`~mercury_dem.validate.synthetic_network.intersect_rays`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from mercury_dem.exceptions import NetworkError
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.geometry.camera import FramingCamera, mdis_nac, mdis_wac
from mercury_dem.geometry.pose import look_at_rotation, rotation_from_angles
from mercury_dem.validate.synthetic_network import footprint_area_m2, intersect_rays, plane_wave_relief

#: Candidate images examined per point (nearest image targets); enough for 15 views at coverage 10.
CANDIDATES = 48


@dataclass(frozen=True)
class SyntheticSpec:
    """Parameters of a synthetic network (see the module docstring)."""

    n_measures: int
    seed: int = 0
    outlier_fraction: float = 0.01
    noise_px: float = 0.25
    outlier_px: tuple[float, float] = (5.0, 50.0)
    pointing_error_rad: float = 450e-6
    wac_fraction: float = 0.1
    altitude_km: tuple[float, float] = (200.0, 1500.0)
    wac_altitude_km: tuple[float, float] = (200.0, 500.0)
    samples: int = 512
    measures_per_image: float = 940.0
    mean_views: float = 7.5
    max_views: int = 15
    coverage: float = 13.0
    max_emission_deg: float = 25.0
    relief_m: float = 2000.0
    measure_sigma_px: float = 1.0
    block_points: int = 25_000
    #: expected measures per drawn point (visibility cuts the wanted count); calibrates the point count
    yield_per_point: float = 7.0

    def __post_init__(self) -> None:
        if self.n_measures < 100:
            raise NetworkError(f"synthetic network: --measures {self.n_measures} is too small (at least 100)")
        if not 0.0 <= self.outlier_fraction < 0.5:
            raise NetworkError(f"synthetic network: outlier fraction {self.outlier_fraction} must be in [0, 0.5)")
        if not 2 <= self.mean_views <= self.max_views:
            raise NetworkError(f"synthetic network: mean views {self.mean_views} must be in [2, {self.max_views}]")
        if self.block_points < 100:
            raise NetworkError(f"synthetic network: block_points {self.block_points} must be >= 100")

    @property
    def n_images(self) -> int:
        return max(8, int(round(self.n_measures / self.measures_per_image)))

    @property
    def n_points_drawn(self) -> int:
        return max(8, int(round(self.n_measures / self.yield_per_point)))

    @property
    def n_blocks(self) -> int:
        return max(1, -(-self.n_points_drawn // self.block_points))


@dataclass(frozen=True)
class ImageSet:
    """The images of a synthetic network: a-priori and true poses (positions are exact)."""

    cameras: tuple[FramingCamera, ...]
    image_camera: NDArray[np.int64]
    positions: NDArray[np.float64]
    true_rotations: NDArray[np.float64]
    rotations: NDArray[np.float64]  # a-priori
    pointing_error: NDArray[np.float64]  # (n_img, 3) rad, injected
    target_unit: NDArray[np.float64]  # (n_img, 3) boresight ground target directions
    cos_alpha: float  # the covered cap about +X
    relief_seed: int

    @property
    def n_images(self) -> int:
        return len(self.positions)


@dataclass(frozen=True)
class PointBlock:
    """The points of one block and their measures (point indices local to the block)."""

    block: int
    true_points: NDArray[np.float64]
    apriori_points: NDArray[np.float64]
    measure_image: NDArray[np.int64]
    measure_point: NDArray[np.int64]  # local, non-decreasing
    measures: NDArray[np.float64]  # (M, 2) px
    outlier: NDArray[np.bool_]

    @property
    def n_points(self) -> int:
        return len(self.true_points)

    @property
    def n_measures(self) -> int:
        return len(self.measure_image)


def _cap_uniform(x: NDArray[np.float64], phi: NDArray[np.float64]) -> NDArray[np.float64]:
    s = np.sqrt(np.maximum(1.0 - x * x, 0.0))
    return np.stack([x, s * np.cos(phi), s * np.sin(phi)], axis=1)


def make_images(spec: SyntheticSpec) -> ImageSet:
    """All images of the network (poses, a-priori pointing), from the spec's seed."""
    rng = np.random.default_rng([spec.seed, 0])
    nac, wac = mdis_nac(spec.samples), mdis_wac(spec.samples)
    n = spec.n_images
    is_wac = rng.random(n) < spec.wac_fraction
    alt = np.where(is_wac, rng.uniform(*spec.wac_altitude_km, n), rng.uniform(*spec.altitude_km, n)) * 1e3
    area = np.where(is_wac, footprint_area_m2(wac, alt), footprint_area_m2(nac, alt))
    cap_area = float(area.sum()) / spec.coverage
    cos_alpha = max(-1.0, 1.0 - cap_area / (2 * np.pi * DATUM_RADIUS_M**2))
    target_u = _cap_uniform(1.0 - rng.random(n) * (1.0 - cos_alpha), rng.uniform(0.0, 2 * np.pi, n))
    relief_seed = int(rng.integers(1 << 31))
    target = target_u * (DATUM_RADIUS_M + plane_wave_relief(target_u, spec.relief_m, relief_seed))[:, None]
    emission = np.radians(rng.uniform(0.0, spec.max_emission_deg, n))
    tangent = np.cross(target_u, rng.normal(size=(n, 3)))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    sub = target_u * DATUM_RADIUS_M + tangent * (alt * np.tan(emission))[:, None]
    positions = sub / np.linalg.norm(sub, axis=1, keepdims=True) * (DATUM_RADIUS_M + alt)[:, None]
    rot_true = look_at_rotation(positions, target)
    eps = rng.normal(0.0, spec.pointing_error_rad, (n, 3))
    rot_ap = np.matmul(rotation_from_angles(eps), rot_true)
    return ImageSet((nac, wac), is_wac.astype(np.int64), positions, rot_true, rot_ap, eps, target_u, cos_alpha, relief_seed)


def block_cell(spec: SyntheticSpec, cos_alpha: float, block: int) -> tuple[float, float, float, float]:
    """The equal-area cell of the cap holding ``block``'s points: ``(x_lo, x_hi, phi_lo, phi_hi)``.

    ``x`` is the cosine of the angle from +X (the cap's centre). Blocks fill bands of
    ``ceil(sqrt(n_blocks))`` sectors from the centre outwards; a band's width in ``x``
    is proportional to the blocks it holds (the last band may hold fewer), so every
    cell has the same area and its points, uniform in ``x`` and ``phi``, are uniform
    on the sphere at the density of every other cell.
    """
    nb = spec.n_blocks
    n_sectors = max(1, int(np.ceil(np.sqrt(nb))))
    band = block // n_sectors
    first = band * n_sectors
    in_band = min(n_sectors, nb - first)
    span = 1.0 - cos_alpha
    x_hi = 1.0 - first / nb * span
    x_lo = 1.0 - (first + in_band) / nb * span
    sector = block - first
    width = 2 * np.pi / in_band
    return x_lo, x_hi, sector * width, (sector + 1) * width


def point_block(spec: SyntheticSpec, images: ImageSet, block: int, tree: cKDTree | None = None) -> PointBlock:
    """The points of ``block`` (0 <= block < spec.n_blocks), drawn from the block's own stream."""
    if not 0 <= block < spec.n_blocks:
        raise NetworkError(f"synthetic network: block {block} outside [0, {spec.n_blocks})")
    rng = np.random.default_rng([spec.seed, 1, block])
    n_pt = spec.n_points_drawn // spec.n_blocks + (1 if block < spec.n_points_drawn % spec.n_blocks else 0)
    x_lo, x_hi, phi_lo, phi_hi = block_cell(spec, images.cos_alpha, block)
    x = x_lo + rng.random(n_pt) * (x_hi - x_lo)
    phi = phi_lo + rng.random(n_pt) * (phi_hi - phi_lo)
    pt_u = _cap_uniform(x, phi)
    points = pt_u * (DATUM_RADIUS_M + plane_wave_relief(pt_u, spec.relief_m, images.relief_seed))[:, None]
    tree = tree or cKDTree(images.target_unit)
    k_cand = min(CANDIDATES, images.n_images)
    _, cand = tree.query(pt_u, k=k_cand)
    cand = np.asarray(cand).reshape(n_pt, k_cand)
    px = np.full(cand.shape + (2,), np.nan)
    vis = np.zeros(cand.shape, bool)
    for k, cam in enumerate(images.cameras):
        sel = images.image_camera[cand] == k
        ii = cand[sel]
        rows = np.nonzero(sel)[0]
        v = np.matmul(images.true_rotations[ii], (points[rows] - images.positions[ii])[:, :, None])[:, :, 0]
        p = cam.camera_to_pixel(v)
        ok = (v[:, 2] > 0) & cam.in_image(p, margin=2.0) & np.all(np.isfinite(p), axis=1)
        px[sel] = p
        vis[sel] = ok
    wanted = np.minimum(2 + rng.poisson(spec.mean_views - 2.0, n_pt), spec.max_views)
    keys = np.where(vis, rng.random(vis.shape), 2.0)
    rank = np.argsort(np.argsort(keys, axis=1), axis=1)
    take = vis & (rank < wanted[:, None])
    take &= (take.sum(axis=1) >= 2)[:, None]
    r_idx, c_idx = np.nonzero(take)  # row-major: grouped by point
    used, meas_pt = np.unique(r_idx, return_inverse=True)
    meas_img = cand[r_idx, c_idx].astype(np.int64)
    true_px = px[r_idx, c_idx]
    m = len(meas_img)
    measures = true_px + rng.normal(0.0, spec.noise_px, true_px.shape)
    outlier = rng.random(m) < spec.outlier_fraction
    ang = rng.uniform(0.0, 2 * np.pi, int(outlier.sum()))
    mag = rng.uniform(*spec.outlier_px, int(outlier.sum()))
    measures[outlier] += np.stack([np.cos(ang), np.sin(ang)], axis=1) * mag[:, None]
    true_points = points[used]
    if len(used):
        ap = intersect_rays(images.cameras, images.image_camera, images.positions, images.rotations,
                            meas_img, meas_pt, measures, len(used), DATUM_RADIUS_M)
    else:
        ap = np.zeros((0, 3))
    return PointBlock(block, true_points, ap, meas_img, meas_pt.astype(np.int64), measures, outlier)
