"""Dense displacement field of a pair (OpenCV's DIS optical flow), read at the measures.

After the datum pre-transform the partner still carries the relief's parallax, which
varies inside a 21-pixel correlation window when the two views converge (measured on
the tiny mission: similar-illumination measures of views converging by more than 30 deg
have twice the true error of those within 20 deg). A dense flow with 8-pixel patches
and a variational (smoothness + brightness/gradient constancy) refinement follows the
parallax at the scale of a few pixels; reading each measure's partner position from the
flow at its base position cut the similar class's p95 on a 60-pair sample of the tiny
mission from 0.57 to 0.49 px (docs/benchmarks/match.md, session 4), where windows of
other sizes, an affine window or a centre weighting had not moved it.

The flow runs on the locally normalized images of the refinement
(:func:`mercury_dem.match.refine.local_normalize`, here mapped to 8 bits as DIS
requires): illumination differs between the images of a pair and DIS assumes
brightness constancy. ``cv2.DISOpticalFlow`` is used rather than a flow written here:
it is coarse-to-fine (the pointing offset of several pixels is found), multi-threaded in
OpenCV and releases the GIL. Pure functions; the matcher decides where the result is used.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.match.refine import sample_patches

#: 8-bit mapping of a locally normalized image (unit local std): DN = 128 + this * value, clipped.
_NORMALIZED_TO_8BIT = 40.0


@dataclass(frozen=True)
class Flow:
    """A displacement field over a crop of the pair frame.

    Attributes
    ----------
    field : ndarray (h, w, 2) float32, (sample, line) displacement base -> warped partner
    origin : (sample, line) of the crop's first pixel in the pair frame
    usable : ndarray (h, w) bool, where the field is supported by the partner's data (the
        partner position, a flow patch's half-width inside its valid data)
    """

    field: NDArray[np.float32]
    origin: tuple[int, int]
    usable: NDArray[np.bool_]


def to_8bit(pattern: NDArray[np.float32]) -> NDArray[np.uint8]:
    """A locally normalized image as 8 bits (``128 + 40 * value``, clipped: +-3.2 local sigmas)."""
    return np.clip(pattern * _NORMALIZED_TO_8BIT + 128.0, 0.0, 255.0).astype(np.uint8)


def dense_flow(
    base_pattern: NDArray[np.float32],
    warped_pattern: NDArray[np.float32],
    valid: NDArray[np.bool_],
    patch_px: int = 8,
    stride_px: int = 4,
    variational_iterations: int = 10,
    initial: NDArray[np.float64] | None = None,
) -> Flow | None:
    """DIS flow from the base to the warped partner over the bounding box of the partner's data.

    Parameters
    ----------
    base_pattern, warped_pattern : ndarray (lines, samples) float32, locally normalized images
    valid : ndarray bool, where the warped partner has data
    patch_px, stride_px : DIS patch size and stride (pixels)
    variational_iterations : iterations of DIS's variational refinement at every scale
    initial : (2,) displacement the flow starts from everywhere (e.g. the median of the pair's
        refined matches). DIS's coarsest scale is bounded by the crop: on a 50-px wide strip it
        did not find a 7-px pointing offset by itself (measured on the tiny mission)

    Returns
    -------
    :class:`Flow`, or None when the partner's data is too small for a flow patch
    """
    rows = np.flatnonzero(valid.any(axis=1))
    cols = np.flatnonzero(valid.any(axis=0))
    if rows.size < 2 * patch_px or cols.size < 2 * patch_px:
        return None
    margin = 2 * patch_px
    h, w = valid.shape
    l0, l1 = max(int(rows[0]) - margin, 0), min(int(rows[-1]) + margin + 1, h)
    s0, s1 = max(int(cols[0]) - margin, 0), min(int(cols[-1]) + margin + 1, w)
    a8 = to_8bit(base_pattern[l0:l1, s0:s1])
    b8 = to_8bit(warped_pattern[l0:l1, s0:s1])
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(0)
    dis.setPatchSize(int(patch_px))
    dis.setPatchStride(int(stride_px))
    dis.setVariationalRefinementIterations(int(variational_iterations))
    dis.setUseMeanNormalization(True)
    start = None
    if initial is not None:
        start = np.empty(a8.shape + (2,), np.float32)
        start[...] = np.asarray(initial, np.float32).reshape(2)
    field = dis.calc(a8, b8, start)
    # where the partner position lies a patch half-width inside the partner's data
    inner = cv2.erode(valid[l0:l1, s0:s1].view(np.uint8), np.ones((patch_px + 1, patch_px + 1), np.uint8))
    yy, xx = np.mgrid[0 : l1 - l0, 0 : s1 - s0].astype(np.float32)
    mx, my = xx + field[..., 0], yy + field[..., 1]
    usable = cv2.remap(inner, mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    return Flow(field, (s0, l0), usable)


def flow_at(flow: Flow, points: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The displacement (N, 2) at base positions (bilinear), and whether it is usable there (N,)."""
    p = np.asarray(points, np.float64) - np.asarray(flow.origin, np.float64)
    h, w = flow.usable.shape
    inside = np.isfinite(p).all(axis=1) & (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] < w - 1) & (p[:, 1] < h - 1)
    q = np.where(inside[:, None], p, 0.0)
    d = np.stack([sample_patches(np.ascontiguousarray(flow.field[..., k]), q, 0)[:, 0, 0] for k in (0, 1)], axis=-1)
    ij = np.floor(q).astype(np.int64)
    ok = inside.copy()
    for di in (0, 1):  # the four pixels of the bilinear support
        for dj in (0, 1):
            ok &= flow.usable[ij[:, 1] + di, ij[:, 0] + dj]
    return d.astype(np.float64), ok


def base_position(flow: Flow, warped_points: NDArray[np.float64], start: NDArray[np.float64],
                  iterations: int = 5) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Base positions ``p`` with ``p + flow(p) = warped_points`` (fixed-point iterations from ``start``).

    The inverse reading, for measures whose partner-side position is the fixed one (a
    propagated anchor of the warped image). Returns the positions and whether the flow was
    usable at every iterate.
    """
    p = np.asarray(start, np.float64).copy()
    ok = np.ones(p.shape[0], bool)
    for _ in range(iterations):
        d, u = flow_at(flow, p)
        ok &= u
        p = np.where(ok[:, None], warped_points - d, p)
    return p, ok
