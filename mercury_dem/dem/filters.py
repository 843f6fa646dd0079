"""Smoothing of a gridded DEM: NaN-aware box (averaging) filters.

The reference smoothed its median11 DEM with "a series of averaging filters"
(Becker et al. 2016). A box mean is written here as an explicit sum of shifted
slices rather than with ``scipy.ndimage.uniform_filter`` on purpose: scipy's
running-sum implementation makes a pixel's rounding depend on where the array
starts, so a chunked DEM would differ from a whole-map one in the last bit. The
explicit sum adds the same neighbours in the same order wherever the pixel sits.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def box_mean_nan(values: NDArray[np.floating], size: int) -> NDArray[np.float64]:
    """One pass of a NaN-aware ``size`` x ``size`` box mean.

    Parameters
    ----------
    values : ndarray of shape (H, W); NaN = no value
    size : odd box edge, pixels

    Returns
    -------
    ndarray of shape (H, W), float64: the mean of the valid pixels in the box
    around each pixel; NaN where the pixel itself has no value (gaps are not
    filled) and outside the array the box sees no value.
    """
    if size % 2 != 1 or size < 1:
        raise ValueError(f"box size must be a positive odd number, got {size}")
    v = np.asarray(values, dtype=np.float64)
    if size == 1:
        return v.copy()
    r = size // 2
    H, W = v.shape
    valid = np.isfinite(v)
    padded = np.zeros((H + 2 * r, W + 2 * r))
    padded[r : r + H, r : r + W] = np.where(valid, v, 0.0)
    pmask = np.zeros((H + 2 * r, W + 2 * r))
    pmask[r : r + H, r : r + W] = valid
    total = np.zeros((H, W))
    count = np.zeros((H, W))
    for di in range(size):
        for dj in range(size):
            total += padded[di : di + H, dj : dj + W]
            count += pmask[di : di + H, dj : dj + W]
    with np.errstate(invalid="ignore", divide="ignore"):
        out = total / count
    return np.where(valid, out, np.nan)


def smooth_height(height: NDArray[np.floating], size: int = 3, passes: int = 1) -> NDArray[np.float64]:
    """``passes`` successive NaN-aware box means of a height map (m), shape preserved.

    Each pass reaches ``size // 2`` pixels farther, so a chunk needs a halo of
    ``passes * (size // 2)`` pixels to match a whole-map result exactly.
    """
    out = np.asarray(height, dtype=np.float64)
    for _ in range(passes):
        out = box_mean_nan(out, size)
    return out
