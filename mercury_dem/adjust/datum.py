"""Where the tie points' radius constraint is centred: the block's own surface, not the datum sphere.

Without ground control the radius of a weakly determined tie point (two nearly parallel rays) is
held by its a-priori radius constraint. Centred on the datum sphere (``point_prior_center:
datum``), that constraint pulls every point toward the sphere by ``σ_h² / (σ_h² + σ_p²)`` of its
true height (``σ_h`` what its rays say about its height, ``σ_p`` the constraint's sigma): a
low-pass copy of the true shape with the opposite sign. Measured on the demo (2026-11-26,
``workflows/benchmarks/shape_study.py``): the truth's polar depression (1.5 km) and long waves
came out as "poles ~+0.3…1 km high", degree 2 of DEM − truth 163 m RMS without altimetry;
with the constraint's sigma at 100 km instead of 10 km, 44 m — but the points' scatter grows
where the constraint was the only thing fixing their depth.

So the constraint is re-centred (:func:`neighbour_radii`): a first adjustment with a loose
radius constraint gives an unbiased but noisy cloud; each point's constraint is then centred on
the median radius of its nearest neighbours in that cloud, and the adjustment runs again with the
configured sigma. The weak points are held to the surface their neighbours see, at every
wavelength longer than the neighbourhood, and keep the regularization.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

__all__ = ["neighbour_radii"]


def neighbour_radii(points_xyz: ArrayLike, usable: ArrayLike | None = None, k: int = 50) -> NDArray[np.float64]:
    """Median radius of each point's ``k`` nearest usable points (itself included), metres.

    Parameters
    ----------
    points_xyz : (n, 3) body-fixed points, m (non-finite rows are not usable)
    usable : (n,) bool, the points whose radii may be used (e.g. not under-determined); default all
    k : neighbours (fewer when fewer points are usable)

    Returns
    -------
    (n,) float: the median radius around each point (its direction's), NaN where no point is usable
    or the point itself is not finite. The median, not the mean: a point thrown kilometres off by
    a bad ray must not move its neighbours' centre.

    Why scipy's kd-tree and ``np.median`` over an (n, k) array: 10⁵ points × 50 neighbours is
    5·10⁶ values, a fraction of a second; the neighbours are searched on unit directions (chord
    distance), so the radii themselves do not decide who is a neighbour.
    """
    xyz = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    r = np.linalg.norm(xyz, axis=1)
    finite = np.isfinite(r) & (r > 0)
    ok = finite if usable is None else finite & np.asarray(usable, bool)
    out = np.full(len(xyz), np.nan)
    if not ok.any() or not finite.any():
        return out
    units = xyz[ok] / r[ok, None]
    tree = cKDTree(units)
    kk = int(min(max(k, 1), ok.sum()))
    _, idx = tree.query(xyz[finite] / r[finite, None], k=kk)
    idx = np.asarray(idx).reshape(int(finite.sum()), kk)
    out[finite] = np.median(r[ok][idx], axis=1)
    return out
