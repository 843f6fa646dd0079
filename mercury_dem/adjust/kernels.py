"""Compiled (numba) loops of the normal-equation assembly.

Why not numpy: the work is millions of tiny (c x 2) and (c x 3) products summed
into blocks. Stacked ``np.matmul`` on such small matrices runs at a fraction of
a flop per cycle, and a gather of the two operands of every measure pair costs
more than the product (measured on BAL problem-49: 66 ms per assembly with
``np.matmul`` + sparse segment sums, 15-20 ms here). numba is already a project
dependency; the functions are cached on disk (``cache=True``) so only the first
run on a machine pays the ~1-2 s compilation.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from mercury_dem.adjust.problem import IndexArray


@numba.njit(cache=True, fastmath=True)
def normal_blocks(
    r: NDArray[np.float64],
    jc: NDArray[np.float64],
    jp: NDArray[np.float64],
    cam: IndexArray,
    pt: IndexArray,
    u: NDArray[np.float64],
    g_c: NDArray[np.float64],
    v: NDArray[np.float64],
    g_p: NDArray[np.float64],
    w: NDArray[np.float64],
) -> None:
    """Accumulate U += Jc^T Jc, g_c += Jc^T r (per camera), V += Jp^T Jp, g_p += Jp^T r
    (per point), and set W[m] = Jc^T Jp per measure. Rows are (M, 2, .) blocks.
    """
    c = jc.shape[2]
    for m in range(r.shape[0]):
        i = cam[m]
        j = pt[m]
        for a in range(c):
            ja0 = jc[m, 0, a]
            ja1 = jc[m, 1, a]
            g_c[i, a] += ja0 * r[m, 0] + ja1 * r[m, 1]
            for b in range(c):
                u[i, a, b] += ja0 * jc[m, 0, b] + ja1 * jc[m, 1, b]
            for b in range(3):
                w[m, a, b] = ja0 * jp[m, 0, b] + ja1 * jp[m, 1, b]
        for a in range(3):
            pa0 = jp[m, 0, a]
            pa1 = jp[m, 1, a]
            g_p[j, a] += pa0 * r[m, 0] + pa1 * r[m, 1]
            for b in range(3):
                v[j, a, b] += pa0 * jp[m, 0, b] + pa1 * jp[m, 1, b]


@numba.njit(cache=True, fastmath=True)
def _w_vinv(w: NDArray[np.float64], v_inv: NDArray[np.float64], pt: IndexArray) -> NDArray[np.float64]:
    """Y[m] = W[m] V^-1[pt[m]] for every measure (M, c, 3): the left factor of each pair's Schur block."""
    m_count, c, _ = w.shape
    y = np.empty((m_count, c, 3))
    for m in range(m_count):
        q = v_inv[pt[m]]
        for a in range(c):
            for b in range(3):
                y[m, a, b] = w[m, a, 0] * q[0, b] + w[m, a, 1] * q[1, b] + w[m, a, 2] * q[2, b]
    return y


@numba.njit(cache=True, fastmath=True, inline="always")
def _add_pair(out: NDArray[np.float64], k: int, y: NDArray[np.float64], w: NDArray[np.float64],
              m1: int, m2: int) -> None:
    """out[k] += Y[m1] W[m2]^T, one measure pair's term of the reduced camera system."""
    c = w.shape[1]
    for a in range(c):
        y0 = y[m1, a, 0]
        y1 = y[m1, a, 1]
        y2 = y[m1, a, 2]
        for b in range(c):
            out[k, a, b] += y0 * w[m2, b, 0] + y1 * w[m2, b, 1] + y2 * w[m2, b, 2]


@numba.njit(cache=True, fastmath=True)
def schur_pairs(
    w: NDArray[np.float64],
    v_inv: NDArray[np.float64],
    pt: IndexArray,
    first: NDArray[np.int64],
    second: NDArray[np.int64],
    block: NDArray[np.int64],
    out: NDArray[np.float64],
) -> None:
    """out[block[p]] += W[first[p]] V^-1[pt] W[second[p]]^T over measure pairs p of one point."""
    y = _w_vinv(w, v_inv, pt)
    for p in range(first.shape[0]):
        m1 = first[p]
        m2 = second[p]
        k = block[p]
        _add_pair(out, k, y, w, m1, m2)


@numba.njit(cache=True, fastmath=True)
def schur_pairs_grouped(
    w: NDArray[np.float64],
    v_inv: NDArray[np.float64],
    pt: IndexArray,
    cam: IndexArray,
    order: IndexArray,
    ptr: IndexArray,
    block: NDArray[np.int64],
    out: NDArray[np.float64],
) -> None:
    """:func:`schur_pairs` without the pair lists: the pairs are enumerated from the measures grouped by point.

    ``order`` lists the measures of the eliminated points grouped by point (``ptr[p]:ptr[p + 1]`` is point
    ``p``'s run), in :class:`~mercury_dem.adjust.schur.SchurStructure`'s order; the pairs ``(m1, m2)`` of a run with
    ``cam[m1] <= cam[m2]`` come in the order of its pair lists, so ``block`` (one entry a pair) is its ``pair_block``
    and the sums are the same. Why: the two pair lists were 35 of the ~200 bytes a measure the blocked adjustment
    keeps (4.4 pairs a measure at 7 views a point); enumerating them costs a comparison a pair.
    """
    y = _w_vinv(w, v_inv, pt)
    p = 0
    for g in range(ptr.shape[0] - 1):
        for i in range(ptr[g], ptr[g + 1]):
            m1 = order[i]
            for j in range(ptr[g], ptr[g + 1]):
                m2 = order[j]
                if cam[m1] > cam[m2]:
                    continue
                k = block[p]
                p += 1
                _add_pair(out, k, y, w, m1, m2)


@numba.njit(cache=True, fastmath=True)
def schur_pairs_table(
    w: NDArray[np.float64],
    v_inv: NDArray[np.float64],
    pt: IndexArray,
    cam: IndexArray,
    order: IndexArray,
    ptr: IndexArray,
    table: NDArray[np.int32],
    out: NDArray[np.float64],
) -> None:
    """:func:`schur_pairs_grouped` with each pair's block looked up in ``table[cam[m1], cam[m2]]`` (n_cam, n_cam).

    The same pairs in the same order into the same blocks, so the same sums, bit for bit. Why: the per-pair block
    index (``block``, 4 B a pair, ~17.5 B a measure) is the largest index array a block keeps; a table of the
    block's images (4 n_cam^2 B: 1.1 MB for 533 images, against 3.1 MB of pair indices of its 180,000 measures)
    replaces it when smaller.
    """
    y = _w_vinv(w, v_inv, pt)
    for g in range(ptr.shape[0] - 1):
        for i in range(ptr[g], ptr[g + 1]):
            m1 = order[i]
            for j in range(ptr[g], ptr[g + 1]):
                m2 = order[j]
                if cam[m1] > cam[m2]:
                    continue
                _add_pair(out, table[cam[m1], cam[m2]], y, w, m1, m2)


@numba.njit(cache=True, fastmath=True)
def prior_blocks(
    r: NDArray[np.float64], jac: NDArray[np.float64], h: NDArray[np.float64], g: NDArray[np.float64]
) -> None:
    """h[i] += J_i^T J_i, g[i] += J_i^T r_i for prior rows r (N, k), J (N, k, d)."""
    n, k, d = jac.shape
    for i in range(n):
        for a in range(d):
            s = 0.0
            for t in range(k):
                s += jac[i, t, a] * r[i, t]
            g[i, a] += s
            for b in range(d):
                s = 0.0
                for t in range(k):
                    s += jac[i, t, a] * jac[i, t, b]
                h[i, a, b] += s


@numba.njit(cache=True, fastmath=True, error_model="numpy")  # 1/0 gives inf (then AdjustmentError), not ZeroDivisionError
def bal_project(
    rot: NDArray[np.float64],
    par: NDArray[np.float64],
    points: NDArray[np.float64],
    cam: IndexArray,
    pt: IndexArray,
    obs: NDArray[np.float64],
    res: NDArray[np.float64],
    jc: NDArray[np.float64],
    jp: NDArray[np.float64],
    with_jacobian: bool,
) -> None:
    """BAL residuals (M, 2) and, when asked, Jacobians d r/d(dtheta, t, f, k1, k2) (M, 2, 9)
    and d r/d X (M, 2, 3); see :mod:`mercury_dem.adjust.bal` for the model.
    """
    for m in range(cam.shape[0]):
        i = cam[m]
        j = pt[m]
        rx0 = rot[i, 0, 0] * points[j, 0] + rot[i, 0, 1] * points[j, 1] + rot[i, 0, 2] * points[j, 2]
        rx1 = rot[i, 1, 0] * points[j, 0] + rot[i, 1, 1] * points[j, 1] + rot[i, 1, 2] * points[j, 2]
        rx2 = rot[i, 2, 0] * points[j, 0] + rot[i, 2, 1] * points[j, 1] + rot[i, 2, 2] * points[j, 2]
        p0 = rx0 + par[i, 0]
        p1 = rx1 + par[i, 1]
        p2 = rx2 + par[i, 2]
        iz = 1.0 / p2
        px = -p0 * iz
        py = -p1 * iz
        f = par[i, 3]
        k1 = par[i, 4]
        k2 = par[i, 5]
        n2 = px * px + py * py
        d = 1.0 + k1 * n2 + k2 * n2 * n2
        res[m, 0] = f * d * px - obs[m, 0]
        res[m, 1] = f * d * py - obs[m, 1]
        if not with_jacobian:
            continue
        # dr/dp = f (d I + a p p^T), a = 2 (k1 + 2 k2 n2)
        a = 2.0 * (k1 + 2.0 * k2 * n2) * f
        a00 = f * d + a * px * px
        a01 = a * px * py
        a11 = f * d + a * py * py
        # dr/dP = dr/dp * (1/Pz) [[-1, 0, -px], [0, -1, -py]]
        e = np.empty((2, 3))
        e[0, 0] = -a00 * iz
        e[0, 1] = -a01 * iz
        e[0, 2] = -(a00 * px + a01 * py) * iz
        e[1, 0] = -a01 * iz
        e[1, 1] = -a11 * iz
        e[1, 2] = -(a01 * px + a11 * py) * iz
        for k in range(2):
            # d P / d dtheta = -[R X]x  ->  row e_k times -[rx]x = rx x e_k
            jc[m, k, 0] = rx1 * e[k, 2] - rx2 * e[k, 1]
            jc[m, k, 1] = rx2 * e[k, 0] - rx0 * e[k, 2]
            jc[m, k, 2] = rx0 * e[k, 1] - rx1 * e[k, 0]
            jc[m, k, 3] = e[k, 0]
            jc[m, k, 4] = e[k, 1]
            jc[m, k, 5] = e[k, 2]
            for b in range(3):
                jp[m, k, b] = e[k, 0] * rot[i, 0, b] + e[k, 1] * rot[i, 1, b] + e[k, 2] * rot[i, 2, b]
        jc[m, 0, 6] = d * px
        jc[m, 1, 6] = d * py
        jc[m, 0, 7] = f * n2 * px
        jc[m, 1, 7] = f * n2 * py
        jc[m, 0, 8] = f * n2 * n2 * px
        jc[m, 1, 8] = f * n2 * n2 * py


@numba.njit(cache=True, fastmath=True)
def reduced_rhs(
    w: NDArray[np.float64], t_p: NDArray[np.float64], cam: IndexArray, pt: IndexArray, b: NDArray[np.float64]
) -> None:
    """b[cam] += W[m] t_p[pt] over measures (the W V^-1 g_p part of the reduced right-hand side)."""
    c = w.shape[1]
    for m in range(w.shape[0]):
        i = cam[m]
        j = pt[m]
        for a in range(c):
            b[i, a] += w[m, a, 0] * t_p[j, 0] + w[m, a, 1] * t_p[j, 1] + w[m, a, 2] * t_p[j, 2]


@numba.njit(cache=True, fastmath=True)
def point_rhs(
    w: NDArray[np.float64], dc: NDArray[np.float64], cam: IndexArray, pt: IndexArray, q: NDArray[np.float64]
) -> None:
    """q[pt] += W[m]^T dc[cam] over measures (for the point back-substitution)."""
    c = w.shape[1]
    for m in range(w.shape[0]):
        i = cam[m]
        j = pt[m]
        for b in range(3):
            s = 0.0
            for a in range(c):
                s += w[m, a, b] * dc[i, a]
            q[j, b] += s
