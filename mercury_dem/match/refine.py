"""Sub-pixel refinement of matches on the pre-transformed images, vectorized over measures.

For every match, a ``window`` x ``window`` template around the reference
position is correlated (zero-mean normalized cross-correlation) with the
warped match image at every integer shift within ``search`` pixels of the
matched position; the peak is located to sub-pixel by a parabola through its
neighbours along each axis, then polished by a few Gauss-Newton
(Lucas-Kanade) steps of a translation with gain and offset
(``ref ~ a * match(x + d) + b``), which removes the parabola's pixel-locking
bias. Only the match-side position moves; the reference position (the
keypoint, whose id the control network tracks) is kept.

The integer search is one ``cv2.matchTemplate`` (zero-mean NCC) per measure: a Python
loop, but measured 4x faster than the batched numpy product over every measure's
(2 * search + 1)^2 windows it replaced (session 11, docs/benchmarks/match.md), which had to
copy all windows first. The Gauss-Newton polish is vectorized over all measures (numpy;
``cv2.findTransformECC`` takes one template per call and has no gain/offset model).
Bilinear sampling is done in numpy (``cv2.remap`` quantizes positions to 1/32 pixel).

The positions can be found on other images than the score (``ref_pattern``,
``warped_pattern``): the matcher passes both images locally normalized
(:func:`local_normalize`, a band-pass that keeps the texture at a few pixels and
drops the smooth shading), while the score stays the NCC of the DN windows. Measured
on the tiny mission (docs/benchmarks/match.md, session 4): shading that differs between
two views -- slopes seen foreshortened by convergent views, or lit from another sun
elevation -- pulls a 21-px DN window off its centre; on the normalized images the
similar-illumination tail (p95) drops by about a third and the 30/70 median by half.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class Refined:
    """Refined match positions.

    Attributes
    ----------
    points : ndarray (N, 2), refined positions in the warped (reference-geometry) frame
    score : ndarray (N,), NCC of the template at the refined position
    ok : ndarray (N,) bool, False where the window leaves valid data, the peak is on
        the search border, the score is low or the move is too large
    on_data : ndarray (N,) bool, False where the windows left the image or the valid data
        (None: not recorded)
    window : ndarray (N,) int, the window size each measure was refined with (None: all the same)
    """

    points: NDArray[np.float64]
    score: NDArray[np.float64]
    ok: NDArray[np.bool_]
    on_data: NDArray[np.bool_] | None = None
    window: NDArray[np.int64] | None = None


def sample_patches(image: NDArray[np.float32], centres: NDArray[np.float64], half: int) -> NDArray[np.float32]:
    """Bilinear samples (N, 2*half+1, 2*half+1) of ``image`` on square grids about ``centres`` (N, 2).

    Every pixel of one patch shares the centre's fractional offset, so a patch is
    one integer block of (2*half+2)^2 pixels (gathered through a strided window
    view, a single fancy index) blended with four scalar weights. Blocks that
    would leave the image take its border pixels there (replicated, as
    ``cv2.BORDER_REPLICATE``; callers check validity); non-finite centres give the
    image's corner block.
    """
    h, w = image.shape
    size = 2 * half + 1
    c = np.asarray(centres, dtype=np.float64)
    fl = np.floor(c)
    fx = (c[:, 0] - fl[:, 0]).astype(np.float32)[:, None, None]
    fy = (c[:, 1] - fl[:, 1]).astype(np.float32)[:, None, None]
    lo = fl - half
    lo = np.where(np.isnan(lo), 0.0, lo)  # (not nan_to_num: its overhead showed in profiles; inf is clipped below)
    x0 = np.clip(lo[:, 0], -size - 2, w + 1).astype(np.intp)
    y0 = np.clip(lo[:, 1], -size - 2, h + 1).astype(np.intp)
    xi = np.clip(x0, 0, w - size - 1)
    yi = np.clip(y0, 0, h - size - 1)
    blocks = np.lib.stride_tricks.sliding_window_view(image, (size + 1, size + 1))[yi, xi]
    off = np.flatnonzero((xi != x0) | (yi != y0))
    if off.size:  # blocks over the border: per-pixel indices clipped to the image
        r = np.arange(size + 1)
        xs = np.clip(x0[off, None] + r, 0, w - 1)
        ys = np.clip(y0[off, None] + r, 0, h - 1)
        blocks[off] = image[ys[:, :, None], xs[:, None, :]]
    # along the samples once for every row of the block (rows 0..size are the patch's top rows
    # and 1..size+1 its bottom rows), then along the lines: the same float32 operations as
    # ``top = b00 + fx (b01 - b00)``, ``bot = b10 + fx (b11 - b10)``, ``top + fy (bot - top)``
    left = blocks[:, :, :-1]
    rows = blocks[:, :, 1:] - left
    rows *= fx
    rows += left
    top = rows[:, :-1]
    out = rows[:, 1:] - top
    out *= fy
    out += top
    return out


def local_normalize(image: NDArray[np.float32], sigma_px: float) -> NDArray[np.float32]:
    """``(image - local mean) / local std`` with Gaussian weights of ``sigma_px`` (float32).

    A contrast-normalizing band-pass: the shading at scales above a few ``sigma_px``
    (which changes with the view and the sun) is removed and every neighbourhood gets
    unit contrast. The variance gets a floor of 1e-3 of its image mean, so flat areas
    stay near 0 instead of amplifying their noise. Two OpenCV Gaussian blurs.
    """
    img = np.asarray(image, np.float32)
    m = cv2.GaussianBlur(img, (0, 0), float(sigma_px))
    v = cv2.GaussianBlur(img * img, (0, 0), float(sigma_px)) - m * m
    np.maximum(v, 0.0, out=v)
    floor = 1e-3 * float(v.mean()) + 1e-12
    return ((img - m) / np.sqrt(v + floor)).astype(np.float32, copy=False)


def _normalize(p: NDArray[np.float32]) -> NDArray[np.float32]:
    q = p - p.mean(axis=(1, 2), keepdims=True)
    n = np.sqrt(np.sum(q * q, axis=(1, 2), keepdims=True))
    return q / np.maximum(n, 1e-12)


def integral_image(mask: NDArray[np.bool_]) -> NDArray[np.int32]:
    """The (lines + 1, samples + 1) integral image of a bool mask, for :func:`box_count` (compute once, reuse)."""
    return cv2.integral(mask.view(np.uint8))


def box_count(mask: NDArray[np.bool_], lo: NDArray[np.int64], hi: NDArray[np.int64],
               integral: NDArray[np.int32] | None = None) -> NDArray[np.int64]:
    """Number of True pixels in boxes [lo, hi] (inclusive, (N, 2) sample/line) via an integral image.

    ``integral``: :func:`integral_image` of ``mask`` when the caller has it (a 1024^2 one costs
    ~1.4 ms; the propagation asks the same masks ~16 times per pair); None = computed here.
    """
    h, w = mask.shape
    ii = integral_image(mask) if integral is None else integral  # (h + 1, w + 1) int32
    s0 = np.clip(lo[:, 0], 0, w)
    l0 = np.clip(lo[:, 1], 0, h)
    s1 = np.clip(hi[:, 0] + 1, 0, w)
    l1 = np.clip(hi[:, 1] + 1, 0, h)
    return (ii[l1, s1] - ii[l0, s1] - ii[l1, s0] + ii[l0, s0]).astype(np.int64)


def refine_matches(
    ref: NDArray[np.float32],
    warped: NDArray[np.float32],
    valid: NDArray[np.bool_],
    points_ref: NDArray[np.float64],
    points_warped: NDArray[np.float64],
    window: int = 21,
    search: int = 3,
    iterations: int = 4,
    min_score: float = 0.5,
    max_shift_px: float = 2.5,
    ref_pattern: NDArray[np.float32] | None = None,
    warped_pattern: NDArray[np.float32] | None = None,
    valid_integral: NDArray[np.int32] | None = None,
) -> Refined:
    """Refine the warped-frame position of every match (see the module docstring).

    Parameters
    ----------
    ref : ndarray (lines, samples) float32, reference image DN
    warped : ndarray (lines, samples) float32, match image resampled in the reference geometry
    valid : ndarray (lines, samples) bool, where ``warped`` has data
    points_ref : ndarray (N, 2), reference positions (sample, line), kept fixed
    points_warped : ndarray (N, 2), matched positions in the warped frame (start values)
    window : odd correlation window size, pixels
    search : integer search radius, pixels
    iterations : Gauss-Newton polishing steps (0 = parabola only)
    min_score : lowest accepted NCC at the refined position
    max_shift_px : largest accepted move from the start position
    ref_pattern, warped_pattern : images (same shapes) the positions are found on, e.g.
        :func:`local_normalize` of ``ref`` and ``warped``; None = ``ref``, ``warped``. The
        score (and ``min_score``) is always the NCC of ``ref`` and ``warped`` at the result
    valid_integral : :func:`integral_image` of ``valid``, when the caller has it (None = computed)
    """
    n = points_ref.shape[0]
    if n == 0:
        return Refined(np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool), np.zeros(0, bool), np.zeros(0, np.int64))
    half = window // 2
    h, w = ref.shape
    pa = np.asarray(points_ref, np.float64)
    pb = np.asarray(points_warped, np.float64)
    # The template must lie in the reference image.
    inside = (
        (pa[:, 0] - half - 1 >= 0) & (pa[:, 1] - half - 1 >= 0) & (pa[:, 0] + half + 2 < w) & (pa[:, 1] + half + 2 < h)
    )
    # The searched patches may leave the image (sampling replicates its border pixels there): validity
    # of the warped data is checked at the final position only, so a match near the image border or
    # the edge of a small overlap survives as long as its own window is on data.
    rp = ref if ref_pattern is None else ref_pattern
    wp = warped if warped_pattern is None else warped_pattern
    t_raw = sample_patches(rp, pa, half)
    big = sample_patches(wp, pb, half + search)
    k = 2 * search + 1
    # The (2 search + 1)^2 zero-mean NCC scores of every measure: one cv2.matchTemplate per measure.
    # A Python loop, but measured faster than one batched numpy product over all measures' windows
    # (which must first copy every window: 400 measures x 49 shifts x 21^2 pixels = 35 MB per pair):
    # 7 ms vs 30 ms for 400 measures (docs/benchmarks/match.md, session 11). Same scores to 3e-7.
    ncc = np.empty((n, k, k), np.float32)
    match_template, method = cv2.matchTemplate, cv2.TM_CCOEFF_NORMED
    for b_i, t_i, out_i in zip(big, t_raw, ncc):  # written into ``ncc`` in place (a third cheaper than assigning)
        match_template(b_i, t_i, method, out_i)
    flat = ncc.reshape(n, -1)
    best = np.argmax(flat, axis=1)
    bi, bj = np.divmod(best, k)
    interior = (bi > 0) & (bi < k - 1) & (bj > 0) & (bj < k - 1)
    rows = np.arange(n)
    c0 = flat[rows, best]

    def vertex(m: NDArray[np.float32], c: NDArray[np.float32], p: NDArray[np.float32]) -> NDArray[np.float64]:
        den = m - 2.0 * c + p
        with np.errstate(divide="ignore", invalid="ignore"):
            v = np.where(den < 0, 0.5 * (m - p) / den, 0.0)
        return np.clip(v, -0.5, 0.5).astype(np.float64)

    bi_c, bj_c = np.clip(bi, 1, k - 2), np.clip(bj, 1, k - 2)
    dy = vertex(ncc[rows, bi_c - 1, bj_c], c0, ncc[rows, bi_c + 1, bj_c])
    dx = vertex(ncc[rows, bi_c, bj_c - 1], c0, ncc[rows, bi_c, bj_c + 1])
    d = np.stack([bj - search + dx, bi - search + dy], axis=-1)

    # Gauss-Newton on ref ~ a * warped(x + d) + b, unknowns (a, b, a*dx, a*dy). The design
    # matrix is filled in place (its transpose, rows c, 1, gx, gy), not stacked anew each step.
    t_col = t_raw.reshape(n, -1, 1).astype(np.float64)
    a_t = np.empty((n, 4, window * window))
    a_t[:, 1] = 1.0
    a4 = a_t.reshape(n, 4, window, window)
    a_mat = a_t.transpose(0, 2, 1)
    for _ in range(iterations):
        p = sample_patches(wp, pb + d, half + 1)
        a4[:, 0] = p[:, 1:-1, 1:-1]
        np.subtract(p[:, 1:-1, 2:], p[:, 1:-1, :-2], out=a4[:, 2], dtype=np.float64)
        a4[:, 2] *= 0.5
        np.subtract(p[:, 2:, 1:-1], p[:, :-2, 1:-1], out=a4[:, 3], dtype=np.float64)
        a4[:, 3] *= 0.5
        ata = np.matmul(a_t, a_mat)
        atb = np.matmul(a_t, t_col)
        ata += np.eye(4) * 1e-9 * np.trace(ata, axis1=1, axis2=2)[:, None, None]
        sol = np.linalg.solve(ata, atb)[..., 0]
        gain = sol[:, 0]
        step = sol[:, 2:] / np.where(np.abs(gain) > 1e-9, gain, np.nan)[:, None]
        step = np.clip(np.nan_to_num(step), -1.0, 1.0)
        d = d + step
    final = pb + d
    tmpl = _normalize(t_raw if ref_pattern is None else sample_patches(ref, pa, half))
    score = np.sum(_normalize(sample_patches(warped, final, half)) * tmpl, axis=(1, 2)).astype(np.float64)
    moved = np.hypot(d[:, 0], d[:, 1])
    # The window's bilinear support must be valid data; the ring one pixel beyond it (the last
    # Gauss-Newton step's central differences) may lie outside, as ``valid_region`` keeps ``valid``
    # a pixel inside the match image (and the warp replicates its border).
    f = np.nan_to_num(final, nan=-1e9)
    lo = np.floor(f).astype(np.int64) - half
    hi = np.ceil(f).astype(np.int64) + half
    on_data = (lo[:, 0] >= 1) & (lo[:, 1] >= 1) & (hi[:, 0] < w - 1) & (hi[:, 1] < h - 1)
    on_data &= box_count(valid, lo, hi, valid_integral) == (hi - lo + 1).prod(axis=1)
    inside &= on_data
    ok = inside & interior & np.isfinite(final).all(axis=1) & (score >= min_score) & (moved <= max_shift_px)
    return Refined(final, score, ok, inside, np.full(n, window, np.int64))


def refine_matches_adaptive(
    ref: NDArray[np.float32],
    warped: NDArray[np.float32],
    valid: NDArray[np.bool_],
    points_ref: NDArray[np.float64],
    points_warped: NDArray[np.float64],
    window: int = 21,
    search: int = 3,
    iterations: int = 4,
    min_score: float = 0.5,
    max_shift_px: float = 2.5,
    min_window: int = 11,
    ref_pattern: NDArray[np.float32] | None = None,
    warped_pattern: NDArray[np.float32] | None = None,
) -> Refined:
    """:func:`refine_matches`, retrying with smaller windows the measures whose window left the data.

    When the finer image of a pair is warped onto the coarser one it covers a small
    patch of the pair frame (1/16 of it at 4x scale: a ~64 pixel square on a 256^2
    image), and most of its matches lie within a 21-pixel window of the patch's edge.
    Measures whose window (or search area) leaves the image or the warped data are
    refined again with windows shrinking by ~30 % down to ``min_window`` (odd), on the
    same acceptance rules (a smaller window is less precise, but such a measure was
    lost otherwise). ``window`` in the result says which size each measure used.
    """
    ii = integral_image(valid) if points_ref.shape[0] else None  # shared by the retries
    r = refine_matches(ref, warped, valid, points_ref, points_warped, window, search, iterations, min_score, max_shift_px,
                       ref_pattern, warped_pattern, ii)
    if r.on_data is None or r.on_data.all():
        return r
    points, score, ok, used = r.points.copy(), r.score.copy(), r.ok.copy(), r.window.copy()
    todo = np.flatnonzero(~r.on_data)
    w = window
    while todo.size and w > min_window:
        w = max(min_window, int(round(w * 0.7)) | 1)
        s = refine_matches(ref, warped, valid, points_ref[todo], points_warped[todo], w, search, iterations,
                           min_score, max_shift_px, ref_pattern, warped_pattern, ii)
        points[todo], score[todo], ok[todo], used[todo] = s.points, s.score, s.ok, w
        todo = todo[~s.on_data]
    return Refined(points, score, ok, ~np.isin(np.arange(ok.size), todo), used)
