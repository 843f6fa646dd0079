"""Compiled kernel of the dense refinement's window fit (:func:`mercury_dem.dense.disparity.refine_disparity`).

One Gauss--Newton step of the 1-D affine window model for every pixel, each with its own whole-window
shift of the right chip: an integer column offset ``k`` plus a sub-pixel phase ``p`` (an index into
planes of the right chip and of its x-gradient already resampled at that phase). The numpy version grouped
the pixels by shift and box-filtered each group's bounding box (~13 box filters, 5 ramp filters and a 2 x 2
solve per group, ~30-50 groups per 128-px block): the time went to Python and small-array overhead and to
the overlap of the boxes (docs/benchmarks/dense.md). Here each pixel's window sums are built from
*column sums* (the ``w`` rows of one column at one shift), each computed once per row, column and shift
where it can be: along a row, a pixel whose shift equals its left neighbour's adds one new column, and a
shift seen a few pixels before finds its columns in a small direct-mapped table (the second pass's 1/8-px
shifts change every ~2 pixels but a window sees only ~4 of them). Every column sum is
summed over the rows top to bottom and the window over its columns left to right, in float64, whatever run
of equal shifts the pixel sits in: a pixel's result depends only on its own window and shift -- not on the
blocking, the run it belongs to or the thread count.

Borders as the numpy version's (OpenCV ``BORDER_REFLECT`` of the box filters at the array's edges, the
right chip's columns clamped at its edges).

Compiled with numba (``cache=True``, warmed by :mod:`mercury_dem.pipeline.warm`), serial and ``nogil`` so
that Dask's threads run chips side by side.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

#: Column-sum channels: l, r, g, ll, lr, rr, gg, lg, rg.
_NCH = 9
#: Tables of column sums per row (a power of 2), indexed by the shift: neighbouring 1/8-px shifts never share one.
_WAYS = 16


@numba.njit(cache=True, inline="always")
def _reflect(p: int, n: int) -> int:  # pragma: no cover - compiled
    """OpenCV's BORDER_REFLECT index (``fedcba|abcdefgh|hgfedcb``)."""
    if n == 1:
        return 0
    while p < 0 or p >= n:
        if p < 0:
            p = -p - 1
        else:
            p = 2 * n - p - 1
    return p


@numba.njit(cache=True, nogil=True, error_model="numpy")
def window_fit(left, rplanes, gplanes, col_offset, shift, phase, w, noise_factor, full,
               step, sigma, zncc, slope):  # pragma: no cover - compiled
    """Fit every pixel with ``phase >= 0``; write NaN elsewhere (``full`` False: the step only).

    Parameters
    ----------
    left : (H, W) float32, the left chip
    rplanes, gplanes : (P, H, W2) float32, the right chip and its x-gradient resampled at each phase; left
        column ``c`` at integer shift ``k`` samples plane column ``c + k + col_offset`` (clamped to the plane)
    col_offset : int, columns of padding on the planes' left
    shift, phase : (H, W) int64, each pixel's integer shift and phase index (-1: not fitted)
    w : odd window side
    noise_factor : ``sqrt(max(noise_correlation_px2, 1))``
    full : also write sigma, zncc and slope (False: only ``step``; the others are left as they are)
    step, sigma, zncc, slope : (H, W) float32 outputs: the Gauss--Newton step of the shift, its stated
        precision, the windows' zero-mean normalised correlation and the fitted disparity slope (px per px)

    Model ``I_l ~ a I_r(u + d + t + s x) + b`` linearised in ``(t, s)``: ``a (g t + h s) = residual`` over the
    window, a 2 x 2 system per pixel (Cramer's rule), ``a`` the windows' regression gain; the residual
    variance has ``n - 4`` degrees of freedom (t, s, a, b) and ``sigma = sqrt(s^2 (N^-1)_11) noise_factor``.
    """
    hh, ww = left.shape
    w2 = rplanes.shape[2]
    half = w // 2
    n = float(w * w)
    inv_n = 1.0 / n
    dof = n / (n - 4.0)
    # column sums of the current row: column c at index c + half, in one of _WAYS tables chosen by the shift
    # (direct-mapped; tags say which row and shift a table's column holds)
    npl = rplanes.shape[0]
    cs = np.zeros((_WAYS, ww + 2 * half, _NCH), np.float64)
    tag_row = np.full((_WAYS, ww + 2 * half), -1, np.int64)
    tag_k = np.zeros((_WAYS, ww + 2 * half), np.int64)
    tag_p = np.zeros((_WAYS, ww + 2 * half), np.int64)
    rows = np.empty(w, np.int64)
    for i in range(hh):
        for t in range(w):
            rows[t] = _reflect(i + t - half, hh)
        prev_j = -10
        prev_k = 0
        prev_p = -1
        for j in range(ww):
            p = phase[i, j]
            if p < 0:
                step[i, j] = np.nan
                if full:
                    sigma[i, j] = np.nan
                    zncc[i, j] = np.nan
                    slope[i, j] = np.nan
                continue
            k = shift[i, j]
            if prev_j == j - 1 and prev_k == k and prev_p == p:
                c_first = j + half  # one new column; the others are the neighbour's
            else:
                c_first = j - half
            way = (k * npl + p) & (_WAYS - 1)
            for c in range(c_first, j + half + 1):
                slot = c + half
                if tag_row[way, slot] == i and tag_k[way, slot] == k and tag_p[way, slot] == p:
                    continue  # summed already in this row for this shift
                tag_row[way, slot] = i
                tag_k[way, slot] = k
                tag_p[way, slot] = p
                cc = _reflect(c, ww)
                rc = cc + k + col_offset
                if rc < 0:
                    rc = 0
                elif rc > w2 - 1:
                    rc = w2 - 1
                sl = 0.0
                sr = 0.0
                sg = 0.0
                sll = 0.0
                slr = 0.0
                srr = 0.0
                sgg = 0.0
                slg = 0.0
                srg = 0.0
                for t in range(w):
                    y = rows[t]
                    lv = float(left[y, cc])
                    rv = float(rplanes[p, y, rc])
                    gv = float(gplanes[p, y, rc])
                    sl += lv
                    sr += rv
                    sg += gv
                    sll += lv * lv
                    slr += lv * rv
                    srr += rv * rv
                    sgg += gv * gv
                    slg += lv * gv
                    srg += rv * gv
                cs[way, slot, 0] = sl
                cs[way, slot, 1] = sr
                cs[way, slot, 2] = sg
                cs[way, slot, 3] = sll
                cs[way, slot, 4] = slr
                cs[way, slot, 5] = srr
                cs[way, slot, 6] = sgg
                cs[way, slot, 7] = slg
                cs[way, slot, 8] = srg
            prev_j = j
            prev_k = k
            prev_p = p
            # window sums, columns left to right; h = g x (x: column offset from the centre)
            s_l = 0.0
            s_r = 0.0
            s_g = 0.0
            s_ll = 0.0
            s_lr = 0.0
            s_rr = 0.0
            s_gg = 0.0
            s_lg = 0.0
            s_rg = 0.0
            s_h = 0.0
            s_gh = 0.0
            s_hh = 0.0
            s_lh = 0.0
            s_rh = 0.0
            for t in range(w):
                x = float(t - half)
                slot = j + t
                s_l += cs[way, slot, 0]
                s_r += cs[way, slot, 1]
                s_g += cs[way, slot, 2]
                s_ll += cs[way, slot, 3]
                s_lr += cs[way, slot, 4]
                s_rr += cs[way, slot, 5]
                s_gg += cs[way, slot, 6]
                s_lg += cs[way, slot, 7]
                s_rg += cs[way, slot, 8]
                s_h += x * cs[way, slot, 2]
                s_gh += x * cs[way, slot, 6]
                s_hh += x * x * cs[way, slot, 6]
                s_lh += x * cs[way, slot, 7]
                s_rh += x * cs[way, slot, 8]
            ml = s_l * inv_n
            mr = s_r * inv_n
            mg = s_g * inv_n
            mh = s_h * inv_n
            m_ll = s_ll * inv_n - ml * ml
            m_lr = s_lr * inv_n - ml * mr
            m_rr = s_rr * inv_n - mr * mr
            m_gg = s_gg * inv_n - mg * mg
            m_gh = s_gh * inv_n - mg * mh
            m_hh = s_hh * inv_n - mh * mh
            m_lg = s_lg * inv_n - ml * mg
            m_rg = s_rg * inv_n - mr * mg
            m_lh = s_lh * inv_n - ml * mh
            m_rh = s_rh * inv_n - mr * mh
            # the 2 x 2 Gauss--Newton system (the numpy version's formulas, in float64)
            a = m_lr / m_rr
            b1 = (m_lg - a * m_rg) / a
            b2 = (m_lh - a * m_rh) / a
            det = m_gg * m_hh - m_gh * m_gh
            st = (m_hh * b1 - m_gh * b2) / det
            step[i, j] = st
            if not full:
                continue
            sp = (m_gg * b2 - m_gh * b1) / det
            rss = m_ll - a * m_lr - a * a * (st * b1 + sp * b2)
            if rss < 0.0:
                rss = 0.0
            rss = rss * dof
            sigma[i, j] = np.sqrt(rss * m_hh / (a * a * det * n)) * noise_factor
            zncc[i, j] = m_lr / np.sqrt(m_ll * m_rr)
            slope[i, j] = sp


@numba.njit(cache=True, nogil=True)
def after_first_pass(k0, known, step, quantum, d, ok, q):  # pragma: no cover - compiled
    """Between the passes, per pixel: ``ok`` (a finite step), ``d = k0 + clip(step, -1, 1)`` (float32 clip,
    float64 sum; ``k0`` where not ok) and ``q = rint(d / quantum)``; returns the smallest and largest ``q`` of
    the ok pixels (``(0, -1)`` if none).
    """
    qmin = np.int64(0)
    qmax = np.int64(-1)
    first = True
    hh, ww = k0.shape
    for i in range(hh):
        for j in range(ww):
            s = step[i, j]
            if s > np.float32(1.0):
                s = np.float32(1.0)
            elif s < np.float32(-1.0):
                s = np.float32(-1.0)
            good = known[i, j] and np.isfinite(s)
            ok[i, j] = good
            if good:
                dv = float(k0[i, j]) + float(s)
            else:
                dv = float(k0[i, j])
            d[i, j] = dv
            qv = np.int64(np.rint(dv / quantum))
            q[i, j] = qv
            if good:
                if first or qv < qmin:
                    qmin = qv
                if first or qv > qmax:
                    qmax = qv
                first = False
    return qmin, qmax


@numba.njit(cache=True, nogil=True)
def quanta_present(q, ok, qmin, qmax):  # pragma: no cover - compiled
    """Which quanta ``qmin .. qmax`` some ok pixel has (bool array)."""
    present = np.zeros(qmax - qmin + 1, np.bool_)
    hh, ww = q.shape
    for i in range(hh):
        for j in range(ww):
            if ok[i, j]:
                present[q[i, j] - qmin] = True
    return present


@numba.njit(cache=True, nogil=True)
def shift_and_phase(q, ok, qmin, lut_k, lut_p, kk, phase):  # pragma: no cover - compiled
    """Each ok pixel's integer shift and phase index from its quantum (tables over ``qmin ..``); -1 elsewhere."""
    hh, ww = q.shape
    for i in range(hh):
        for j in range(ww):
            if ok[i, j]:
                kk[i, j] = lut_k[q[i, j] - qmin]
                phase[i, j] = lut_p[q[i, j] - qmin]
            else:
                kk[i, j] = 0
                phase[i, j] = -1


@numba.njit(cache=True, nogil=True)
def finish_second_pass(q, quantum, known, ok, step, sigma, score, slope,
                       d_out, sigma_out, score_out, slope_out):  # pragma: no cover - compiled
    """The outputs: ``d = q quantum + clip(step, -1, 1)`` (float64, then float32) and the pass's sigma, score,
    slope; NaN where the seed was NaN, the first pass failed, or sigma or d is not finite.
    """
    nan = np.float32(np.nan)
    hh, ww = q.shape
    for i in range(hh):
        for j in range(ww):
            s = step[i, j]
            if s > np.float32(1.0):
                s = np.float32(1.0)
            elif s < np.float32(-1.0):
                s = np.float32(-1.0)
            dv = float(q[i, j]) * quantum + float(s)
            if not known[i, j] or not ok[i, j] or not np.isfinite(sigma[i, j]) or not np.isfinite(dv):
                d_out[i, j] = nan
                sigma_out[i, j] = nan
                score_out[i, j] = nan
                slope_out[i, j] = nan
            else:
                d_out[i, j] = np.float32(dv)
                sigma_out[i, j] = sigma[i, j]
                score_out[i, j] = score[i, j]
                slope_out[i, j] = slope[i, j]


@numba.njit(cache=True, nogil=True)
def flag_holes(d0, seed, d, sigma, score, slope, left_valid, right_valid, lit_l, lit_r, dark_l, dark_r,
               max_sigma, min_score, holes, d_out, sigma_out, score_out, slope_out):  # pragma: no cover - compiled
    """Hole flags and outputs of :func:`mercury_dem.dense.disparity.dense_disparity` in one pass (its numpy
    expressions, element by element, float32 comparisons as numpy's with float32 thresholds).

    Bits: 1 outside (the left pixel, or the right pixel it matched -- rounded -- is not inside its image),
    2 shadow (``lit_l`` below ``dark_l`` or ``lit_r`` at the matched column below ``dark_r``), 4 no texture
    (SGBM matched but sigma not <= ``max_sigma``), 8 no SGBM match, 16 refinement (left the SGBM pixel by
    more than 1 or score not >= ``min_score``). Outputs NaN in holes; the score everywhere (NaN as 0).
    """
    hh, ww = d.shape
    nan = np.float32(np.nan)
    big = np.float32(3.4028234663852886e38)
    for i in range(hh):
        for j in range(ww):
            h = np.uint8(0)
            dv = d[i, j]
            target = np.float32(j) + (dv if np.isfinite(dv) else seed[i, j])
            t = np.float32(-1.0) if np.isnan(target) else np.rint(target)
            if t < -1.0:
                t = np.float32(-1.0)
            elif t > ww:
                t = np.float32(ww)
            ti = np.int64(t)
            rv = ti >= 0 and ti < ww and right_valid[i, ti]
            if not left_valid[i, j] or (np.isfinite(target) and not rv):
                h |= np.uint8(1)
            tc = min(max(ti, 0), ww - 1)
            if lit_l[i, j] < dark_l or lit_r[i, tc] < dark_r:
                h |= np.uint8(2)
            if not np.isfinite(d0[i, j]):
                h |= np.uint8(8)
            elif not sigma[i, j] <= max_sigma:
                h |= np.uint8(4)
            if np.isfinite(dv) and (abs(dv - seed[i, j]) > np.float32(1.0) or not score[i, j] >= min_score):
                h |= np.uint8(16)
            holes[i, j] = h
            if h == 0:
                d_out[i, j] = dv
                sigma_out[i, j] = sigma[i, j]
                slope_out[i, j] = slope[i, j]
            else:
                d_out[i, j] = nan
                sigma_out[i, j] = nan
                slope_out[i, j] = nan
            sc = score[i, j]
            if np.isnan(sc):
                sc = np.float32(0.0)
            elif sc > big:
                sc = big
            elif sc < -big:
                sc = -big
            score_out[i, j] = sc


def fit_windows(left: NDArray[np.float32], rplanes: NDArray[np.float32], gplanes: NDArray[np.float32],
                col_offset: int, shift: NDArray[np.int64], phase: NDArray[np.int64], w: int,
                noise_factor: float, full: bool = True) -> tuple[NDArray[np.float32], ...]:
    """:func:`window_fit` with its outputs allocated: ``(step, sigma, zncc, slope)``, each (H, W) float32
    (``full`` False: only ``step`` is filled, the others are returned uninitialised).
    """
    out = tuple(np.empty(left.shape if k == 0 or full else (1, 1), np.float32) for k in range(4))
    window_fit(np.ascontiguousarray(left, np.float32), np.ascontiguousarray(rplanes, np.float32),
               np.ascontiguousarray(gplanes, np.float32), int(col_offset),
               np.ascontiguousarray(shift, np.int64), np.ascontiguousarray(phase, np.int64), int(w),
               float(noise_factor), bool(full), *out)
    return out


def warm() -> None:
    """Compile (or load from numba's cache) the kernels for the types the refinements pass (both methods)."""
    from mercury_dem.dense import lk_kernel

    lk_kernel.warm()
    z = np.zeros((1, 4, 4), np.float32)
    i4 = np.zeros((4, 4), np.int64)
    yes = np.ones((4, 4), np.bool_)
    step = fit_windows(z[0], z, z, 0, i4, i4, 3, 1.0, full=False)[0]
    fit_windows(z[0], z, z, 0, i4, i4, 3, 1.0)
    d = np.empty((4, 4), np.float64)
    ok = np.empty((4, 4), np.bool_)
    q = np.empty((4, 4), np.int64)
    after_first_pass(i4, yes, step, 0.125, d, ok, q)
    quanta_present(q, ok, np.int64(0), np.int64(1))
    shift_and_phase(q, ok, np.int64(0), i4[0], i4[0], i4.copy(), i4.copy())
    finish_second_pass(q, 0.125, yes, ok, step, step, step, step, *(np.empty((4, 4), np.float32) for _ in range(4)))
    f4 = np.float32(0.5)
    flag_holes(step, step, step, step, step, step, yes, yes, step, step, f4, f4, f4, f4, np.empty((4, 4), np.uint8),
               *(np.empty((4, 4), np.float32) for _ in range(4)))
