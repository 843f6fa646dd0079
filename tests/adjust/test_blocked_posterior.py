"""A-posteriori pointing covariances of the blocked adjustment against the in-memory adjuster's (issues #17 §2, #33 §2)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from mercury_dem.adjust import blocked, posterior
from mercury_dem.adjust.blocked_bundle import blocked_bundle_adjust
from mercury_dem.adjust.bundle import bundle_adjust
from mercury_dem.adjust.schur import HAVE_CHOLMOD
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.validate.synthetic_network import make_synthetic_network

CFG = AdjustConfig(posterior_sigmas=True, blocked_float32=False)


@pytest.fixture(scope="module")
def problem():
    """A 5·10³-measure network (seed 43, not used for tuning) with a held image."""
    p = make_synthetic_network(5_000, rng=np.random.default_rng(43), min_views=3).problem
    held = np.zeros(p.n_images, bool)
    held[2] = True
    return dataclasses.replace(p, held_images=held)


@pytest.fixture(scope="module")
def reference(problem):
    ref = bundle_adjust(problem, CFG)
    assert ref.image_sigmas is not None
    return ref


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    free = b > 0
    return float(np.max(np.abs(a[free] - b[free]) / b[free]))


def _scaled(a: np.ndarray, b: np.ndarray) -> float:
    """Largest |A - B| over sqrt(B_aa B_bb) over the non-held images (a correlation-scaled error)."""
    d = np.sqrt(np.diagonal(b, axis1=1, axis2=2))
    scale = d[:, :, None] * d[:, None, :]
    live = scale[:, 0, 0] > 0
    return float(np.max(np.abs(a[live] - b[live]) / scale[live]))


def test_covariances_equal_the_in_memory_ones(problem, reference) -> None:
    """Same solution, same weights and accepted set (outliers rejected): the same image covariances and point
    sigmas, sums in another order (bound 1e-9, correlation-scaled; sigmas measured within 1e-13 relative)."""
    assert reference.n_rejected > 0
    res = blocked_bundle_adjust(problem, CFG, block_points=300)
    assert res.extra["blocked"]["blocks"] > 2
    assert "selected inverse" in res.extra["blocked"]["posterior_sigmas"]
    assert res.image_sigmas is not None and res.image_sigmas.shape == reference.image_sigmas.shape
    assert np.all(res.image_sigmas[2] == 0.0) and np.all(reference.image_sigmas[2] == 0.0)
    assert np.all(res.image_covariances[2] == 0.0)
    assert _rel(res.image_sigmas, reference.image_sigmas) < 1e-9
    assert _scaled(res.image_covariances, reference.image_covariances) < 1e-9
    # the points' sigmas, computed on the shards from the inverse's blocks of their image pairs
    assert res.point_sigmas is not None and reference.point_sigmas is not None
    live = reference.point_sigmas > 0
    assert np.array_equal(res.point_sigmas > 0, live) and live.mean() > 0.9
    assert _rel(res.point_sigmas, reference.point_sigmas) < 1e-9


def test_float32_storage_moves_the_sigmas_little(problem, reference) -> None:
    """float32 W and measures: the sigmas within 1e-5 relative (measured 1.5e-6 and 7e-7 on seeds 43 and 47)."""
    res = blocked_bundle_adjust(problem, dataclasses.replace(CFG, blocked_float32=True), block_points=300)
    assert _rel(res.image_sigmas, reference.image_sigmas) < 1e-5


def test_without_cholmod_superlu_gives_the_same(problem, reference, monkeypatch) -> None:
    """Without scikit-sparse the factor is SuperLU's (symmetric pivoting): the same covariances, at any size (no
    size limit, no lower bounds: both removed with the selected inverse)."""
    monkeypatch.setattr(posterior, "HAVE_CHOLMOD", False)
    res = blocked_bundle_adjust(problem, dataclasses.replace(CFG, posterior_max_unknowns=3), block_points=300)
    assert "splu" in res.extra["blocked"]["posterior_sigmas"]
    assert _scaled(res.image_covariances, reference.image_covariances) < 1e-9


@pytest.mark.skipif(not HAVE_CHOLMOD, reason="scikit-sparse (CHOLMOD) not importable")
def test_blocked_posterior_reports_its_cost(problem) -> None:
    """The result names the factor, its size and the time of its two parts (what docs/benchmarks.md records)."""
    setup = blocked.setup_from_config(problem.cameras, problem.image_camera, problem.positions, problem.rotations, CFG, pointing_sigma_urad=450.0)
    opt = blocked.options_from_config(CFG)
    eng = blocked.SyncEngine([blocked.BlockShard(blocked.blocks_from_problem(problem, 3), setup, opt)])
    res = blocked.blocked_levenberg_marquardt(eng, setup, opt)
    post = blocked.blocked_posterior_sigmas(eng, setup, res)
    assert post.method == "cholmod" and post.factor_nnz >= 6 * problem.n_images
    assert post.factor_seconds > 0 and post.recurrence_seconds > 0 and post.seconds >= post.factor_seconds
    assert np.all(post.image_sigmas > 0)
