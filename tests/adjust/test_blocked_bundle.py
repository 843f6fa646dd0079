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

CFG = AdjustConfig(pointing_sigma_deg=float(np.degrees(450e-6)))


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


def test_blocked_equals_bundle_adjust(problem) -> None:
    ref = bundle_adjust(problem, CFG)
    res = blocked_bundle_adjust(problem, CFG, block_points=700)  # 4 blocks
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
