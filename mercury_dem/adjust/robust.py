"""Robust losses (by iteratively reweighted least squares) and k x MAD rejection.

Residuals here are whitened (divided by the measure sigma), so thresholds are in
units of the measure sigma. A loss is written as rho(s) of the squared norm s of
a measure's 2-vector residual (the Ceres convention); the cost of a measure is
0.5 rho(s) and its IRLS weight is rho'(s).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from mercury_dem.stats import NMAD_FACTOR

LOSSES = ("none", "huber", "cauchy")


def loss_rho(s: NDArray[np.float64], loss: str, scale: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """rho(s) and rho'(s) of squared whitened residual norms ``s`` (M,).

    ``huber``: quadratic below ``scale`` (in sigmas), linear beyond;
    ``cauchy``: ``scale^2 log(1 + s/scale^2)``; ``none``: ``s``.
    """
    if loss == "none":
        return s, np.ones_like(s)
    a2 = scale * scale
    if loss == "huber":
        r = np.sqrt(s)
        big = s > a2
        rho = np.where(big, 2.0 * scale * r - a2, s)
        with np.errstate(divide="ignore"):
            w = np.where(big, scale / np.where(big, r, 1.0), 1.0)
        return rho, w
    if loss == "cauchy":
        return a2 * np.log1p(s / a2), 1.0 / (1.0 + s / a2)
    raise ValueError(f"unknown robust loss {loss!r}; choose one of {LOSSES}")


def rejection_limit(norms: NDArray[np.float64], sample: NDArray[np.bool_], k: float, floor: float) -> float:
    """Residual-norm limit ``median + k * 1.4826 * MAD`` over the ``sample`` measures (at least ``floor``).

    The adjustment passes all measures as the sample (median and MAD shrug off
    up to half of them being outliers); using only the accepted ones, as jigsaw
    does, truncates the distribution each round so the limit creeps down and
    good measures erode. The limit applies to all measures, so rejected ones can
    come back.
    """
    x = norms[sample]
    if x.size == 0:
        return float("inf")
    med = float(np.median(x))
    mad = float(np.median(np.abs(x - med)))
    return max(med + k * NMAD_FACTOR * mad, floor)
