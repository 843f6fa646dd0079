"""The DEM smoothing (NaN-aware box means) against whole-array numpy sums."""

from __future__ import annotations

import numpy as np


def _box_mean_reference(v: np.ndarray, size: int) -> np.ndarray:
    """NaN-aware box mean as whole-array numpy sums of shifted slices (the test's oracle)."""
    r = size // 2
    H, W = v.shape
    valid = np.isfinite(v)
    padded = np.zeros((H + 2 * r, W + 2 * r))
    padded[r : r + H, r : r + W] = np.where(valid, v, 0.0)
    pmask = np.zeros_like(padded)
    pmask[r : r + H, r : r + W] = valid
    total = np.zeros((H, W))
    count = np.zeros((H, W))
    for di in range(size):
        for dj in range(size):
            total += padded[di : di + H, dj : dj + W]
            count += pmask[di : di + H, dj : dj + W]
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(valid, total / count, np.nan)


def test_compiled_box_mean_equals_numpy_sums_bit_for_bit():
    """The compiled smoothing gives the bits of the whole-array numpy sums (same order of
    additions), with gaps, edges, exact and signed-zero values, for several boxes and passes."""
    from mercury_dem.dem.filters import smooth_height

    rng = np.random.default_rng(0)
    for t in range(200):
        H, W = rng.integers(1, 30, 2)
        v = rng.normal(0, 1000, (H, W))
        if t % 3 == 0:
            v = np.round(v)
        if t % 5 == 0:
            v[rng.random((H, W)) < 0.5] = -0.0
        v[rng.random((H, W)) < rng.uniform(0, 0.7)] = np.nan
        for size in (1, 3, 5):
            for passes in (1, 2):
                want = v.copy()
                for _ in range(passes):
                    want = _box_mean_reference(want, size) if size > 1 else want
                got = smooth_height(v, size, passes)
                np.testing.assert_array_equal(got, want)
                assert np.array_equal(np.signbit(got), np.signbit(want))
