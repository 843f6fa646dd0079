"""A-posteriori covariances from the sparse factor of the reduced camera system (selected inversion).

The a-posteriori covariance of the cameras is ``sigma0^2 S^-1`` with ``S = U - W V^-1 W^T`` the undamped
reduced camera system at the solution (:mod:`mercury_dem.adjust.schur`); a point's is
``sigma0^2 (V^-1 + Y^T S^-1 Y)`` over the camera pairs of its measures (``Y = W V^-1``). Neither needs the
whole inverse: an image's covariance is a diagonal block of ``S^-1``, a point's needs the blocks of the image
pairs that share it, i.e. blocks where ``S`` itself is non-zero. All of these lie inside the pattern of the
sparse Cholesky factor ``L`` of ``S`` (``P S P^T = L D L^T``, unit ``L``), and the entries of ``Z = S^-1`` on
that pattern follow from ``L`` alone by the Takahashi recurrence (Takahashi, Fagan & Chin 1973; Erisman &
Tinney 1975), column by column from the last::

    Z[I, j] = -Z[I, I] l_j            (I: the rows of column j below the diagonal, l_j = L[I, j])
    Z[j, j] = 1 / D_j - l_j^T Z[I, j]

where every ``Z[I, I]`` entry needed is already known and on the pattern (the rows of a column of ``L`` form
a clique of the filled graph). The cost is that of the numeric factorization (``sum_j |I_j|^2``) and the
memory one more array of ``nnz(L)`` values: no column solves (``n`` solves of ``nnz(L)`` each), no dense
inverse (``n^2`` values). Hence no size limit but the factor's own.

Why our own: neither CHOLMOD through scikit-sparse (its ``Factor.inv`` forms the whole inverse) nor scipy
offers a selected inverse; the factorization is still CHOLMOD's (supernodal, fill-reducing ordering) or,
without scikit-sparse, SuperLU's with symmetric pivoting (``diag_pivot_thresh=0``, which on a symmetric
positive definite matrix is ``L D L^T``). The recurrence is compiled (numba, as
:mod:`mercury_dem.adjust.kernels`) and runs a supernode (a run of columns with one pattern) at a time: the
``Z[R, R]`` entries it needs gathered once into a dense block, the products done by BLAS
(:func:`_takahashi_supernodal`; 14x the column-by-column form, :func:`_takahashi`, kept as its check, on a
3·10⁶-measure network's system). Cost and memory measured: docs/benchmarks/adjust.md ("A-posteriori covariances
at size").

Pure functions: sparse matrices and arrays in, arrays out.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numpy.typing import NDArray

from mercury_dem.adjust.problem import IndexArray
from mercury_dem.adjust.schur import HAVE_CHOLMOD, CholmodNotPositiveDefinite, cholmod_factor
from mercury_dem.exceptions import AdjustmentError


@numba.njit(cache=True)
def _takahashi(indptr: NDArray[np.int64], indices: NDArray[np.int64], lval: NDArray[np.float64],
               dinv: NDArray[np.float64], z: NDArray[np.float64]) -> int:
    """Fill ``z`` (the layout of ``lval``) with ``L^-T D^-1 L^-1`` on the pattern of ``L`` (see the module docstring).

    ``indptr``, ``indices``: lower-triangular CSC pattern with sorted rows, the diagonal first in each column;
    ``lval``: the unit factor's entries below the diagonal (the diagonal slots are ignored); ``dinv``: ``1 / D``.
    Returns -1 on success, else the column whose rows are not a clique of the pattern (the pattern is not a
    symbolic factorization: the caller must not use ``z``).
    """
    n = len(indptr) - 1
    width = 0
    for j in range(n):
        width = max(width, indptr[j + 1] - indptr[j])
    s = np.zeros(width)
    for j in range(n - 1, -1, -1):
        p0 = indptr[j] + 1
        m = indptr[j + 1] - p0
        if indices[p0 - 1] != j:
            return j
        for a in range(m):
            s[a] = 0.0
        for b in range(m):
            k = indices[p0 + b]
            lk = lval[p0 + b]
            s[b] += z[indptr[k]] * lk  # Z[k, k]
            q, qe = indptr[k] + 1, indptr[k + 1]
            for a in range(b + 1, m):  # Z[i, k] for the rows i > k of column j: in column k (a clique)
                i = indices[p0 + a]
                while q < qe and indices[q] < i:
                    q += 1
                if q == qe or indices[q] != i:
                    return j
                zik = z[q]
                s[a] += zik * lk
                s[b] += zik * lval[p0 + a]
        d = dinv[j]
        for a in range(m):
            z[p0 + a] = -s[a]
            d += s[a] * lval[p0 + a]
        z[p0 - 1] = d
    return -1


@numba.njit(cache=True)
def _supernodes(indptr: NDArray[np.int64], indices: NDArray[np.int64]) -> NDArray[np.int64]:
    """First columns of the factor's supernodes (and n): runs of columns whose pattern is that of the next one
    plus its own diagonal (column j - 1 holds j and then exactly column j's rows).
    """
    n = len(indptr) - 1
    start = np.ones(n + 1, np.bool_)
    for j in range(1, n):
        cnt = indptr[j] - indptr[j - 1]
        if cnt > 1 and cnt == indptr[j + 1] - indptr[j] + 1 and indices[indptr[j - 1] + 1] == j:
            start[j] = False
    return np.flatnonzero(start)


@numba.njit(cache=True)
def _takahashi_supernodal(indptr: NDArray[np.int64], indices: NDArray[np.int64], lchol: NDArray[np.float64],
                          z: NDArray[np.float64]) -> int:
    """The recurrence of :func:`_takahashi` a supernode at a time, with dense products (BLAS) inside.

    For a supernode of columns ``J`` whose rows below are ``R`` (Cholesky ``L``, not unit: ``lchol``)::

        U = L[R, J] L[J, J]^-1,   Z[R, J] = -Z[R, R] U,   Z[J, J] = L[J, J]^-T L[J, J]^-1 - U^T Z[R, J]

    ``Z[R, R]`` gathered once per supernode (``|R|^2 / 2`` look-ups, against ``|J| |R|^2 / 2`` scalar
    multiply-adds of the column form). Same return convention as :func:`_takahashi`.
    """
    sn = _supernodes(indptr, indices)
    for s in range(len(sn) - 2, -1, -1):
        j0, j1 = sn[s], sn[s + 1]
        w = j1 - j0
        rp0 = indptr[j1 - 1] + 1
        r = indptr[j1] - rp0
        ljj = np.zeros((w, w))
        lrj = np.empty((r, w))
        for t in range(w):
            p = indptr[j0 + t]
            for u in range(t, w):
                if indices[p + u - t] != j0 + u:
                    return int(j0 + t)
                ljj[u, t] = lchol[p + u - t]
            base = p + w - t
            for a in range(r):
                lrj[a, t] = lchol[base + a]
        zrr = np.empty((r, r))
        for b in range(r):
            k = indices[rp0 + b]
            zrr[b, b] = z[indptr[k]]
            q, qe = indptr[k] + 1, indptr[k + 1]
            for a in range(b + 1, r):
                i = indices[rp0 + a]
                while q < qe and indices[q] < i:
                    q += 1
                if q == qe or indices[q] != i:
                    return int(j0)
                zrr[a, b] = z[q]
                zrr[b, a] = z[q]
        linv = np.linalg.inv(ljj)
        zjj = linv.T @ linv
        zrj = np.zeros((r, w))
        if r > 0:
            u_ = lrj @ linv
            zrj = -(zrr @ u_)
            zjj -= u_.T @ zrj
        for t in range(w):
            p = indptr[j0 + t]
            for u in range(t, w):
                z[p + u - t] = zjj[u, t]
            base = p + w - t
            for a in range(r):
                z[base + a] = zrj[a, t]
    return -1


@numba.njit(cache=True)
def _lookup(indptr: NDArray[np.int64], indices: NDArray[np.int64], z: NDArray[np.float64], rows: NDArray[np.int64],
            cols: NDArray[np.int64], out: NDArray[np.float64]) -> int:
    """``out[t] = Z[rows[t], cols[t]]`` (factored order, either triangle); returns the first missing ``t`` or -1."""
    for t in range(len(rows)):
        r, c = rows[t], cols[t]
        if r < c:
            r, c = c, r
        lo, hi = indptr[c], indptr[c + 1]
        while lo < hi:  # binary search of row r in column c
            mid = (lo + hi) // 2
            if indices[mid] < r:
                lo = mid + 1
            else:
                hi = mid
        if lo == indptr[c + 1] or indices[lo] != r:
            return t
        out[t] = z[lo]
    return -1


@dataclass(frozen=True)
class SelectedInverse:
    """Entries of ``A^-1`` on the pattern of ``A``'s sparse factor (see the module docstring).

    ``order[i]``: the factored position of ``A``'s unknown ``i``; ``indptr``, ``indices``, ``values``: the lower
    triangle of ``(P A P^T)^-1`` on the factor's pattern (CSC, sorted, diagonal first); ``method``: the factor's
    library (``"cholmod"`` or ``"splu"``); ``seconds``: factorization and ``recurrence``.
    """

    order: NDArray[np.int64]
    indptr: NDArray[np.int64]
    indices: NDArray[np.int64]
    values: NDArray[np.float64]
    method: str
    factor_seconds: float
    recurrence_seconds: float

    @property
    def n(self) -> int:
        return len(self.order)

    @property
    def nnz(self) -> int:
        """Stored entries (the factor's non-zeros, lower triangle with the diagonal)."""
        return len(self.values)

    def entries(self, rows: NDArray[np.int64], cols: NDArray[np.int64]) -> NDArray[np.float64]:
        """``A^-1[rows, cols]`` (unknowns in ``A``'s order); an entry off the factor's pattern is an error."""
        r = self.order[np.asarray(rows, np.int64).ravel()]
        c = self.order[np.asarray(cols, np.int64).ravel()]
        out = np.empty(len(r))
        bad = _lookup(self.indptr, self.indices, self.values, r, c, out)
        if bad >= 0:
            raise AdjustmentError(f"a-posteriori covariance: entry ({int(np.ravel(rows)[bad])}, {int(np.ravel(cols)[bad])}) "
                                  "is not on the factor's pattern (only blocks where the reduced system is non-zero, "
                                  "and the diagonal ones, can be asked for)")
        return out.reshape(np.shape(rows))

    def blocks(self, first: NDArray[np.int64], second: NDArray[np.int64], c: int) -> NDArray[np.float64]:
        """The (K, c, c) blocks ``A^-1[c i + a, c k + b]`` of unknown blocks ``i = first``, ``k = second``."""
        ar = np.arange(c)
        i = np.asarray(first, np.int64)[:, None, None] * c + ar[None, :, None]
        k = np.asarray(second, np.int64)[:, None, None] * c + ar[None, None, :]
        i, k = np.broadcast_arrays(i, k)
        return self.entries(i, k)


def _chol_cholmod(a: sp.csc_matrix) -> tuple[NDArray[np.int64], sp.csc_matrix]:
    try:
        factor = cholmod_factor(a)
    except CholmodNotPositiveDefinite as e:
        raise AdjustmentError(f"a-posteriori covariance: the reduced camera system is not positive definite ({e}); "
                              "the network has a free gauge or an unconstrained image: hold an image or keep the "
                              "pointing prior (apriori.pointing_sigma_urad)") from e
    lower = factor.L()
    perm = np.asarray(factor.P(), np.int64)  # A[perm][:, perm] = L L^T
    del factor
    lower.sort_indices()
    order = np.empty_like(perm)
    order[perm] = np.arange(len(perm))
    return order, lower


def _chol_splu(a: sp.csc_matrix) -> tuple[NDArray[np.int64], sp.csc_matrix]:
    try:
        lu = spla.splu(a, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError as e:
        raise AdjustmentError(f"a-posteriori covariance: the reduced camera system is singular ({e}); hold an image "
                              "or keep the pointing prior (apriori.pointing_sigma_urad)") from e
    if not np.array_equal(lu.perm_r, lu.perm_c):
        raise AdjustmentError("a-posteriori covariance: SuperLU pivoted off the diagonal (the reduced system is not "
                              "positive definite); install scikit-sparse (CHOLMOD) or check the network's gauge")
    d = lu.U.diagonal()
    if np.any(~(d > 0)):
        raise AdjustmentError("a-posteriori covariance: the reduced camera system is not positive definite; hold an "
                              "image or keep the pointing prior (apriori.pointing_sigma_urad)")
    lower, order = lu.L.tocsc(), np.asarray(lu.perm_c, np.int64)
    del lu
    lower.sort_indices()
    lower.data *= np.repeat(np.sqrt(d), np.diff(lower.indptr))  # unit L D^1/2: the Cholesky factor
    return order, lower


def selected_inverse(matrix: sp.spmatrix, method: str = "auto", supernodal: bool = True) -> SelectedInverse:
    """``matrix^-1`` (symmetric positive definite, sparse) on the pattern of its sparse factor.

    ``method``: ``"cholmod"`` (scikit-sparse), ``"splu"`` (scipy's SuperLU, symmetric pivoting), or ``"auto"``
    (CHOLMOD where importable). ``supernodal``: the recurrence a supernode at a time with dense products (the
    default: 10-15x faster on the reduced camera systems here), else column by column (scalar). Memory beside the
    matrix: the factor while it is made, then its lower triangle (12 bytes a non-zero) and the selected inverse
    (8 bytes a non-zero). Raises :class:`AdjustmentError` for a matrix that is not positive definite.
    """
    if method == "auto":
        method = "cholmod" if HAVE_CHOLMOD else "splu"
    if method not in ("cholmod", "splu"):
        raise AdjustmentError(f"a-posteriori covariance: unknown factorization {method!r} (cholmod, splu)")
    if method == "cholmod" and not HAVE_CHOLMOD:
        raise AdjustmentError("a-posteriori covariance: CHOLMOD asked for but scikit-sparse is not importable")
    t0 = time.perf_counter()
    a = sp.csc_matrix(matrix)
    order, lower = (_chol_cholmod if method == "cholmod" else _chol_splu)(a)
    del a
    t1 = time.perf_counter()
    indptr = lower.indptr.astype(np.int64)
    indices = lower.indices
    z = np.empty_like(lower.data)
    if supernodal:
        bad = _takahashi_supernodal(indptr, indices, lower.data, z)
    else:
        diag = lower.data[indptr[:-1]]
        unit = lower.data / np.repeat(diag, np.diff(indptr))
        bad = _takahashi(indptr, indices, unit, 1.0 / (diag * diag), z)
        del unit
    if bad >= 0:
        raise AdjustmentError(f"a-posteriori covariance: the {method} factor's pattern is not closed at column {bad} "
                              "(not a symbolic factorization); cannot select its inverse")
    return SelectedInverse(order, indptr, indices, z, method, t1 - t0, time.perf_counter() - t1)


def image_covariances(inverse: SelectedInverse, n_images: int, c: int, sigma0: float,
                      held: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """A-posteriori covariance (n_images, c, c) of each image's parameters: ``sigma0^2`` times the diagonal blocks
    of the reduced camera system's inverse; zero for held images (not read: their identity blocks may have lost
    their structural zeros).
    """
    free = np.ones(n_images, bool) if held is None else ~np.asarray(held, bool)
    idx = np.flatnonzero(free)
    cov = np.zeros((n_images, c, c))
    cov[idx] = sigma0 * sigma0 * inverse.blocks(idx, idx, c)
    return cov


def sigmas_of(cov: NDArray[np.float64]) -> NDArray[np.float64]:
    """Standard deviations (..., k) from stacked covariances (..., k, k) (negative rounding clipped to 0)."""
    return np.sqrt(np.maximum(np.diagonal(cov, axis1=-2, axis2=-1), 0.0))


def point_covariances(pair_blocks: Callable[[NDArray[np.int64], NDArray[np.int64]], NDArray[np.float64]], c: int,
                      sigma0: float, wm: NDArray[np.float64],
                      v_inv: NDArray[np.float64], cam: IndexArray, pt: IndexArray,
                      eliminated: NDArray[np.bool_], held: NDArray[np.bool_] | None = None,
                      chunk: int = 1 << 20) -> NDArray[np.float64]:
    """A-posteriori covariance (n_pt, 3, 3) of each point: ``sigma0^2 (V^-1 + sum Y_m1^T C[i1, i2] Y_m2)``.

    Over every ordered pair of measures (m1, m2) of the point (images i1, i2; ``Y = W V^-1``, ``W = Jc^T Jp``
    per measure (M, c, 3) with the measures' final weights, ``V^-1`` (n_pt, 3, 3) the inverses of the undamped
    point blocks, ``C`` the reduced system's inverse). The image pairs are those of the reduced system's blocks,
    so ``C`` is read off the selected inverse: ``pair_blocks(i, k)`` gives the (K, c, c) blocks ``C[i, k]`` for
    image indices ``i <= k`` (e.g. ``lambda i, k: inverse.blocks(i, k, c)``). Points not ``eliminated`` (held, or left with too few measures)
    get ``sigma0^2 V^-1`` as given; the caller zeroes what it does not report. Measures of ``held`` images and
    measures whose ``W`` is zero (rejected: weight 0) are left out: they add nothing, and an image pair whose
    shared measures are all rejected has a zero block of ``S`` that a factor may drop from its pattern. Pairs are formed ``chunk`` at a time.
    """
    n_pt = len(v_inv)
    cov = v_inv.copy()
    keep = eliminated[pt] & np.any(wm != 0, axis=(1, 2))  # rejected measures (weight 0) add nothing
    if held is not None:
        keep &= ~np.asarray(held, bool)[cam]
    use = np.flatnonzero(keep)
    order = use[np.argsort(pt[use], kind="stable")]
    counts = np.bincount(pt[order], minlength=n_pt)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    y = np.matmul(np.asarray(wm[order], np.float64), v_inv[pt[order]])  # (M', c, 3) in point order
    yt = y.transpose(0, 2, 1)
    cams = cam[order]
    n_of = counts[pt[order]]
    pos_start = np.cumsum(n_of) - n_of  # first pair of each measure
    total = int(n_of.sum())
    acc = np.zeros((n_pt, 9))
    for t0 in range(0, total, chunk):
        t1 = min(total, t0 + chunk)
        t = np.arange(t0, t1)
        first = np.searchsorted(pos_start, t, side="right") - 1
        second = starts[pt[order][first]] + (t - pos_start[first])
        c1, c2 = cams[first], cams[second]
        lo, hi = np.minimum(c1, c2), np.maximum(c1, c2)
        base = np.int64(max(int(cam.max()) + 1, 1))
        keys, inv = np.unique(lo * base + hi, return_inverse=True)
        blk = pair_blocks(keys // base, keys % base)[inv]
        swap = c1 > c2
        blk[swap] = blk[swap].transpose(0, 2, 1)
        contrib = np.matmul(np.matmul(yt[first], blk), y[second]).reshape(-1, 9)
        p = pt[order][first]
        for k in range(9):
            acc[:, k] += np.bincount(p, weights=contrib[:, k], minlength=n_pt)
    cov += acc.reshape(n_pt, 3, 3)
    return sigma0 * sigma0 * cov


def inverse_pair_blocks(inverse: SelectedInverse, keys: NDArray[np.int64], n_images: int, c: int,
                        held: NDArray[np.bool_] | None = None,
                        nonzero: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """The blocks ``S^-1[i, k]`` (K, c, c) for image-pair keys ``i * n_images + k`` (``i <= k``: the reduced
    system's upper blocks, ``blocked.GlobalStructure.keys``); zero (not read) where an image is held or where
    ``S``'s own block is not ``nonzero`` (all its shared measures rejected: a factor may have dropped it, and no
    point needs it, :func:`point_covariances`).
    """
    i, k = keys // n_images, keys % n_images
    live = np.ones(len(keys), bool) if held is None else ~(np.asarray(held, bool)[i] | np.asarray(held, bool)[k])
    if nonzero is not None:
        live &= np.asarray(nonzero, bool)
    out = np.zeros((len(keys), c, c))
    out[live] = inverse.blocks(i[live], k[live], c)
    return out


def keyed_pair_blocks(keys: NDArray[np.int64], blocks: NDArray[np.float64], images: NDArray[np.int64], n_images: int
                      ) -> Callable[[NDArray[np.int64], NDArray[np.int64]], NDArray[np.float64]]:
    """``pair_blocks`` for :func:`point_covariances` over local image indices (global ``images[local]``), read from
    sorted global pair ``keys`` and their ``blocks`` (what :func:`inverse_pair_blocks` gives).
    """

    def get(i: NDArray[np.int64], k: NDArray[np.int64]) -> NDArray[np.float64]:
        want = images[i] * np.int64(n_images) + images[k]
        at = np.minimum(np.searchsorted(keys, want), len(keys) - 1)
        if np.any(keys[at] != want):
            raise AdjustmentError("a-posteriori covariance: an image pair of the block is not among the reduced "
                                  "system's blocks sent to it")
        return blocks[at]

    return get
