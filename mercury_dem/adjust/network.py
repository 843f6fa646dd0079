"""Adapter between the control network (:mod:`mercury_dem.network.model`) and the adjustment arrays."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.adjust.result import AdjustmentResult
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.network.model import ControlNetwork, PointType


def problem_from_network(
    network: ControlNetwork,
    cameras: Sequence[FramingCamera],
    positions: ArrayLike,
    rotations: ArrayLike,
    config: AdjustConfig | None = None,
    default_sigma_px: float = 1.0,
    initial_rotations: ArrayLike | None = None,
    *,
    pointing_sigma_urad: float | None = None,
) -> tuple[AdjustmentProblem, NDArray[np.int64]]:
    """The adjustment problem of a network's active measures.

    Parameters
    ----------
    network : the control network (a-priori point coordinates must be set)
    cameras : one FramingCamera per network image (same order as ``network.image_ids``)
    positions : (n_img, 3) a-priori positions, body-fixed m
    rotations : (n_img, 3, 3) a-priori rotations body-fixed -> camera
    config : used for ``held_images`` only (the rest applies in ``bundle_adjust``)
    default_sigma_px : sigma of measures whose sigma is unknown (NaN)
    initial_rotations : (n_img, 3, 3) rotations to start from (a lower level's solution); the
        pointing constraint stays centred on ``rotations``
    pointing_sigma_urad : how wrong ``rotations`` may be, per axis (1 sigma, µrad): the problem's
        :attr:`~AdjustmentProblem.pointing_sigma_urad` (the adjusters refuse None)

    Returns
    -------
    problem : AdjustmentProblem with every network image and point; ``Fixed`` points held
    measure_index : (M_active,) positions in the network's measures table of the problem's measures

    The measure sigma is the mean of the network's sample and line sigmas.
    ``Constrained`` points get the configured point sigmas like free ones.
    """
    n_img = network.n_images
    if len(cameras) != n_img:
        raise AdjustmentError(f"problem_from_network: {len(cameras)} cameras given for {n_img} network images")
    distinct: dict[FramingCamera, int] = {}
    image_camera = np.array([distinct.setdefault(c, len(distinct)) for c in cameras], dtype=np.int64)
    measure_index = np.flatnonzero(network.active_measures())
    sig = np.asarray(network.sigma, np.float64)[measure_index]
    finite = np.isfinite(sig)
    count = finite.sum(axis=1)
    total = np.where(finite, sig, 0.0).sum(axis=1)
    sigma = np.where(count > 0, total / np.maximum(count, 1), default_sigma_px)
    held_images = np.zeros(n_img, bool)
    problem = AdjustmentProblem(
        cameras=tuple(distinct),
        image_camera=image_camera,
        positions=np.asarray(positions, np.float64),
        rotations=np.asarray(rotations, np.float64),
        points=network.apriori_xyz,
        measure_image=network.measure_image[measure_index],
        measure_point=network.measure_point[measure_index],
        measures=network.pixels()[measure_index],
        measure_sigma=sigma,
        image_ids=tuple(str(i) for i in network.image_ids),
        point_ids=np.asarray(network.point_ids),
        held_images=held_images,
        held_points=np.asarray(network.point_type == PointType.FIXED),
        initial_rotations=None if initial_rotations is None else np.asarray(initial_rotations, np.float64),
        pointing_sigma_urad=pointing_sigma_urad,
    )
    return problem, measure_index


def network_with_result(network: ControlNetwork, result: AdjustmentResult, measure_index: NDArray[np.int64]) -> ControlNetwork:
    """The network with adjusted points, residuals (NaN for measures not adjusted) and rejections recorded.

    The engine's residuals are computed - measured; the network's column is measured - computed
    (:mod:`mercury_dem.network.model`, and ISIS's ``ControlPoint::ComputeResiduals``), so the
    sign is turned here.
    """
    residuals = np.full((network.n_measures, 2), np.nan)
    residuals[measure_index] = -result.residuals_px
    rejected = np.asarray(network.measure_rejected).copy()
    rejected[measure_index] = result.rejected
    return network.with_adjustment(result.points, residuals, measure_rejected=rejected)
