"""Smoothing of a gridded DEM: NaN-aware box (averaging) filters.

The reference smoothed its median11 DEM with "a series of averaging filters"
(Becker et al. 2016). A box mean is written here as an explicit sum (compiled with
numba) rather than with ``scipy.ndimage.uniform_filter`` on purpose: scipy's
running-sum implementation makes a pixel's rounding depend on where the array
starts, so a chunked DEM would differ from a whole-map one in the last bit. The
explicit sum adds the same neighbours in the same order wherever the pixel sits.
(The box skips the pixels without a value: adding their 0.0 instead, as a masked
array sum does, gives the same bits, since the running sum starts at +0.0.)
"""

from __future__ import annotations

import math

import numba
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
    v = np.ascontiguousarray(values, dtype=np.float64)
    if size == 1:
        return v.copy()
    out = np.empty_like(v)
    _box_mean_pass(v, size, out)
    return out


@numba.njit(cache=True, nogil=True)
def _box_mean_pass(v: NDArray[np.float64], size: int, out: NDArray[np.float64]) -> None:  # pragma: no cover - compiled
    """Compiled: each valid pixel's box summed in a fixed order (rows of the box top to
    bottom, each left to right), whatever the pixel's place in the array. One pass over
    the map instead of numpy's ~25 whole-array passes (shifted sums, masks, temporaries).
    """
    H, W = v.shape
    r = size // 2
    for i in range(H):
        for j in range(W):
            if not math.isfinite(v[i, j]):
                out[i, j] = np.nan
                continue
            total = 0.0
            count = 0.0
            for ii in range(i - r, i + r + 1):
                if ii < 0 or ii >= H:
                    continue
                for jj in range(j - r, j + r + 1):
                    if 0 <= jj < W and math.isfinite(v[ii, jj]):
                        total += v[ii, jj]
                        count += 1.0
            out[i, j] = total / count


def smooth_height(height: NDArray[np.floating], size: int = 3, passes: int = 1) -> NDArray[np.float64]:
    """``passes`` successive NaN-aware box means of a height map (m), shape preserved.

    Each pass reaches ``size // 2`` pixels farther, so a chunk needs a halo of
    ``passes * (size // 2)`` pixels to match a whole-map result exactly.
    """
    out = np.asarray(height, dtype=np.float64)
    for _ in range(passes):
        out = box_mean_nan(out, size)
    return out
