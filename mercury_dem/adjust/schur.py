"""The reduced camera system of a bundle adjustment: structure, assembly and solution.

The normal equations of a bundle adjustment with camera blocks (``c`` parameters
each) and 3-D points are

.. code-block:: text

    [ U   W ] [dc]   [-g_c]          U: block-diagonal (n_cam blocks c x c)
    [ W^T V ] [dp] = [-g_p]          V: block-diagonal (n_pt blocks 3 x 3)

Points are eliminated with their 3 x 3 blocks (closed-form inverses), leaving the
reduced camera system ``S dc = b`` with ``S = U - W V^-1 W^T``, block-sparse: the
block (i, k) is non-zero when images i and k share a point. Its structure never
changes during an adjustment (rejected measures get zero weight, they are not
removed), so every index array is computed once in :class:`SchurStructure` and
each iteration only fills numbers:

* per-measure products are summed per camera / per point, and the camera-pair
  products ``Y_m1 W_m2^T`` (``Y = W V^-1``) of every pair of
  measures of a point are summed into their (i, k) block by a compiled loop
  (:mod:`mercury_dem.adjust.kernels`), so no per-pair array ever exists;
* the blocks go straight into a ``scipy.sparse.bsr_matrix`` (block CSR) whose
  index arrays were built once.

Why our own assembly rather than a library: scipy has no Schur-complement
bundle-adjustment solver, and building the full Jacobian as a scipy sparse
matrix (what ``least_squares`` does) costs 20-100x more here (see
docs/benchmarks/adjust.md). The factorization itself is a library's: CHOLMOD
(scikit-sparse) when importable, SuperLU otherwise; the iterative path uses
``scipy.sparse.linalg.cg`` with a block-Jacobi preconditioner.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from mercury_dem.adjust.kernels import schur_pairs
from mercury_dem.adjust.problem import IndexArray

try:  # CHOLMOD through scikit-sparse; optional (needs Debian's libsuitesparse at run time)
    from sksparse import cholmod as _cholmod
except Exception:  # pragma: no cover - depends on the machine
    _cholmod = None

HAVE_CHOLMOD = _cholmod is not None


class _NeverRaised(Exception):
    """Stands for CHOLMOD's not-positive-definite error where CHOLMOD is absent (nothing raises it)."""


#: The exception CHOLMOD raises for a matrix that is not positive definite (catchable without CHOLMOD installed).
CholmodNotPositiveDefinite: type[Exception] = (
    _cholmod.CholmodNotPositiveDefiniteError if _cholmod is not None else _NeverRaised)


def cholmod_factor(matrix: sp.csc_matrix) -> Any:
    """CHOLMOD's supernodal Cholesky factor of the symmetric positive definite ``matrix`` (CSC).

    The factor is callable (``factor(rhs)`` solves) and can be refactorized in place
    (``cholesky_inplace``). Only when :data:`HAVE_CHOLMOD`; raises CHOLMOD's
    ``CholmodNotPositiveDefiniteError`` for a matrix that is not positive definite.
    """
    if _cholmod is None:
        raise RuntimeError("CHOLMOD (scikit-sparse) is not importable here")
    return _cholmod.cholesky(matrix, mode="supernodal")


def inv3(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverses of stacked 3 x 3 matrices (..., 3, 3) by the adjugate (closed form).

    About 10x faster than ``np.linalg.inv`` on (N, 3, 3) here; the caller makes
    the blocks positive definite (damping, priors or freezing) beforehand.
    """
    a00, a01, a02 = a[..., 0, 0], a[..., 0, 1], a[..., 0, 2]
    a10, a11, a12 = a[..., 1, 0], a[..., 1, 1], a[..., 1, 2]
    a20, a21, a22 = a[..., 2, 0], a[..., 2, 1], a[..., 2, 2]
    c00 = a11 * a22 - a12 * a21
    c01 = a02 * a21 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c10 = a12 * a20 - a10 * a22
    c11 = a00 * a22 - a02 * a20
    c12 = a02 * a10 - a00 * a12
    c20 = a10 * a21 - a11 * a20
    c21 = a01 * a20 - a00 * a21
    c22 = a00 * a11 - a01 * a10
    det = a00 * c00 + a01 * c10 + a02 * c20
    out = np.stack([c00, c01, c02, c10, c11, c12, c20, c21, c22], axis=-1).reshape(a.shape)
    return out / det[..., None, None]


@dataclass
class SchurStructure:
    """Index structure of the reduced camera system, computed once per adjustment.

    Parameters
    ----------
    camera_index, point_index : (M,) int, camera and point of each measure
    n_cameras, n_points, camera_dim : sizes
    pair_points : (M,) bool, measures whose point takes part in the elimination
        (False for held points: they contribute to U and g_c only)
    """

    camera_index: IndexArray
    point_index: IndexArray
    n_cameras: int
    n_points: int
    camera_dim: int
    pair_first: NDArray[np.int64] = field(init=False)
    pair_second: NDArray[np.int64] = field(init=False)
    block_row: NDArray[np.int64] = field(init=False)
    block_col: NDArray[np.int64] = field(init=False)
    diag_block: NDArray[np.int64] = field(init=False)
    pair_block: NDArray[np.int64] = field(init=False)
    _bsr_order: NDArray[np.int64] = field(init=False)
    _bsr_indices: NDArray[np.int32] = field(init=False)
    _bsr_indptr: NDArray[np.int32] = field(init=False)
    _offdiag: NDArray[np.int64] = field(init=False)

    @classmethod
    def build(
        cls,
        camera_index: IndexArray,
        point_index: IndexArray,
        n_cameras: int,
        n_points: int,
        camera_dim: int,
        eliminate: NDArray[np.bool_] | None = None,
    ) -> SchurStructure:
        self = cls(np.asarray(camera_index, np.int64), np.asarray(point_index, np.int64),
                   n_cameras, n_points, camera_dim)
        self._build(eliminate)
        return self

    def _build(self, eliminate: NDArray[np.bool_] | None) -> None:
        cam, pt = self.camera_index, self.point_index
        m = len(cam)
        use = np.ones(m, bool) if eliminate is None else eliminate[pt]
        # All ordered pairs (m1, m2) of measures of the same point.
        idx = np.flatnonzero(use)
        idx = idx[np.argsort(pt[idx], kind="stable")]
        counts = np.bincount(pt[idx], minlength=self.n_points)
        starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
        n_of = counts[pt[idx]]
        total = int(np.sum(n_of))
        first_pos = np.repeat(np.arange(len(idx)), n_of)
        run_start = np.repeat(np.cumsum(n_of) - n_of, n_of)
        second_pos = np.repeat(starts[pt[idx]], n_of) + (np.arange(total) - run_start)
        m1, m2 = idx[first_pos], idx[second_pos]
        c1, c2 = cam[m1], cam[m2]
        # Upper triangle of the camera blocks: pairs with c1 < c2, and every ordered pair
        # within one camera (so the diagonal block gets Y1 W2^T + Y2 W1^T).
        keep = c1 <= c2
        m1, m2, c1, c2 = m1[keep], m2[keep], c1[keep], c2[keep]
        # Unique blocks, with every diagonal block present even for cameras without pairs.
        diag = np.arange(self.n_cameras, dtype=np.int64)
        keys = np.concatenate([c1 * self.n_cameras + c2, diag * self.n_cameras + diag])
        ukeys, inverse = np.unique(keys, return_inverse=True)
        pair_block = inverse[: len(c1)]
        self.block_row = ukeys // self.n_cameras
        self.block_col = ukeys % self.n_cameras
        self.diag_block = inverse[len(c1):].copy()  # not a view: it would keep the pair-sized inverse alive
        self.pair_first, self.pair_second, self.pair_block = m1, m2, pair_block.astype(np.int64)
        # Block-CSR layout of the full symmetric matrix: upper blocks then transposed off-diagonals.
        off = np.flatnonzero(self.block_row != self.block_col)
        rows = np.concatenate([self.block_row, self.block_col[off]])
        cols = np.concatenate([self.block_col, self.block_row[off]])
        bsr_order = np.lexsort((cols, rows))
        self._offdiag = off
        self._bsr_order = bsr_order
        self._bsr_indices = cols[bsr_order].astype(np.int32)
        self._bsr_indptr = np.concatenate(
            [[0], np.cumsum(np.bincount(rows, minlength=self.n_cameras))]
        ).astype(np.int32)

    @property
    def n_blocks(self) -> int:
        return len(self.block_row)

    def to_bsr(self, blocks: NDArray[np.float64]) -> sp.bsr_matrix:
        """The full symmetric reduced matrix from its upper blocks (B, c, c)."""
        c = self.camera_dim
        full = np.concatenate([blocks, blocks[self._offdiag].transpose(0, 2, 1)])[self._bsr_order]
        n = self.n_cameras * c
        return sp.bsr_matrix((full, self._bsr_indices, self._bsr_indptr), shape=(n, n), blocksize=(c, c))

    def schur_blocks(
        self, w: NDArray[np.float64], v_inv: NDArray[np.float64], u: NDArray[np.float64]
    ) -> NDArray[np.float64]:
        """Upper blocks (B, c, c) of S = U - W V^-1 W^T.

        Parameters
        ----------
        w : (M, c, 3) per-measure Jc^T Jp
        v_inv : (n_points, 3, 3) inverses of the damped point blocks
        u : (n_cameras, c, c) damped camera blocks (with priors)
        """
        c = self.camera_dim
        blocks = np.zeros((self.n_blocks, c, c))
        schur_pairs(w, v_inv, self.point_index, self.pair_first, self.pair_second, self.pair_block, blocks)
        blocks *= -1.0
        blocks[self.diag_block] += u
        return blocks


@dataclass
class LinearSolveInfo:
    """How one reduced system was solved."""

    method: str
    iterations: int = 0
    ok: bool = True


class ReducedSolver:
    """Solves S x = b for successive matrices of one structure.

    ``method``: ``"dense"`` (LAPACK Cholesky of the dense matrix, small systems),
    ``"cholmod"`` (symbolic analysis reused across iterations),
    ``"splu"`` (SuperLU, the scipy fallback), or ``"pcg"`` (block-Jacobi
    preconditioned conjugate gradients, forcing tolerance ``pcg_tolerance``).
    """

    def __init__(self, method: str, camera_dim: int, pcg_tolerance: float = 0.1, pcg_max_iterations: int = 500):
        self.method = method
        self.c = camera_dim
        self.pcg_tolerance = pcg_tolerance
        self.pcg_max_iterations = pcg_max_iterations
        self._factor: Any = None

    def solve(
        self, matrix: sp.bsr_matrix, diag_blocks: NDArray[np.float64], rhs: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], LinearSolveInfo]:
        if self.method == "pcg":
            return self._pcg(matrix, diag_blocks, rhs)
        if self.method == "dense":
            try:
                fac = scipy.linalg.cho_factor(matrix.toarray(), check_finite=False)
            except np.linalg.LinAlgError:
                return np.full_like(rhs, np.nan), LinearSolveInfo("dense", ok=False)
            return scipy.linalg.cho_solve(fac, rhs, check_finite=False), LinearSolveInfo("dense")
        a = matrix.tocsc()
        if self.method == "cholmod":
            try:
                if self._factor is None:
                    self._factor = cholmod_factor(a)
                else:
                    self._factor.cholesky_inplace(a)
                return self._factor(rhs), LinearSolveInfo("cholmod")
            except _cholmod.CholmodNotPositiveDefiniteError:
                return np.full_like(rhs, np.nan), LinearSolveInfo("cholmod", ok=False)
        try:
            x = spla.splu(a, permc_spec="MMD_AT_PLUS_A").solve(rhs)
        except RuntimeError:  # exactly singular
            return np.full_like(rhs, np.nan), LinearSolveInfo("splu", ok=False)
        return x, LinearSolveInfo("splu")

    def _pcg(
        self, matrix: sp.bsr_matrix, diag_blocks: NDArray[np.float64], rhs: NDArray[np.float64]
    ) -> tuple[NDArray[np.float64], LinearSolveInfo]:
        c = self.c
        n_cam = diag_blocks.shape[0]
        try:
            pinv = np.linalg.inv(diag_blocks)
        except np.linalg.LinAlgError:
            return np.full_like(rhs, np.nan), LinearSolveInfo("pcg", ok=False)

        def precond(x: NDArray[np.float64]) -> NDArray[np.float64]:
            out: NDArray[np.float64] = np.matmul(pinv, x.reshape(n_cam, c, 1)).ravel()
            return out

        n = n_cam * c
        m_op = spla.LinearOperator((n, n), matvec=precond, dtype=np.float64)
        count = [0]

        def cb(_: Any) -> None:
            count[0] += 1

        x, info = spla.cg(matrix, rhs, rtol=self.pcg_tolerance, maxiter=self.pcg_max_iterations, M=m_op, callback=cb)
        return x, LinearSolveInfo("pcg", iterations=count[0], ok=bool(np.all(np.isfinite(x))))


#: Reduced systems up to this many unknowns are factored as dense matrices (LAPACK).
DENSE_MAX_UNKNOWNS = 2000


def choose_method(solver: str, n_unknowns: int, direct_max_unknowns: int) -> str:
    """Resolve ``"auto"``/``"direct"``/``"pcg"`` to ``"dense"``, ``"cholmod"``, ``"splu"`` or ``"pcg"``.

    Small systems (up to :data:`DENSE_MAX_UNKNOWNS`) are factored densely: a
    441-unknown BAL system takes ~2 ms with LAPACK against ~30 ms through
    CHOLMOD on Debian's reference BLAS.
    """
    if solver == "pcg" or (solver == "auto" and n_unknowns > direct_max_unknowns):
        return "pcg"
    if n_unknowns <= DENSE_MAX_UNKNOWNS:
        return "dense"
    return "cholmod" if HAVE_CHOLMOD else "splu"
