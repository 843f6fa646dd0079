"""The point cloud a DEM is gridded from: the control network's points that are kept and finite."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from mercury_dem.network.model import ControlNetwork


def point_cloud(network: ControlNetwork, adjusted: bool = True) -> NDArray[np.float64]:
    """Body-fixed points (N, 3) of a network: adjusted (not rejected, finite) or a-priori.

    Parameters
    ----------
    network : a :class:`~mercury_dem.network.model.ControlNetwork` (anything with ``adjusted_xyz``,
        ``apriori_xyz`` (N, 3) and ``point_rejected`` (N,))
    adjusted : the adjusted coordinates (True) or the a-priori ones

    Returns
    -------
    (M, 3) float64 : the points not rejected whose three coordinates are finite, in network order
    """
    xyz = network.adjusted_xyz if adjusted else network.apriori_xyz
    ok = np.all(np.isfinite(xyz), axis=1) & ~np.asarray(network.point_rejected)
    return np.asarray(xyz[ok], dtype=np.float64)
