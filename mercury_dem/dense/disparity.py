"""Dense disparity of a rectified chip pair: OpenCV StereoSGBM, then a least-squares refinement on the images.

1. **Integer disparity**: ``cv2.StereoSGBM`` on the two chips stretched to 8 bits, with its own
   left--right check (``disp12MaxDiff``) and speckle filter. Its 1/16-pixel output is a parabola on the
   aggregated costs, which pixel-locks (the anchors' note on ASP): only its integer part is trusted.
2. **Sub-pixel refinement** on the float images, not on the costs: a 1-D Lucas--Kanade with a gain, an
   offset and a disparity slope per window. Each pixel's window (``refine_window`` squared) minimises
   ``sum (I_l - a I_r(u + d + s x) - b)^2`` by one Gauss--Newton step from the SGBM integer disparity (the
   window shifted as a whole), then one more from that estimate quantised to ``refine_quantum_px`` (the
   right chip resampled by a Lanczos-4 row filter once per quantum fraction). The window sums run in a
   compiled kernel (:mod:`mercury_dem.dense.refine_kernel`). Written here because OpenCV has no per-pixel
   least-squares disparity refinement (its optical flows -- DIS in ``match/flow.py``, Farneback -- solve
   for 2-D flow with their own smoothness terms and give no per-pixel covariance).
3. **Per-pixel score and precision**: the zero-mean normalised correlation of the final windows (score),
   and the least-squares precision of ``d``: ``sigma_d^2 = s^2 / (a^2 sum g_c^2)``, with ``s^2`` the
   residual variance (``n - 4`` degrees of freedom: shift, slope, gain, offset) and ``g_c`` the centred gradient of the resampled
   right image. The residuals of neighbouring pixels are correlated (both images are blurred by a
   point-spread function and resampled), so ``n`` pixels carry fewer independent observations:
   ``sigma_d`` is multiplied by ``sqrt(noise_correlation_px2)``, the area over which the noise is
   correlated (``4 pi sigma_psf^2`` for a Gaussian PSF of sigma ``sigma_psf``, at least 1).
4. **Holes, never invented**: a pixel keeps NaN and a flag (bits of :data:`HOLE_FLAGS`) when it is outside
   either image, dark (in shadow) in either image, without texture (``sigma_d`` above ``max_sigma_px``), without
   an SGBM disparity or inconsistent left--right, or when the refinement leaves the SGBM pixel
   (``|d - d_sgbm| > 1``) or scores below ``min_score``. Nothing is interpolated into a hole.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

#: Hole flags (bits of :attr:`DisparityMap.holes`; 0 means a valid disparity).
HOLE_OUTSIDE = 1
HOLE_SHADOW = 2
HOLE_NO_TEXTURE = 4
HOLE_NO_MATCH = 8
HOLE_REFINEMENT = 16
HOLE_FLAGS = {"outside": HOLE_OUTSIDE, "shadow": HOLE_SHADOW, "no_texture": HOLE_NO_TEXTURE,
              "no_match": HOLE_NO_MATCH, "refinement": HOLE_REFINEMENT}

#: Sub-pixel refinements (:attr:`MatcherSettings.refine_method`).
REFINE_METHODS = ("window_fit", "dense_lk")

_SGBM_MODES = {"sgbm": cv2.STEREO_SGBM_MODE_SGBM, "hh": cv2.STEREO_SGBM_MODE_HH,
               "sgbm_3way": cv2.STEREO_SGBM_MODE_SGBM_3WAY, "hh4": cv2.STEREO_SGBM_MODE_HH4}


@dataclass(frozen=True)
class MatcherSettings:
    """Dense matching parameters.

    Attributes
    ----------
    mode : StereoSGBM mode: ``sgbm`` (5 paths), ``sgbm_3way`` (faster, 5 paths), ``hh`` (8 paths), ``hh4``
    block_size : SGBM matching block, pixels (odd)
    p1, p2 : SGBM smoothness penalties per pixel of block (OpenCV's are ``p * block_size^2``)
    uniqueness_ratio : SGBM uniqueness margin, percent
    lr_max_diff : left--right check tolerance, integer pixels (``disp12MaxDiff``)
    speckle_window, speckle_range : SGBM speckle filter (region size, pixels; disparity step, pixels)
    refine_window : side of the refinement's least-squares window, pixels (odd)
    refine_method : ``window_fit`` (the compiled per-pixel window fit, :func:`refine_disparity_blocks`) or
        ``dense_lk`` (the whole-image Lucas--Kanade of :func:`refine_disparity_lk`)
    refine_iterations : Gauss--Newton iterations of ``dense_lk``
    refine_quantum_px : second pass: window shifts quantised to this step (0: one dense step instead)
    refine_block_px : the refinement runs block by block (side in pixels; 0: the whole chip at once); bounds
        the memory of the resampled right chip (2 x 8 float32 planes per pixel at 1/8 px) on large chips
    noise_correlation_px2 : area (pixels) over which the images' noise is correlated (see module docstring)
    max_sigma_px : larger stated disparity precision is a no-texture hole
    min_score : smaller zero-mean normalised correlation is a hole
    shadow_fraction : a pixel whose 3 x 3 mean DN (dark level removed) is below this fraction of the
        chip's median is in shadow
    dark_dn : dark level of the images, DN
    """

    mode: str = "sgbm_3way"
    block_size: int = 5
    p1: int = 8
    p2: int = 32
    uniqueness_ratio: int = 5
    lr_max_diff: int = 1
    speckle_window: int = 50
    speckle_range: int = 2
    refine_window: int = 9
    refine_method: str = "window_fit"
    refine_iterations: int = 2
    refine_quantum_px: float = 0.125
    refine_block_px: int = 512
    noise_correlation_px2: float = 1.0
    max_sigma_px: float = 0.5
    min_score: float = 0.5
    shadow_fraction: float = 0.15
    dark_dn: float = 10.0

    def __post_init__(self) -> None:
        if self.mode not in _SGBM_MODES:
            raise ValueError(f"matcher mode {self.mode!r}: choose one of {sorted(_SGBM_MODES)}")
        if self.refine_method not in REFINE_METHODS:
            raise ValueError(f"refine method {self.refine_method!r}: choose one of {REFINE_METHODS}")
        if self.block_size % 2 == 0 or self.refine_window % 2 == 0 or self.refine_window < 3:
            raise ValueError("block_size and refine_window must be odd (refine_window >= 3)")


@dataclass(frozen=True)
class DisparityMap:
    """Per-pixel result on the rectified left chip.

    Attributes
    ----------
    disparity : ndarray (H, W) float32, ``u_right - u_left`` rectified pixels, NaN in holes
    sigma_px : ndarray (H, W) float32, stated 1-sigma precision of ``disparity``, NaN in holes
    score : ndarray (H, W) float32, zero-mean normalised correlation of the final windows (-1..1)
    holes : ndarray (H, W) uint8, bits of :data:`HOLE_FLAGS` (0 where valid)
    slope : ndarray (H, W) float32, the window's fitted disparity gradient along x (px per px), NaN in holes
    """

    disparity: NDArray[np.float32]
    sigma_px: NDArray[np.float32]
    score: NDArray[np.float32]
    holes: NDArray[np.uint8]
    slope: NDArray[np.float32]

    def hole_counts(self) -> dict[str, int]:
        """Pixels carrying each flag (a pixel may carry several)."""
        return {k: int(np.count_nonzero(self.holes & v)) for k, v in HOLE_FLAGS.items()}


def to_8bit(left: NDArray[np.float32], right: NDArray[np.float32], valid: NDArray[np.bool_],
            percentiles: tuple[float, float] = (0.5, 99.5)) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
    """Both chips stretched by one shared linear map (the valid pixels' percentiles) to 0..255."""
    v = np.concatenate([left[valid], right[valid]]) if valid.any() else np.array([0.0, 1.0])
    lo, hi = np.percentile(v, percentiles)
    scale = 255.0 / max(float(hi - lo), 1e-6)

    def stretch(x: NDArray[np.float32]) -> NDArray[np.uint8]:
        return np.asarray(np.clip((x - lo) * scale + 0.5, 0, 255), np.uint8)

    return stretch(left), stretch(right)


def sgbm_matcher(settings: MatcherSettings, min_disparity: int, num_disparities: int) -> cv2.StereoSGBM:
    """The configured ``cv2.StereoSGBM`` (OpenCV's disparity ``xl - xr``; see :func:`sgbm_disparity`)."""
    b = settings.block_size
    return cv2.StereoSGBM.create(
        minDisparity=int(min_disparity), numDisparities=int(num_disparities), blockSize=b,
        P1=settings.p1 * b * b, P2=settings.p2 * b * b, disp12MaxDiff=settings.lr_max_diff,
        uniquenessRatio=settings.uniqueness_ratio, speckleWindowSize=settings.speckle_window,
        speckleRange=settings.speckle_range, mode=_SGBM_MODES[settings.mode],
    )


def sgbm_disparity(left8: NDArray[np.uint8], right8: NDArray[np.uint8], d_min: float, d_max: float,
                   settings: MatcherSettings) -> NDArray[np.float32]:
    """SGBM disparity ``u_right - u_left`` (float32 pixels, NaN where SGBM found none) searched in [d_min, d_max].

    OpenCV matches a left pixel x with the right pixel ``x - d_cv``; ours is ``d = -d_cv``, so the search
    is ``d_cv`` in ``[-d_max, -d_min]`` rounded out to a multiple of 16 disparities.
    """
    lo = int(np.floor(-d_max))
    n = int(16 * np.ceil((int(np.ceil(-d_min)) - lo + 1) / 16))
    raw = sgbm_matcher(settings, lo, n).compute(left8, right8)
    d = -raw.astype(np.float32) / 16.0
    d[raw < lo * 16] = np.nan  # OpenCV marks a pixel without disparity (or failing its checks) by (lo - 1) * 16
    return d


def _box(x: NDArray[np.float32], w: int) -> NDArray[np.float32]:
    return np.asarray(cv2.boxFilter(x, cv2.CV_32F, (w, w), normalize=True, borderType=cv2.BORDER_REFLECT), np.float32)


def lanczos4_weights(fraction: float) -> NDArray[np.float32]:
    """The 8 Lanczos-4 weights (normalised to sum 1) that sample a row at ``x + fraction`` (0 <= fraction < 1)
    from the samples at ``x - 3 .. x + 4``.
    """
    t = fraction - (np.arange(8) - 3.0)
    w = np.sinc(t) * np.sinc(t / 4.0)
    return np.asarray(w / w.sum(), np.float32)


def _phase_planes(right: NDArray[np.float32], gx: NDArray[np.float32], fractions: NDArray[np.float64],
                  pad: int) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """The right chip and its x-gradient resampled at ``u + f`` for each fraction ``f`` (0 <= f < 1): (P, H, W + 2 pad).

    A shift along the rows only: one 8-tap Lanczos-4 row filter (``cv2.filter2D``, a 1 x 8 kernel) per
    fraction, exact and 8x cheaper than ``cv2.remap``'s 8 x 8 Lanczos (which also quantises the fraction to
    1/32 px). The chip is first padded by ``pad`` columns repeating its edge, so plane column ``c + pad`` is
    chip column ``c`` shifted, with columns beyond the chip repeating its edge.
    """
    hh, ww = right.shape
    out = np.empty((2, len(fractions), hh, ww + 2 * pad), np.float32)
    for m, img in enumerate((right, gx)):
        band = cv2.copyMakeBorder(img, 0, 0, pad, pad, cv2.BORDER_REPLICATE)
        for q, f in enumerate(fractions):
            # correlation: dst(x) = sum_i kern[i] band(x + i - 3)
            cv2.filter2D(band, cv2.CV_32F, lanczos4_weights(float(f))[None, :], dst=out[m, q], anchor=(3, 0),
                         borderType=cv2.BORDER_REPLICATE)
    return out[0], out[1]


def refine_disparity(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    initial: NDArray[np.float32],
    settings: MatcherSettings,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Least-squares sub-pixel disparity with gain and offset per window (module docstring, steps 2--3).

    Two passes. (1) Each pixel's window is fitted against the right chip shifted by exactly its integer
    disparity ``k`` columns (no resampling) with one Gauss--Newton step: each window moves as a whole, so a
    pixel's estimate does not depend on its neighbours' disparities. (2) The same from that estimate
    quantised to ``refine_quantum_px`` (the right chip resampled once per distinct fraction by a Lanczos-4
    row filter), which gives the disparity, its precision, the score and the slope. With
    ``refine_quantum_px = 0`` pass (2) is instead one dense step: the right chip is resampled (Lanczos-4)
    at each pixel's own disparity and every window fitted on it -- which feeds each window its neighbours'
    disparities; iterated, that amplified the noise on the rendered pairs (docs/design/dense.md).

    Both passes run in the compiled kernel :func:`mercury_dem.dense.refine_kernel.window_fit` (per pixel,
    its own shift; the numpy version grouped pixels by shift, same formulas in float32).

    Parameters
    ----------
    left, right : ndarray (H, W) float32, the rectified chips (``right`` may be wider, (H, W') with
        W' >= W: left column u is right column u + d)
    initial : ndarray (H, W) float32, starting integer disparity ``u_right - u_left`` (NaN: not refined)
    settings : :class:`MatcherSettings` (``refine_window``, ``refine_quantum_px``, ``noise_correlation_px2``)

    Returns
    -------
    disparity, sigma_px, score, slope : each ndarray (H, W) float32 (NaN where ``initial`` is NaN or the
    window has no gradient); ``slope`` is the window's fitted disparity gradient along x (px per px)
    """
    from mercury_dem.dense import refine_kernel as rk

    w = settings.refine_window
    hh, ww = left.shape
    noise = float(np.sqrt(max(settings.noise_correlation_px2, 1.0)))
    known = np.isfinite(initial)
    k0 = np.where(known, np.rint(initial), 0).astype(np.int64)
    l1 = np.ascontiguousarray(left, np.float32)
    r1 = np.ascontiguousarray(right, np.float32)
    gx = np.asarray(cv2.Sobel(r1, cv2.CV_32F, 1, 0, ksize=1, scale=0.5), np.float32)  # central difference
    step = rk.fit_windows(l1, r1[None], gx[None], 0, k0, known.astype(np.int64) - 1, w, noise, full=False)[0]
    if settings.refine_quantum_px <= 0:
        dstep = np.clip(step, np.float32(-1.0), np.float32(1.0))
        ok = known & np.isfinite(dstep)
        d = np.where(ok, k0 + dstep.astype(np.float64), k0)
        uu, vv = np.meshgrid(np.arange(ww, dtype=np.float32), np.arange(hh, dtype=np.float32))
        mx = (uu + d).astype(np.float32)
        r2 = np.asarray(cv2.remap(r1, mx, vv, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE), np.float32)
        g = np.asarray(cv2.remap(gx, mx, vv, cv2.INTER_LANCZOS4, borderMode=cv2.BORDER_REPLICATE), np.float32)
        step, sigma, score, slope = rk.fit_windows(l1, r2[None], g[None], 0, np.zeros(l1.shape, np.int64),
                                                   np.where(ok, 0, -1), w, noise)
        d = d + np.clip(step, np.float32(-1.0), np.float32(1.0)).astype(np.float64)
        bad = ~known | ~ok | ~np.isfinite(sigma) | ~np.isfinite(d)
        return (np.where(bad, np.nan, d).astype(np.float32), np.where(bad, np.nan, sigma).astype(np.float32),
                np.where(bad, np.nan, score).astype(np.float32), np.where(bad, np.nan, slope).astype(np.float32))
    qs = float(settings.refine_quantum_px)
    d = np.empty(l1.shape, np.float64)
    ok = np.empty(l1.shape, np.bool_)
    q = np.empty(l1.shape, np.int64)
    q0, q1 = rk.after_first_pass(k0, known, step, qs, d, ok, q)
    # the few quanta present (a table over their range, not a sort of every pixel): integer part and phase
    used = (np.flatnonzero(rk.quanta_present(q, ok, q0, q1)) + q0 if q1 >= q0 else np.zeros(1, np.int64))
    shifts = used * qs
    whole = np.floor(shifts).astype(np.int64)
    fractions, phase_of = np.unique(shifts - whole, return_inverse=True)
    lut_k = np.zeros(int(used[-1]) - int(used[0]) + 1, np.int64)
    lut_p = np.full(lut_k.size, -1, np.int64)
    lut_k[used - used[0]] = whole
    lut_p[used - used[0]] = phase_of.ravel()
    kk = np.empty(l1.shape, np.int64)
    phase = np.empty(l1.shape, np.int64)
    rk.shift_and_phase(q, ok, np.int64(used[0]), lut_k, lut_p, kk, phase)
    pad = int(np.abs(whole).max()) + 8
    rp, gp = _phase_planes(r1, gx, fractions, pad)
    step, sigma, score, slope = rk.fit_windows(l1, rp, gp, pad, kk, phase, w, noise)
    out = tuple(np.empty(l1.shape, np.float32) for _ in range(4))
    rk.finish_second_pass(q, qs, known, ok, step, sigma, score, slope, *out)
    return out[0], out[1], out[2], out[3]


def refine_disparity_blocks(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    initial: NDArray[np.float32],
    settings: MatcherSettings,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """:func:`refine_disparity` block by block (about ``refine_block_px`` squared, each with the margins its
    windows and its disparities reach): the same result for every pixel (the disparity within one float32 rounding).

    The compiled refinement costs the same per pixel on a whole chip; blocks only bound the memory of the
    resampled right chip (one plane per 1/8-px phase) on large chips. (The numpy version grouped pixels by
    shift and its cost grew with the chip's area times its disparity range, which 128-px blocks contained.)
    """
    b = settings.refine_block_px
    hh, ww = left.shape
    # about b each way, in equal parts (a chip a few pixels over b is not cut into slivers)
    nr, nc = (max(round(hh / b), 1), max(round(ww / b), 1)) if b > 0 else (1, 1)
    if nr * nc == 1:
        return refine_disparity(left, right, initial, settings)
    br, bc = -(-hh // nr), -(-ww // nc)
    # the windows (w // 2) and, in the dense step of fast mode, the first-pass windows of their pixels
    m = 2 * (settings.refine_window // 2) + 2
    out = [np.full(left.shape, np.nan, np.float32) for _ in range(4)]
    for r0 in range(0, hh, br):
        for c0 in range(0, ww, bc):
            r1, c1 = min(r0 + br, hh), min(c0 + bc, ww)
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


#: Upsampling of the right chip along the rows before the linear resampling of ``dense_lk`` (a module
#: constant: measured, not a setting; docs/design/dense.md)
LK_UPSAMPLE = 4


def _lanczos4_derivative() -> NDArray[np.float32]:
    """The 7 taps (``x - 3 .. x + 3``, correlation) of the derivative of the Lanczos-4 interpolant at a sample:
    ``-(-1)^n sinc(n / 4) / n`` (the central difference, 2/pi of the slope at a wavelength of 4 px, made
    the Gauss--Newton steps over- or undershoot by wavelength: ~0.15 of the error left per iteration).
    """
    n = np.arange(-3, 4, dtype=np.float64)
    h = np.zeros(7)
    nz = n != 0
    h[nz] = -((-1.0) ** n[nz]) * np.sinc(n[nz] / 4.0) / n[nz]
    return np.asarray(h, np.float32)


_LANCZOS4_DERIVATIVE = _lanczos4_derivative()


def refine_disparity_lk(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    initial: NDArray[np.float32],
    settings: MatcherSettings,
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Sub-pixel disparity by a dense inverse-compositional Lucas--Kanade built from whole-image OpenCV
    primitives: its cost per pixel does not depend on the window (box filters) nor on the disparity range.

    The right chip is resampled at every pixel's current disparity ``d``: upsampled ``LK_UPSAMPLE`` times along
    the rows by Lanczos-4 row filters once, then ``cv2.remap`` (linear) at columns rounded to the 1/32 sample
    that ``remap`` resolves, so the place sampled is known exactly. In each
    ``refine_window`` square window the resampled right chip ``R_w`` is fitted by least squares as
    ``a L + c L' + b`` (``L'`` the left chip's gradient along the rows, so the 2 x 2 normal matrix of the
    centred window is fixed and computed once): ``R(u + d) = alpha L(u - e) + beta`` with ``e`` the error
    of ``d`` gives ``e = -c / a``. The window's estimate is its ``L'^2``-weighted mean warp plus ``e`` (not the
    pixel's own warp plus ``e``, which would keep each pixel's own error: the windows overlap), so every
    iteration estimates the window's disparity afresh about a better warp. The start is the box mean of the
    valid SGBM integer disparities (a smooth warp). Window sums are ``cv2.boxFilter`` means.

    Score: the zero-mean normalised correlation of ``L`` and ``R_w`` in the last window. Precision:
    ``sigma_e^2 = s^2 (N^-1)_cc / a^2`` (``s^2`` the residual variance, ``n - 3`` degrees of freedom),
    times ``sqrt(noise_correlation_px2)`` as :func:`refine_disparity`. Slope: the central difference of
    the result along the rows. Pixels whose ``initial`` is NaN are not refined (NaN).

    Written with OpenCV primitives (resampling, box filters) rather than its optical flows for the reasons of
    the module docstring; the element-wise work between them is fused in :mod:`mercury_dem.dense.lk_kernel`.

    Parameters and returns as :func:`refine_disparity`.
    """
    from mercury_dem.dense import lk_kernel as lk

    f32 = np.float32
    w = settings.refine_window
    up = LK_UPSAMPLE
    hh, ww = left.shape
    noise = float(np.sqrt(max(settings.noise_correlation_px2, 1.0)))
    # one offset off both chips (the model has its own per window): the window moments lose fewer digits
    l1, r1 = np.empty((hh, ww), f32), np.empty(right.shape, f32)
    seeds = np.empty((hh, ww, 2), f32)
    known = np.empty((hh, ww), np.bool_)
    fill = lk.prepare(np.ascontiguousarray(left, f32), np.ascontiguousarray(right, f32),
                      np.ascontiguousarray(initial, f32), float(np.mean(left)), l1, r1, seeds, known)
    g = np.asarray(cv2.filter2D(l1, cv2.CV_32F, _LANCZOS4_DERIVATIVE[None, :], borderType=cv2.BORDER_REFLECT), f32)
    # the right chip upsampled along the rows (Lanczos-4 row filters, exact phases); remap then interpolates
    # linearly between samples 1/up px apart: its bias is below 0.002 px where bicubic on the chip gave 0.04
    phases = np.empty((hh, int(right.shape[1]), up), f32)
    phases[:, :, 0] = r1
    for k in range(1, up):
        phases[:, :, k] = cv2.filter2D(r1, cv2.CV_32F, lanczos4_weights(k / up)[None, :], anchor=(3, 0),
                                       borderType=cv2.BORDER_REPLICATE)
    r_up = phases.reshape(hh, -1)
    buf4 = np.empty((hh, ww, 4), f32)
    buf1 = np.empty((hh, ww), f32)
    lk.fixed_products(l1, g, buf4, buf1)
    fixed4, fixed_gg = _box(buf4, w), _box(buf1, w)
    d, mx, dq, sigma, score = (np.empty((hh, ww), f32) for _ in range(5))
    lk.start(_box(seeds, w), fill, up, d, mx, dq)
    vv = np.repeat(np.arange(hh, dtype=f32)[:, None], ww, axis=1)
    iterations = max(settings.refine_iterations, 1)
    for it in range(iterations):
        rw = np.asarray(cv2.remap(r_up, mx, vv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE), f32)
        lk.products(l1, g, rw, dq, buf4, buf1)
        if it < iterations - 1:
            lk.update(fixed4, fixed_gg, _box(buf4, w), _box(buf1, w), fill, up, d, mx, dq)
        else:
            lk.update_last(fixed4, fixed_gg, _box(buf4, w), _box(buf1, w), float(w * w), noise, d, sigma, score)
    out = tuple(np.empty((hh, ww), f32) for _ in range(4))
    lk.finish(d, sigma, score, known, *out)
    return out[0], out[1], out[2], out[3]


def dense_disparity(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    left_valid: NDArray[np.bool_],
    right_valid: NDArray[np.bool_],
    d_min: float,
    d_max: float,
    settings: MatcherSettings = MatcherSettings(),
) -> DisparityMap:
    """SGBM, left--right check, least-squares refinement, score, precision and holes of a rectified chip pair.

    Parameters
    ----------
    left, right : ndarray (H, W) float32 DN, rectified (the right one resampled into the left's frame)
    left_valid, right_valid : ndarray (H, W) bool, where each chip's samples lie inside its image
    d_min, d_max : search range of ``u_right - u_left``, pixels
    settings : :class:`MatcherSettings`

    Returns
    -------
    :class:`DisparityMap`
    """
    s = settings
    both = left_valid & right_valid
    l8, r8 = to_8bit(left, right, both)
    d0 = sgbm_disparity(l8, r8, d_min, d_max, s)
    # The SGBM disparity's integer part seeds the refinement; its parabola fraction would pixel-lock.
    seed = np.round(d0)
    if s.refine_method == "dense_lk":  # an iteration converges to its own fixed point: start from SGBM's 1/16 px
        d, sigma, score, slope = refine_disparity_lk(left, right, d0, s)
    else:
        d, sigma, score, slope = refine_disparity_blocks(left, right, seed, s)
    # holes (flags in one compiled pass, refine_kernel.flag_holes):
    # outside: the left pixel, or the right pixel it matched, is not inside its image;
    # shadow: the pixel (its 3 x 3 mean, for the noise) is dark in the left chip, or at the matched place in
    # the right one: a pixel in shadow gets no height even where its window reaches lit ground
    from mercury_dem.dense.refine_kernel import flag_holes

    lit_l = _box(np.maximum(left - s.dark_dn, 0.0).astype(np.float32), 3)
    lit_r = _box(np.maximum(right - s.dark_dn, 0.0).astype(np.float32), 3)
    ref_l = float(np.median(np.maximum(left[both] - s.dark_dn, 0.0))) if both.any() else 0.0
    ref_r = float(np.median(np.maximum(right[both] - s.dark_dn, 0.0))) if both.any() else 0.0
    holes = np.empty(left.shape, np.uint8)
    out = [np.empty(left.shape, np.float32) for _ in range(4)]
    f32 = np.float32
    flag_holes(np.asarray(d0, f32), np.asarray(seed, f32), d, sigma, score, slope,
               np.ascontiguousarray(left_valid, np.bool_), np.ascontiguousarray(right_valid, np.bool_), lit_l, lit_r,
               f32(s.shadow_fraction * ref_l), f32(s.shadow_fraction * ref_r), f32(s.max_sigma_px), f32(s.min_score),
               holes, *out)
    return DisparityMap(out[0], out[1], out[2], holes, out[3])
