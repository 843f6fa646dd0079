"""Compiled element-wise steps of the dense Lucas--Kanade refinement
(:func:`mercury_dem.dense.disparity.refine_disparity_lk`).

The window sums are OpenCV box filters (multi-channel, one call per iteration); these kernels fuse the
element-wise work between them -- the products fed to the box filters, the 2 x 2 solve of every window and
the next warp -- into one pass over the chip each. The same formulas in numpy took ~25 whole-chip float32
temporaries per iteration and cost more than the box filters and the resampling together (profile at 512^2,
docs/benchmarks/dense.md): the reason for compiling them. Arithmetic in float64 per pixel, arrays float32.

Compiled with numba (``cache=True``, warmed by :func:`mercury_dem.dense.refine_kernel.warm`), serial and
``nogil`` so that Dask's threads run chips side by side.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, nogil=True, error_model="numpy")
def prepare(left: NDArray[np.float32], right: NDArray[np.float32], initial: NDArray[np.float32], level: float,
            l1: NDArray[np.float32], r1: NDArray[np.float32], seeds: NDArray[np.float32],
            known: NDArray[np.bool_]) -> float:  # pragma: no cover - compiled
    """Both chips less ``level``; ``seeds = [d, 1]`` where ``initial`` is finite (``[0, 0]`` elsewhere) and
    ``known``; returns the mean of the finite seeds (0 if none).
    """
    hh, ww = left.shape
    lev = np.float32(level)
    for i in range(hh):
        for j in range(right.shape[1]):
            r1[i, j] = right[i, j] - lev
    total = 0.0
    count = 0
    for i in range(hh):
        for j in range(ww):
            l1[i, j] = left[i, j] - lev
            v = initial[i, j]
            k = np.isfinite(v)
            known[i, j] = k
            seeds[i, j, 0] = v if k else np.float32(0.0)
            seeds[i, j, 1] = np.float32(1.0) if k else np.float32(0.0)
            if k:
                total += v
                count += 1
    return total / count if count > 0 else 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def fixed_products(left: NDArray[np.float32], grad: NDArray[np.float32], out4: NDArray[np.float32],
                   out_gg: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """``out4 = [l, g, l^2, l g]`` and ``out_gg = g^2`` (the left chip's products, box-filtered once)."""
    hh, ww = left.shape
    for i in range(hh):
        for j in range(ww):
            lv = left[i, j]
            gv = grad[i, j]
            out4[i, j, 0] = lv
            out4[i, j, 1] = gv
            out4[i, j, 2] = lv * lv
            out4[i, j, 3] = lv * gv
            out_gg[i, j] = gv * gv


@numba.njit(cache=True, nogil=True, error_model="numpy")
def start(box2: NDArray[np.float32], fill: float, up: int, d: NDArray[np.float32],
          mx: NDArray[np.float32], dq: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """The starting warp: the box mean of the valid seeds (``box2 = box([known d, known])``; ``fill`` where no
    seed is in the window), and the map of the upsampled right chip at it (:func:`next_map`).
    """
    hh, ww = d.shape
    for i in range(hh):
        for j in range(ww):
            den = box2[i, j, 1]
            v = box2[i, j, 0] / den if den > 1e-6 else fill
            d[i, j] = v
            _map(i, j, v, up, mx, dq)


@numba.njit(cache=True, inline="always")
def _map(i: int, j: int, v: float, up: int, mx: NDArray[np.float32],
         dq: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """Column of the ``up``-times upsampled right chip at ``j + v``, rounded to the 1/32 px ``cv2.remap``
    resolves, and the disparity it stands for (``dq``).
    """
    x = np.rint((j + v) * 32.0 * up) / 32.0
    mx[i, j] = x
    dq[i, j] = x / up - j


@numba.njit(cache=True, nogil=True, error_model="numpy")
def products(left: NDArray[np.float32], grad: NDArray[np.float32], warped: NDArray[np.float32],
             dq: NDArray[np.float32], out4: NDArray[np.float32],
             out_wd: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """``out4 = [r, l r, g r, r^2]`` of the warped right chip ``r`` and ``out_wd = g^2 dq`` (to box-filter)."""
    hh, ww = left.shape
    for i in range(hh):
        for j in range(ww):
            r = warped[i, j]
            gv = grad[i, j]
            out4[i, j, 0] = r
            out4[i, j, 1] = left[i, j] * r
            out4[i, j, 2] = gv * r
            out4[i, j, 3] = r * r
            out_wd[i, j] = gv * gv * dq[i, j]


@numba.njit(cache=True, inline="always")
def _solve(fixed4: NDArray[np.float32], fixed_gg: NDArray[np.float32], it4: NDArray[np.float32],
           it_wd: NDArray[np.float32], i: int, j: int,
           fill: float) -> tuple[float, float, float, float, float, float, float]:  # pragma: no cover - compiled
    """The window's disparity (``fill`` where it cannot be solved), ``a``, ``c``, the centred moments
    ``c_lr, c_gr, c_rr`` and ``s_ll / det`` (0 where unsolved).
    """
    m_l = np.float64(fixed4[i, j, 0])
    m_g = np.float64(fixed4[i, j, 1])
    m_gg = np.float64(fixed_gg[i, j])
    s_ll = fixed4[i, j, 2] - m_l * m_l
    s_lg = fixed4[i, j, 3] - m_l * m_g
    s_gg = m_gg - m_g * m_g
    det = s_ll * s_gg - s_lg * s_lg
    m_r = np.float64(it4[i, j, 0])
    c_lr = it4[i, j, 1] - m_l * m_r
    c_gr = it4[i, j, 2] - m_g * m_r
    c_rr = it4[i, j, 3] - m_r * m_r
    inv = 1.0 / det if det > 0.0 else 0.0
    a = (s_gg * c_lr - s_lg * c_gr) * inv
    c = (s_ll * c_gr - s_lg * c_lr) * inv
    ok = a > 0.0 and m_gg > 0.0
    e = min(max(-c / a, -1.0), 1.0) if ok else 0.0
    v = it_wd[i, j] / m_gg + e if ok else fill
    return v, a if ok else 0.0, c, c_lr, c_gr, c_rr, s_ll * inv


@numba.njit(cache=True, nogil=True, error_model="numpy")
def update(fixed4: NDArray[np.float32], fixed_gg: NDArray[np.float32], it4: NDArray[np.float32],
           it_wd: NDArray[np.float32], fill: float, up: int, d: NDArray[np.float32], mx: NDArray[np.float32],
           dq: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """One Gauss--Newton step of every window (window means of the box filters in; ``d`` and the next map out).

    Model ``R_w = a L + c L' + b`` (centred window moments); ``e = -c / a`` (clipped to +-1 px); the window's
    disparity ``sum(g^2 dq) / sum(g^2) + e``; ``fill`` where the window cannot be solved (no gradient, a <= 0).
    """
    hh, ww = d.shape
    for i in range(hh):
        for j in range(ww):
            v = _solve(fixed4, fixed_gg, it4, it_wd, i, j, fill)[0]
            d[i, j] = v
            _map(i, j, v, up, mx, dq)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def update_last(fixed4: NDArray[np.float32], fixed_gg: NDArray[np.float32], it4: NDArray[np.float32],
                it_wd: NDArray[np.float32], n: float, noise: float, d: NDArray[np.float32],
                sigma: NDArray[np.float32], score: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """The last step (:func:`update`) with the stated precision and the score (NaN where unsolved):
    ``sigma^2 = s^2 (N^-1)_cc / a^2``, ``s^2`` the residual variance on ``n - 3`` degrees of freedom, times
    ``noise`` (sqrt of the noise correlation area); the score the windows' zero-mean normalised correlation.
    """
    hh, ww = d.shape
    nan = np.float32(np.nan)
    dof = n / max(n - 3.0, 1.0)
    for i in range(hh):
        for j in range(ww):
            v, a, c, c_lr, c_gr, c_rr, nll = _solve(fixed4, fixed_gg, it4, it_wd, i, j, np.nan)
            d[i, j] = v
            if a > 0.0:
                res = max(c_rr - a * c_lr - c * c_gr, 0.0) * dof
                sigma[i, j] = np.sqrt(res * nll / n) / a * noise
                s_ll = fixed4[i, j, 2] - np.float64(fixed4[i, j, 0]) ** 2
                score[i, j] = c_lr / np.sqrt(max(s_ll * c_rr, 1e-30))
            else:
                sigma[i, j] = nan
                score[i, j] = nan


@numba.njit(cache=True, nogil=True, error_model="numpy")
def finish(d: NDArray[np.float32], sigma: NDArray[np.float32], score: NDArray[np.float32],
           known: NDArray[np.bool_], d_out: NDArray[np.float32], sigma_out: NDArray[np.float32],
           score_out: NDArray[np.float32], slope_out: NDArray[np.float32]) -> None:  # pragma: no cover - compiled
    """Outputs NaN where there was no seed or no solution; the slope the central difference of ``d`` along
    the rows (0 at the chip's first and last columns, as ``cv2.Sobel``'s reflected border).
    """
    hh, ww = d.shape
    nan = np.float32(np.nan)
    for i in range(hh):
        for j in range(ww):
            if known[i, j] and np.isfinite(sigma[i, j]):
                d_out[i, j] = d[i, j]
                sigma_out[i, j] = sigma[i, j]
                score_out[i, j] = score[i, j]
                if 0 < j < ww - 1:
                    slope_out[i, j] = np.float32(0.5) * (d[i, j + 1] - d[i, j - 1])
                else:
                    slope_out[i, j] = np.float32(0.0)
            else:
                d_out[i, j] = nan
                sigma_out[i, j] = nan
                score_out[i, j] = nan
                slope_out[i, j] = nan


def warm() -> None:
    """Compile (or load from numba's cache) the kernels for the types the refinement passes."""
    f = np.zeros((4, 4), np.float32)
    f4 = np.zeros((4, 4, 4), np.float32)
    f2 = np.ones((4, 4, 2), np.float32)
    prepare(f, f, f, 0.0, f.copy(), f.copy(), f2.copy(), np.ones((4, 4), np.bool_))
    fixed_products(f, f, f4, f)
    start(f2, 0.0, 4, f, f.copy(), f.copy())
    products(f, f, f, f, f4, f)
    update(f4, f, f4, f, 0.0, 4, f, f.copy(), f.copy())
    update_last(f4, f, f4, f, 81.0, 1.0, f, f.copy(), f.copy())
    finish(f, f, f, np.ones((4, 4), np.bool_), f.copy(), f.copy(), f.copy(), f.copy())
