"""Reductions of a pixel's neighbours in the gridding kernels (numba): 1-sigma filtered median, weighted mean.

``median11`` (Becker et al. 2016): the k (11) nearest radii sorted (a sorting network for
11, rank counting up to ``RANK_MAX``, insertion beyond), the points farther than one
standard deviation from the median dropped, the median of the rest. ``shepard`` (Becker
et al. 2015): the weighted mean and weighted spread of the radii. Written here rather than
with numpy's sort/median: they run once per pixel inside the compiled search loop, on
11-32 values, where a call into numpy would cost more than the work.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

#: Up to this many values, top-k selection and sorting count ranks instead of inserting.
RANK_MAX = 64


@numba.njit(cache=True, inline="always")
def _sort11(r: NDArray[np.float64]) -> None:  # pragma: no cover
    """Sort r[:11] ascending in place with a 35-comparator sorting network (min/max pairs, no
    branches; checked on all 2**11 0/1 inputs in the tests). Same values as any sort.
    """
    v0, v1, v2, v3, v4, v5, v6, v7, v8, v9, v10 = r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10]
    v0, v9 = min(v0, v9), max(v0, v9)
    v1, v6 = min(v1, v6), max(v1, v6)
    v2, v4 = min(v2, v4), max(v2, v4)
    v3, v7 = min(v3, v7), max(v3, v7)
    v5, v8 = min(v5, v8), max(v5, v8)
    v0, v1 = min(v0, v1), max(v0, v1)
    v3, v5 = min(v3, v5), max(v3, v5)
    v4, v10 = min(v4, v10), max(v4, v10)
    v6, v9 = min(v6, v9), max(v6, v9)
    v7, v8 = min(v7, v8), max(v7, v8)
    v1, v3 = min(v1, v3), max(v1, v3)
    v2, v5 = min(v2, v5), max(v2, v5)
    v4, v7 = min(v4, v7), max(v4, v7)
    v8, v10 = min(v8, v10), max(v8, v10)
    v0, v4 = min(v0, v4), max(v0, v4)
    v1, v2 = min(v1, v2), max(v1, v2)
    v3, v7 = min(v3, v7), max(v3, v7)
    v5, v9 = min(v5, v9), max(v5, v9)
    v6, v8 = min(v6, v8), max(v6, v8)
    v0, v1 = min(v0, v1), max(v0, v1)
    v2, v6 = min(v2, v6), max(v2, v6)
    v4, v5 = min(v4, v5), max(v4, v5)
    v7, v8 = min(v7, v8), max(v7, v8)
    v9, v10 = min(v9, v10), max(v9, v10)
    v2, v4 = min(v2, v4), max(v2, v4)
    v3, v6 = min(v3, v6), max(v3, v6)
    v5, v7 = min(v5, v7), max(v5, v7)
    v8, v9 = min(v8, v9), max(v8, v9)
    v1, v2 = min(v1, v2), max(v1, v2)
    v3, v4 = min(v3, v4), max(v3, v4)
    v5, v6 = min(v5, v6), max(v5, v6)
    v7, v8 = min(v7, v8), max(v7, v8)
    v2, v3 = min(v2, v3), max(v2, v3)
    v4, v5 = min(v4, v5), max(v4, v5)
    v6, v7 = min(v6, v7), max(v6, v7)
    r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7], r[8], r[9], r[10] = v0, v1, v2, v3, v4, v5, v6, v7, v8, v9, v10


@numba.njit(cache=True)
def filtered_median(r: NDArray[np.float64], s: NDArray[np.float64], n: int, sigma: float) -> tuple[float, float]:  # pragma: no cover
    """1-sigma filtered median of r[:n] (sorted in place; s: scratch of n) and the spread of the kept run."""
    if n == 11:
        _sort11(r)
    elif n <= RANK_MAX:  # sort by counting ranks (no data-dependent branches; ties by position)
        for a in range(n):
            v = r[a]
            q = 0
            for b in range(n):
                w = r[b]
                q += (w < v) | ((w == v) & (b < a))
            s[q] = v
        for a in range(n):
            r[a] = s[a]
    else:
        for i in range(1, n):  # insertion sort
            v = r[i]
            j = i - 1
            while j >= 0 and r[j] > v:
                r[j + 1] = r[j]
                j -= 1
            r[j + 1] = v
    if n % 2:
        med = r[n // 2]
    else:
        med = 0.5 * (r[n // 2 - 1] + r[n // 2])
    s1 = 0.0
    s2 = 0.0
    for i in range(n):
        c = r[i] - med
        s1 += c
        s2 += c * c
    var = s2 / n - (s1 / n) ** 2
    band = sigma * math.sqrt(var) if var > 0 else 0.0
    lo = 0
    hi = 0
    for i in range(n):
        c = r[i] - med
        if c < -band:
            lo += 1
        if c <= band:
            hi += 1
    nk = hi - lo
    if nk <= 0:
        return med, np.nan
    a = lo + (nk - 1) // 2
    b = lo + nk // 2
    value = med + 0.5 * ((r[a] - med) + (r[b] - med))
    if nk < 2:
        return value, np.nan
    t1 = 0.0
    t2 = 0.0
    for i in range(lo, hi):
        c = r[i] - med
        t1 += c
        t2 += c * c
    t1 /= nk
    return value, math.sqrt(max(t2 / nk - t1 * t1, 0.0))




@numba.njit(cache=True)
def weighted_mean(radius: NDArray[np.float64], ik: NDArray[np.int64], d: NDArray[np.float64], w: NDArray[np.float64], n: int | np.int64) -> tuple[float, float]:  # pragma: no cover
    """Weighted mean and weighted std of radius[ik[:n]] (weights w[:n]; a zero distance takes all)."""
    exact = False
    for i in range(n):
        if d[i] == 0.0:
            exact = True
    if exact:
        for i in range(n):
            w[i] = 1.0 if d[i] == 0.0 else 0.0
    ref = radius[ik[0]]
    sw = 0.0
    sm = 0.0
    used = 0
    for i in range(n):
        sw += w[i]
        sm += w[i] * (radius[ik[i]] - ref)
        if w[i] > 0:
            used += 1
    m = sm / sw
    sv = 0.0
    for i in range(n):
        c = radius[ik[i]] - ref - m
        sv += w[i] * c * c
    return ref + m, (math.sqrt(sv / sw) if used >= 2 else np.nan)
