"""``blocked_bundle_adjust`` (issue #17): ``bundle_adjust``'s result over point blocks, field by field."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust, point_blocks
from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.pose import rotation_from_angles
from mercury_dem.validate.synthetic_network import make_synthetic_network

CFG = AdjustConfig()


@pytest.fixture(scope="module")
def problem():
    """A 10⁴-measure network (seed 37, not used for tuning) with what the pipeline's units carry: per-point
    radius constraints (altimetry) on a third of the points, a starting pointing (a lower level's solution)
    and a held image."""
    p = make_synthetic_network(10_000, rng=np.random.default_rng(37), min_views=3).problem
    rng = np.random.default_rng(5)
    radius = np.full(p.n_points, np.nan)
    radius[::3] = 500.0
    start = np.matmul(rotation_from_angles(rng.normal(0.0, 100e-6, (p.n_images, 3))), p.rotations)
    held = np.zeros(p.n_images, bool)
    held[4] = True
    return dataclasses.replace(p, point_radius_sigma=radius, initial_rotations=start, held_images=held)


@pytest.fixture(scope="module")
def reference(problem):
    return bundle_adjust(problem, CFG)


def test_blocked_equals_bundle_adjust(problem, reference) -> None:
    """float64 storage: the in-memory adjuster's sums in another order, nothing else."""
    ref = reference
    res = blocked_bundle_adjust(problem, dataclasses.replace(CFG, blocked_float32=False), block_points=700)  # 4 blocks
    assert res.extra["blocked"]["blocks"] == 4
    assert res.iterations == ref.iterations and res.converged and ref.converged
    assert np.array_equal(res.rejected, ref.rejected) and ref.rejected.sum() > 50
    assert np.array_equal(res.underdetermined_points, ref.underdetermined_points)
    # solver tolerance: the same loop, the sums in another order (measured 1e-16 rad, 5e-10 m, 1e-11 px)
    assert np.abs(res.rotations - ref.rotations).max() < 1e-10
    assert np.abs(res.rotations[4] - problem.initial_rotations[4]).max() < 1e-14  # held where it starts
    assert np.abs(res.points - ref.points).max() < 1e-4
    assert np.abs(res.residuals_px - ref.residuals_px).max() < 1e-6
    assert res.sigma0 == pytest.approx(ref.sigma0, rel=1e-9) and res.dof == ref.dof
    assert res.initial_rms_px == pytest.approx(ref.initial_rms_px, rel=1e-12)
    assert np.array_equal(res.accepted_per_image, ref.accepted_per_image)
    assert np.allclose(res.rms_per_image, ref.rms_per_image, rtol=1e-8, equal_nan=True)


def test_float32_storage_gives_the_same_pointing(problem, reference) -> None:
    """float32 W, measures and sigmas (the default): the same stationary point, the observations rounded by
    < 2^-24 of 512 px. Stated bound: pointing within 1e-3 px (measured 2026-11-26: 5e-5 px here, 5e-5 px on seed 41), points
    within 5 cm (0.8 and 1.4 cm; their errors against the truth are ~40 m), the same rejected set."""
    res = blocked_bundle_adjust(problem, CFG, block_points=700)
    ifov = min(c.pixel_size_mm / c.focal_length_mm for c in problem.cameras)  # rad a pixel
    assert np.abs(res.rotations - reference.rotations).max() / ifov < 1e-3
    assert np.abs(res.points - reference.points).max() < 0.05
    assert np.array_equal(res.rejected, reference.rejected)
    assert res.sigma0 == pytest.approx(reference.sigma0, rel=1e-6)


def test_blocks_cover_every_measure_once(problem) -> None:
    blocks, index = point_blocks(problem, 333)
    ix = np.concatenate(index)
    assert np.array_equal(np.sort(ix), np.arange(problem.n_measures))
    assert sum(len(b.apriori_points) for b in blocks) == problem.n_points
    for b, i in zip(blocks, index):
        assert np.array_equal(b.measure_point + b.point_start, problem.measure_point[i])


def test_positions_are_refused_by_name(problem) -> None:
    with pytest.raises(AdjustmentError, match="solve_positions"):
        blocked_bundle_adjust(problem, dataclasses.replace(CFG, solve_positions=True))


def test_grouped_pairs_equal_the_pair_lists(problem) -> None:
    """The Schur pair sums without the pair lists (``schur_pairs_grouped``) equal those over SchurStructure's lists."""
    from mercury_dem.adjust.kernels import schur_pairs, schur_pairs_grouped
    from mercury_dem.adjust.schur import SchurStructure

    rng = np.random.default_rng(3)
    cam, pt = problem.measure_image, problem.measure_point
    held = np.zeros(problem.n_points, bool)
    held[::11] = True  # held points take no part in the elimination
    s = SchurStructure.build(cam, pt, problem.n_images, problem.n_points, 3, eliminate=~held)
    w = rng.normal(size=(problem.n_measures, 3, 3))
    a = rng.normal(size=(problem.n_points, 3, 3))
    v_inv = np.matmul(a, a.transpose(0, 2, 1)) + np.eye(3)
    ref = np.zeros((s.n_blocks, 3, 3))
    schur_pairs(w, v_inv, pt, s.pair_first, s.pair_second, s.pair_block, ref)
    use = np.flatnonzero(~held[pt])
    use = use[np.argsort(pt[use], kind="stable")]
    ptr = np.concatenate([[0], np.cumsum(np.bincount(pt[use], minlength=problem.n_points))])
    got = np.zeros_like(ref)
    schur_pairs_grouped(w, v_inv, pt, cam, use, ptr, s.pair_block, got)
    assert np.allclose(got, ref, rtol=1e-12, atol=1e-9 * np.abs(ref).max())
