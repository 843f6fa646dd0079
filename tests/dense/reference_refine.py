"""The refinement as it was before the compiled kernel (commit 811541b, numpy + OpenCV, grouped passes):
the reference that ``test_refine_kernel.py`` compares the library's refinement with. Verbatim copy; not used
by the library.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.dense.disparity import MatcherSettings, lanczos4_weights


def _box(x: NDArray[np.float32], w: int) -> NDArray[np.float32]:
    return np.asarray(cv2.boxFilter(x, cv2.CV_32F, (w, w), normalize=True, borderType=cv2.BORDER_REFLECT), np.float32)


def _window_stats(l1: NDArray[np.float32], r2: NDArray[np.float32], g: NDArray[np.float32],
                  w: int) -> dict[str, NDArray[np.float32]]:
    """Centred window moments for the 1-D affine model (window means: box filters and a ramp-weighted box).

    With ``l1`` the left chip, ``r2`` the right chip resampled at the current disparity, ``g`` its
    x-gradient there and ``h = g x`` (``x`` the column offset from the window's centre), returns the
    covariances ``ll, lr, rr`` and those of the regressors ``g, h`` with ``l``, ``r`` and each other
    (``lg, rg, lh, rh, gg, gh, hh``).
    """
    ramp = np.arange(w, dtype=np.float32) - np.float32(w // 2)
    ones = np.ones(w, np.float32) / w

    def ramp_box(x: NDArray[np.float32], k: NDArray[np.float32]) -> NDArray[np.float32]:
        return np.asarray(cv2.sepFilter2D(x, cv2.CV_32F, k / w, ones, borderType=cv2.BORDER_REFLECT), np.float32)

    gg = np.asarray(g * g, np.float32)
    m = {"l": _box(l1, w), "r": _box(r2, w), "g": _box(g, w), "h": ramp_box(g, ramp)}
    out = {"ll": _box(np.asarray(l1 * l1, np.float32), w) - m["l"] ** 2,
           "lr": _box(np.asarray(l1 * r2, np.float32), w) - m["l"] * m["r"],
           "rr": _box(np.asarray(r2 * r2, np.float32), w) - m["r"] ** 2,
           "gg": _box(gg, w) - m["g"] ** 2, "gh": ramp_box(gg, ramp) - m["g"] * m["h"],
           "hh": ramp_box(gg, ramp * ramp) - m["h"] ** 2}
    for name, x in (("l", l1), ("r", r2)):
        xg = np.asarray(x * g, np.float32)
        out[name + "g"] = _box(xg, w) - m[name] * m["g"]
        out[name + "h"] = ramp_box(xg, ramp) - m[name] * m["h"]
    return out


def _solve(m: dict[str, NDArray[np.float32]], n: float,
           settings: MatcherSettings) -> tuple[NDArray[np.float32], ...]:
    """Gauss--Newton step, its stated precision, the window's ZNCC and disparity slope from :func:`_window_stats`.

    Model ``I_l ~ a I_r(u + d + t + s x) + b`` linearised in ``(t, s)``: ``a (g t + h s) = residual`` over
    the window, a 2 x 2 system per pixel (Cramer's rule); ``a`` is the windows' regression gain.
    """
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a = m["lr"] / m["rr"]
        b1, b2 = (m["lg"] - a * m["rg"]) / a, (m["lh"] - a * m["rh"]) / a
        det = m["gg"] * m["hh"] - m["gh"] ** 2
        step = (m["hh"] * b1 - m["gh"] * b2) / det
        slope = (m["gg"] * b2 - m["gh"] * b1) / det
        # residual variance after the step (n - 4 degrees of freedom: t, s, a, b) and t's precision
        rss = np.maximum(m["ll"] - a * m["lr"] - a * a * (step * b1 + slope * b2), 0.0) * n / (n - 4.0)
        sig = np.sqrt(rss * m["hh"] / (a * a * det * n)) * np.sqrt(max(settings.noise_correlation_px2, 1.0))
        zncc = m["lr"] / np.sqrt(m["ll"] * m["rr"])
    return (np.asarray(step, np.float32), np.asarray(sig, np.float32), np.asarray(zncc, np.float32),
            np.asarray(slope, np.float32))


def _shift_columns(right: NDArray[np.float32], gx: NDArray[np.float32], rows: slice, cols: slice,
                   shift: float) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The right chip and its x-gradient sampled at ``(u + shift, v)`` for the rows and columns given.

    A shift along the rows only: its integer part is a column offset, its fraction one 8-tap Lanczos-4
    row filter (``cv2.sepFilter2D``), exact and 8x cheaper than ``cv2.remap``'s 8 x 8 Lanczos (which also
    quantises the fraction to 1/32 px). Columns beyond the chip repeat its edge.
    """
    k = int(np.floor(shift))
    f = shift - k
    width = right.shape[1]
    src = np.clip(np.arange(cols.start + k - 4, cols.stop + k + 4), 0, width - 1)  # 4 taps of margin each side
    kern = lanczos4_weights(f)
    one = np.ones(1, np.float32)
    out = []
    for img in (right, gx):
        band = np.ascontiguousarray(img[rows][:, src])
        # correlation: dst(x) = sum_i kern[i] band(x + i - 3); band column j is chip column cols.start + k - 4 + j
        res = cv2.sepFilter2D(band, cv2.CV_32F, kern, one, anchor=(3, 0), borderType=cv2.BORDER_REPLICATE)
        out.append(np.asarray(res[:, 4 : 4 + (cols.stop - cols.start)], np.float32))
    return out[0], out[1]


def refine_disparity(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    initial: NDArray[np.float32],
    settings: MatcherSettings,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Least-squares sub-pixel disparity with gain and offset per window (module docstring, steps 2--3).

    Two passes. (1) Pixels are grouped by their integer disparity ``k``; per group the right chip is
    shifted by exactly ``k`` columns over the group's bounding box (no resampling) and one Gauss--Newton
    step is taken: each window moves as a whole, so a pixel's estimate does not depend on its
    neighbours' disparities. (2) One dense step from that estimate: the right chip is resampled once
    (bicubic) at each pixel's own disparity and the step solved again. Iterating (2) -- which feeds
    every window its neighbours' disparities -- amplified the noise on the rendered pairs at every
    iteration, and repeating (1) at finer quantisation steps (1/8 px groups) cost 20x SGBM for the same
    error; one pass of each is the measured compromise (docs/design/dense.md).

    Parameters
    ----------
    left, right : ndarray (H, W) float32, the rectified chips (``right`` may be wider, (H, W') with
        W' >= W: left column u is right column u + d)
    initial : ndarray (H, W) float32, starting integer disparity ``u_right - u_left`` (NaN: not refined)
    settings : :class:`MatcherSettings` (``refine_window``, ``noise_correlation_px2``)

    Returns
    -------
    disparity, sigma_px, score, slope : each ndarray (H, W) float32 (NaN where ``initial`` is NaN or the
    window has no gradient); ``slope`` is the window's fitted disparity gradient along x (px per px)
    """
    w = settings.refine_window
    n = float(w * w)
    hh, ww = left.shape
    half = w // 2 + 1
    known = np.isfinite(initial)
    k0 = np.where(known, np.rint(initial), 0).astype(np.int64)
    l1 = np.asarray(left, np.float32)
    r1 = np.asarray(right, np.float32)
    gx = np.asarray(cv2.Sobel(r1, cv2.CV_32F, 1, 0, ksize=1, scale=0.5), np.float32)  # central difference
    d = np.full(l1.shape, np.nan, np.float64)
    for k in np.unique(k0[known]):
        sel = known & (k0 == k)
        ys, xs = np.nonzero(sel)
        rows = slice(max(int(ys.min()) - half, 0), min(int(ys.max()) + half + 1, hh))
        cols = np.arange(max(int(xs.min()) - half, 0), min(int(xs.max()) + half + 1, ww))
        src = np.clip(cols + int(k), 0, right.shape[1] - 1)
        c = slice(int(cols[0]), int(cols[-1]) + 1)
        m = _window_stats(l1[rows, c], r1[rows][:, src], gx[rows][:, src], w)
        step = _solve(m, n, settings)[0]
        sub = sel[rows, c]
        d[rows, c][sub] = k + np.clip(step[sub], -1.0, 1.0)
    ok = np.isfinite(d)
    d = np.where(ok, d, k0)
    sigma = np.full(l1.shape, np.nan, np.float32)
    score = np.full(l1.shape, np.nan, np.float32)
    slope = np.full(l1.shape, np.nan, np.float32)
    if settings.refine_quantum_px <= 0:
        uu, vv = np.meshgrid(np.arange(ww, dtype=np.float32), np.arange(hh, dtype=np.float32))
        mx = (uu + d).astype(np.float32)
        r2 = np.asarray(cv2.remap(r1, mx, vv, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE), np.float32)
        g = np.asarray(cv2.remap(gx, mx, vv, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE), np.float32)
        step, sigma, score, slope = _solve(_window_stats(l1, r2, g, w), n, settings)
        d = d + np.clip(step, -1.0, 1.0)
    else:
        qs = settings.refine_quantum_px
        q = np.rint(d / qs).astype(np.int64)
        new = d.copy()
        for k in np.unique(q[known & ok]):
            sel = known & ok & (q == k)
            ys, xs = np.nonzero(sel)
            rows = slice(max(int(ys.min()) - half, 0), min(int(ys.max()) + half + 1, hh))
            c = slice(max(int(xs.min()) - half, 0), min(int(xs.max()) + half + 1, ww))
            r2, g = _shift_columns(r1, gx, rows, c, float(k * qs))
            step, sig, zn, sl = _solve(_window_stats(l1[rows, c], r2, g, w), n, settings)
            sub = sel[rows, c]
            new[rows, c][sub] = k * qs + np.clip(step[sub], -1.0, 1.0)
            sigma[rows, c][sub] = sig[sub]
            score[rows, c][sub] = zn[sub]
            slope[rows, c][sub] = sl[sub]
        d = new
    bad = ~known | ~ok | ~np.isfinite(sigma) | ~np.isfinite(d)
    return (np.where(bad, np.nan, d).astype(np.float32), np.where(bad, np.nan, sigma).astype(np.float32),
            np.where(bad, np.nan, score).astype(np.float32), np.where(bad, np.nan, slope).astype(np.float32))


def refine_disparity_blocks(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    initial: NDArray[np.float32],
    settings: MatcherSettings,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """:func:`refine_disparity` block by block (``refine_block_px`` squared, each with the margins its windows
    and its disparities reach): the same result for every pixel, at a cost linear in the chip's area.

    The grouped passes resample and box-filter each group's bounding box; over a whole chip a group of one
    quantised shift spans most of it, so the cost grew with the chip's area times its disparity range
    (7x for 4x the pixels from 256^2 to 512^2 chips). Within a block the disparities span little.
    """
    b = settings.refine_block_px
    hh, ww = left.shape
    if b <= 0 or (hh <= b and ww <= b):
        return refine_disparity(left, right, initial, settings)
    m = settings.refine_window // 2 + 2
    out = [np.full(left.shape, np.nan, np.float32) for _ in range(4)]
    for r0 in range(0, hh, b):
        for c0 in range(0, ww, b):
            r1, c1 = min(r0 + b, hh), min(c0 + b, ww)
            rs = slice(max(r0 - m, 0), min(r1 + m, hh))
            cs = slice(max(c0 - m, 0), min(c1 + m, ww))
            init = initial[rs, cs]
            if not np.isfinite(init).any():
                continue
            reach = int(np.ceil(np.nanmax(np.abs(init)))) + m + 5  # disparity, window and interpolation taps
            ra = max(cs.start - reach, 0)
            rb = min(cs.stop + reach, ww)
            # right columns [ra, rb); left column u of the block is right column u + d: offset cs.start - ra
            off = cs.start - ra
            res = refine_disparity(left[rs, cs], right[rs, ra:rb], init + np.float32(off), settings)
            inner = (slice(r0 - rs.start, r1 - rs.start), slice(c0 - cs.start, c1 - cs.start))
            for k, a in enumerate(res):
                out[k][r0:r1, c0:c1] = a[inner] - (off if k == 0 else 0)
    return out[0], out[1], out[2], out[3]


def reference_module(float64: bool = False) -> object:
    """Return this module, or (``float64``) a copy computing every image and window moment in float64 instead of
    float32 (the same code with the dtypes replaced): it separates the float32 rounding of the old
    implementation (``box(l * l) - box(l)^2`` in float32 cancels ~5 digits on 1500-DN images) from any
    difference of method.
    """
    import sys
    import types

    if not float64:
        return sys.modules[__name__]
    from pathlib import Path

    src = Path(__file__).read_text().replace("np.float32", "np.float64").replace("cv2.CV_32F", "cv2.CV_64F")
    src = src.replace("kern = lanczos4_weights(f)", "kern = lanczos4_weights(f).astype(np.float64)")
    src = src.replace("(r1, mx, vv,", "(r1, mx.astype(np.float32), vv.astype(np.float32),")
    src = src.replace("(gx, mx, vv,", "(gx, mx.astype(np.float32), vv.astype(np.float32),")
    mod = types.ModuleType("reference_refine_float64")
    exec(compile(src, __file__ + " (float64)", "exec"), mod.__dict__)
    return mod
