"""A-posteriori covariances from the selected inverse of the sparse factor (issue #33 item 2).

The references are dense inverses computed here without the Schur complement: the inverse of the whole
normal matrix of the cameras *and* points (``J^T J`` of the whitened, weighted Jacobian with its priors),
whose camera and point diagonal blocks are the covariances the selected inverse must reproduce.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from mercury_dem.adjust import posterior
from mercury_dem.adjust.bundle import bundle_adjust, make_model, solver_options
from mercury_dem.adjust.framing import FramingState
from mercury_dem.adjust.posterior import selected_inverse
from mercury_dem.adjust.robust import loss_rho
from mercury_dem.adjust.schur import HAVE_CHOLMOD
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.validate.synthetic_network import make_synthetic_network

METHODS = ["splu"] + (["cholmod"] if HAVE_CHOLMOD else [])


def _block_spd(n_blocks: int, c: int, rng: np.random.Generator) -> sp.csc_matrix:
    """A symmetric positive definite block matrix with the sparsity of a strip of overlapping images."""
    a = np.zeros((n_blocks * c, n_blocks * c))
    for i in range(n_blocks):
        for k in (i, i + 1, i + 3, i + 7):
            if k < n_blocks:
                b = rng.normal(size=(c, 4))
                a[i * c:(i + 1) * c, k * c:(k + 1) * c] += b @ rng.normal(size=(4, c)) * 0.3
    a = a + a.T
    a += np.diag(np.abs(a).sum(axis=1) + 0.1)  # diagonally dominant
    return sp.csc_matrix(a)


@pytest.mark.parametrize("supernodal", [True, False], ids=["supernodal", "by-column"])
@pytest.mark.parametrize("method", METHODS)
def test_selected_entries_equal_the_dense_inverse(method: str, supernodal: bool) -> None:
    """Every entry on the matrix's own pattern (and so on the factor's) equals the dense inverse's to 1e-10 of
    the largest entry (measured ~1e-15), by both forms of the recurrence."""
    a = _block_spd(60, 3, np.random.default_rng(5))
    dense = np.linalg.inv(a.toarray())
    inv = selected_inverse(a, method, supernodal)
    assert inv.method == method and inv.nnz >= (a.nnz + a.shape[0]) // 2
    r, c = a.nonzero()
    err = np.max(np.abs(inv.entries(r, c) - dense[r, c])) / np.max(np.abs(dense))
    assert err < 1e-10
    idx = np.arange(60)
    blocks = inv.blocks(idx, idx, 3)
    assert np.allclose(blocks, dense.reshape(60, 3, 60, 3)[idx, :, idx, :], rtol=0, atol=1e-10 * np.max(np.abs(dense)))


@pytest.mark.parametrize("method", METHODS)
def test_off_pattern_and_indefinite_are_errors(method: str) -> None:
    """An entry the factor does not hold is refused (never a silent zero); an indefinite matrix is named."""
    n = 40
    a = sp.diags([np.full(n - 1, -1.0), np.full(n, 2.5), np.full(n - 1, -1.0)], [-1, 0, 1], format="csc")
    inv = selected_inverse(a, method)
    far = np.array([[0]]), np.array([[n - 1]])
    if inv.order[0] != inv.order[n - 1] and _on_pattern(inv, 0, n - 1):
        pytest.skip("this ordering filled the corner")
    with pytest.raises(AdjustmentError, match="not on the factor's pattern"):
        inv.entries(*far)
    with pytest.raises(AdjustmentError, match="positive definite|singular"):
        selected_inverse(a - 3.0 * sp.eye(n, format="csc"), method)


def _on_pattern(inv: posterior.SelectedInverse, i: int, k: int) -> bool:
    try:
        inv.entries(np.array([i]), np.array([k]))
    except AdjustmentError:
        return False
    return True


# -- the in-memory adjuster against the whole normal matrix's dense inverse -------------------------------------

CFG = AdjustConfig(posterior_sigmas=True)


@pytest.fixture(scope="module")
def network():
    """~3·10³ measures in 3-5 views, 1 % gross outliers (seed 43)."""
    return make_synthetic_network(3_000, rng=np.random.default_rng(43), min_views=3, outlier_fraction=0.01).problem


def _full_covariances(problem, config, result, held):
    """sigma0^2 times the camera and point diagonal blocks of (J^T J)^-1 over the free cameras and points."""
    model = make_model(problem, config)
    opt = solver_options(problem, config, held)
    state = FramingState(result.pointing_corrections, result.position_corrections, result.points)
    r, jc, jp = model.linearize(state)
    pt, cam = problem.measure_point, problem.measure_image
    use = ~result.rejected & ~result.underdetermined_points[pt]
    _, w = loss_rho(np.sum(r * r, axis=1), opt.loss, opt.loss_scale)
    sw = np.sqrt(np.where(use, w, 0.0))
    free_c = np.flatnonzero(~held)
    free_p = np.flatnonzero(~result.underdetermined_points)
    col_c = np.full(problem.n_images, -1)
    col_c[free_c] = 3 * np.arange(len(free_c))
    col_p = np.full(problem.n_points, -1)
    col_p[free_p] = 3 * len(free_c) + 3 * np.arange(len(free_p))
    n = 3 * (len(free_c) + len(free_p))
    parts = []  # (row, col, value) triplets of the whitened Jacobian, one row per observation

    def add(starts, blocks, cols):
        """Blocks (K, k, 3) at rows starts (K,) .. starts + k - 1, columns cols (K,) .. cols + 2."""
        rr = starts[:, None, None] + np.arange(blocks.shape[1])[None, :, None]
        cc = cols[:, None, None] + np.arange(3)[None, None, :]
        rr, cc = np.broadcast_arrays(rr, cc)
        parts.append((rr.ravel(), cc.ravel(), blocks.ravel()))

    m = np.flatnonzero(use)  # measure m[t] has rows 2 t, 2 t + 1
    t = np.arange(len(m))
    on_c, on_p = col_c[cam[m]] >= 0, col_p[pt[m]] >= 0
    add(2 * t[on_c], jc[m[on_c]] * sw[m[on_c], None, None], col_c[cam[m[on_c]]])
    add(2 * t[on_p], jp[m[on_p]] * sw[m[on_p], None, None], col_p[pt[m[on_p]]])
    row = 2 * len(m)
    _, jcp = model.camera_prior(state)
    add(row + 3 * np.arange(len(free_c)), jcp[free_c], col_c[free_c])
    row += 3 * len(free_c)
    pp = model.point_prior(state)
    if pp is not None:
        k = pp[1].shape[1]
        add(row + k * np.arange(len(free_p)), pp[1][free_p], col_p[free_p])
        row += k * len(free_p)
    rr, cc, vv = (np.concatenate(x) for x in zip(*parts))
    j = sp.csr_matrix((vv, (rr, cc)), shape=(row, n))
    normal = (j.T @ j).toarray()
    cov = np.linalg.inv(normal) * result.sigma0**2
    cov_c = np.zeros((problem.n_images, 3, 3))
    for i in free_c:
        cov_c[i] = cov[col_c[i]:col_c[i] + 3, col_c[i]:col_c[i] + 3]
    sig_p = np.zeros((problem.n_points, 3))
    for p in free_p:
        sig_p[p] = np.sqrt(np.diag(cov[col_p[p]:col_p[p] + 3, col_p[p]:col_p[p] + 3]))
    return cov_c, sig_p


def _scaled_error(cov: np.ndarray, ref: np.ndarray) -> float:
    """Largest |C - C_ref| over sqrt(C_ref_aa C_ref_bb) (a correlation-scaled error) over the non-zero blocks."""
    d = np.sqrt(np.diagonal(ref, axis1=1, axis2=2))
    scale = d[:, :, None] * d[:, None, :]
    live = scale[:, 0, 0] > 0
    return float(np.max(np.abs(cov[live] - ref[live]) / scale[live]))


@pytest.mark.parametrize("case", ["pose and point priors, one image held", "pose prior only", "splu"])
def test_covariances_equal_the_dense_inverse(network, case: str, monkeypatch) -> None:
    """Image covariances and point sigmas of ``bundle_adjust`` equal the dense inverse of the whole normal
    matrix to 1e-6 (correlation-scaled; measured ~1e-11): with a point prior and a held image, with only the
    pointing prior (radius prior off), and through SuperLU; with the outliers the adjustment rejected left out."""
    problem = network
    config = CFG
    if case == "pose and point priors, one image held":
        held = np.zeros(problem.n_images, bool)
        held[2] = True
        problem = dataclasses.replace(problem, held_images=held)
    else:
        config = dataclasses.replace(CFG, radius_sigma_m=None)
    if case == "splu":
        monkeypatch.setattr(posterior, "HAVE_CHOLMOD", False)
    res = bundle_adjust(problem, config)
    assert res.n_rejected > 0, "the network's outliers should be rejected (the case of this test)"
    assert res.image_covariances is not None and res.point_sigmas is not None
    held = problem.held_images.copy()
    cov_c, sig_p = _full_covariances(problem, config, res, held)
    assert np.all(res.image_covariances[held] == 0.0)
    assert _scaled_error(res.image_covariances, cov_c) < 1e-6
    assert np.allclose(res.image_sigmas, np.sqrt(np.diagonal(cov_c, axis1=1, axis2=2)), rtol=1e-6, atol=0)
    live = sig_p > 0
    assert np.max(np.abs(res.point_sigmas[live] - sig_p[live]) / sig_p[live]) < 1e-6
    assert np.all(res.point_sigmas[~live] == 0.0)
