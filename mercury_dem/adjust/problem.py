"""The planetary bundle-adjustment problem as arrays, and its validation.

An :class:`AdjustmentProblem` holds everything :func:`~mercury_dem.adjust.bundle.bundle_adjust`
needs and nothing more, so the engine does not depend on the control-network
model (:func:`~mercury_dem.adjust.network.problem_from_network` joins the two).

Conventions: positions body-fixed metres; rotations body-fixed -> camera
(``v_cam = R @ (X - C)``); measures 0-based pixels (sample, line), centre of the
first pixel at (0, 0); sigmas in pixels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import AdjustmentError
from mercury_dem.geometry.camera import FramingCamera

#: A measure's point or camera index array: int64, or int32 where the blocked adjuster keeps its
#: indices small (numba compiles the kernels for either).
IndexArray = NDArray[np.int32] | NDArray[np.int64]


def _ids(name: str, values: NDArray[np.bool_], ids: tuple[str, ...] | NDArray[np.int64], limit: int = 10) -> str:
    idx = np.flatnonzero(values)
    shown = ", ".join(str(ids[i]) for i in idx[:limit])
    more = f" and {len(idx) - limit} more" if len(idx) > limit else ""
    return f"{name} {shown}{more}"


def unprojectable(r0: NDArray[np.float64]) -> NDArray[np.int64]:
    """Indices of the measures whose a-priori residuals (M, 2) are not finite (the point behind the camera)."""
    return np.flatnonzero(~np.all(np.isfinite(r0), axis=1))


def unprojectable_error(n_bad: int, where: str, points: list[Any], images: list[Any]) -> AdjustmentError:
    """The error both adjusters raise when measures cannot be projected at the a-priori state.

    ``where``: e.g. ``" of block 3"``; ``points``/``images``: the ids of the first few such measures.
    """
    return AdjustmentError(
        f"{n_bad} measures{where} cannot be projected at the a-priori state (point behind the camera), e.g. "
        f"points {points} in images {images}: check the a-priori points and poses")


@dataclass(frozen=True)
class AdjustmentProblem:
    """A bundle adjustment of framing-camera images.

    Parameters
    ----------
    cameras : tuple of FramingCamera, the distinct cameras (e.g. NAC and WAC at their sizes)
    image_camera : (n_img,) int, index into ``cameras`` for each image
    positions : (n_img, 3) a-priori camera positions, body-fixed metres
    rotations : (n_img, 3, 3) a-priori rotations body-fixed -> camera
    points : (n_pt, 3) a-priori point coordinates, body-fixed metres
    measure_image, measure_point : (M,) int, image and point index of each measure
    measures : (M, 2) measured (sample, line), 0-based pixels
    measure_sigma : (M,) measure sigma, pixels (> 0)
    image_ids : (n_img,) image ids, for reports and error messages
    point_ids : (n_pt,) point ids, int or str (default 0..n_pt-1)
    held_images : (n_img,) bool, images whose pointing (and position) are fixed
    held_points : (n_pt,) bool, points fixed (ground control)
    point_radius_sigma : (n_pt,) float or None, a per-point radius constraint (1 sigma, metres)
        centred on the point's a-priori radius, replacing the configured ``radius_sigma_m`` where
        finite (NaN: the configured one). How ground truth from laser altimetry enters the
        adjustment: the a-priori point sits at the altimetry's radius with the altimetry's sigma
        (:func:`mercury_dem.altimetry.constraints.altimetry_radius_priors`).
    pointing_sigma_urad : how wrong the a-priori ``rotations`` may be, per axis and image (1 sigma,
        microradians): the weight of the pointing constraint. A fact of the a-priori data like
        ``measure_sigma`` (a run takes it from the mission or ``apriori.pointing_sigma_urad``); None
        (the default) is refused by the adjusters, which have no safe guess.
    """

    cameras: tuple[FramingCamera, ...]
    image_camera: NDArray[np.int64]
    positions: NDArray[np.float64]
    rotations: NDArray[np.float64]
    points: NDArray[np.float64]
    measure_image: NDArray[np.int64]
    measure_point: NDArray[np.int64]
    measures: NDArray[np.float64]
    measure_sigma: NDArray[np.float64]
    image_ids: tuple[str, ...] = ()
    point_ids: NDArray[Any] = field(default_factory=lambda: np.zeros(0, np.int64))
    held_images: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    held_points: NDArray[np.bool_] = field(default_factory=lambda: np.zeros(0, bool))
    #: (n_img, 3, 3) rotations to start the iteration from (e.g. a lower level's solution);
    #: None starts at ``rotations``, which stay the centre of the pointing constraint either way.
    initial_rotations: NDArray[np.float64] | None = None
    point_radius_sigma: NDArray[np.float64] | None = None
    pointing_sigma_urad: float | None = None

    def __post_init__(self) -> None:
        n_img, n_pt = len(self.positions), len(self.points)
        set_ = object.__setattr__
        set_(self, "image_camera", np.asarray(self.image_camera, np.int64))
        set_(self, "positions", np.asarray(self.positions, np.float64))
        set_(self, "rotations", np.asarray(self.rotations, np.float64))
        set_(self, "points", np.asarray(self.points, np.float64))
        set_(self, "measure_image", np.asarray(self.measure_image, np.int64))
        set_(self, "measure_point", np.asarray(self.measure_point, np.int64))
        set_(self, "measures", np.asarray(self.measures, np.float64))
        set_(self, "measure_sigma", np.broadcast_to(np.asarray(self.measure_sigma, np.float64), (len(self.measure_image),)).copy())
        if not self.image_ids:
            set_(self, "image_ids", tuple(str(i) for i in range(n_img)))
        if len(self.point_ids) == 0:
            set_(self, "point_ids", np.arange(n_pt, dtype=np.int64))
        if len(self.held_images) == 0:
            set_(self, "held_images", np.zeros(n_img, bool))
        if len(self.held_points) == 0:
            set_(self, "held_points", np.zeros(n_pt, bool))
        if self.initial_rotations is not None:
            init = np.asarray(self.initial_rotations, np.float64)
            if init.shape != (n_img, 3, 3) or not np.all(np.isfinite(init)):
                raise AdjustmentError(f"initial_rotations must be finite, of shape ({n_img}, 3, 3), got {init.shape}")
            set_(self, "initial_rotations", init)
        if self.point_radius_sigma is not None:
            sig = np.asarray(self.point_radius_sigma, np.float64)
            if sig.shape != (n_pt,) or np.any(sig[np.isfinite(sig)] <= 0) or np.any(np.isinf(sig)):
                raise AdjustmentError(f"point_radius_sigma must have shape ({n_pt},) with values > 0 or NaN "
                                      f"(no altimetry constraint), got shape {sig.shape}")
            set_(self, "point_radius_sigma", sig)
        if self.pointing_sigma_urad is not None:
            if not (np.isfinite(self.pointing_sigma_urad) and self.pointing_sigma_urad > 0):
                raise AdjustmentError(f"pointing_sigma_urad must be a positive number, got {self.pointing_sigma_urad}")
            set_(self, "pointing_sigma_urad", float(self.pointing_sigma_urad))
        self.validate()

    @property
    def n_images(self) -> int:
        return len(self.positions)

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_measures(self) -> int:
        return len(self.measure_image)

    def validate(self) -> None:
        """Raise :class:`AdjustmentError` naming what is wrong (shapes, indices, NaN, sigmas)."""
        n_img, n_pt, m = self.n_images, self.n_points, self.n_measures
        if m == 0:
            raise AdjustmentError("the network has no measures: nothing to adjust (match the images first)")
        shapes = {
            "positions": (self.positions.shape, (n_img, 3)),
            "rotations": (self.rotations.shape, (n_img, 3, 3)),
            "points": (self.points.shape, (n_pt, 3)),
            "image_camera": (self.image_camera.shape, (n_img,)),
            "measure_point": (self.measure_point.shape, (m,)),
            "measures": (self.measures.shape, (m, 2)),
            "image_ids": ((len(self.image_ids),), (n_img,)),
            "point_ids": (self.point_ids.shape, (n_pt,)),
            "held_images": (self.held_images.shape, (n_img,)),
            "held_points": (self.held_points.shape, (n_pt,)),
        }
        for name, (got, want) in shapes.items():
            if got != want:
                raise AdjustmentError(f"adjustment problem: field '{name}' has shape {got}, expected {want}")
        if len(self.cameras) == 0 or self.image_camera.min(initial=0) < 0 or self.image_camera.max(initial=-1) >= len(self.cameras):
            raise AdjustmentError(f"adjustment problem: image_camera must index the {len(self.cameras)} cameras given")
        bad = (self.measure_image < 0) | (self.measure_image >= n_img)
        if bad.any():
            raise AdjustmentError(
                f"{int(bad.sum())} measures reference unknown images (indices {np.unique(self.measure_image[bad])[:10].tolist()}; "
                f"the problem has {n_img} images): rebuild the network from the same image list"
            )
        bad = (self.measure_point < 0) | (self.measure_point >= n_pt)
        if bad.any():
            raise AdjustmentError(
                f"{int(bad.sum())} measures reference unknown points (indices {np.unique(self.measure_point[bad])[:10].tolist()}; "
                f"the problem has {n_pt} points)"
            )
        bad = ~np.all(np.isfinite(self.measures), axis=1)
        if bad.any():
            pts = self.point_ids[self.measure_point[bad]]
            raise AdjustmentError(
                f"{int(bad.sum())} measures are NaN/inf (first on points {pts[:10].tolist()}, images "
                f"{[self.image_ids[i] for i in self.measure_image[bad][:10]]}): drop or fix them before adjusting"
            )
        bad = ~(self.measure_sigma > 0) | ~np.isfinite(self.measure_sigma)
        if bad.any():
            raise AdjustmentError(
                f"{int(bad.sum())} measures have sigma <= 0 or NaN (first {self.measure_sigma[bad][:5].tolist()} px on points "
                f"{self.point_ids[self.measure_point[bad]][:10].tolist()}, images "
                f"{[self.image_ids[i] for i in self.measure_image[bad][:10]]}): measure sigmas must be positive pixels"
            )
        bad = ~np.all(np.isfinite(self.points), axis=1)
        if bad.any():
            raise AdjustmentError(f"a-priori coordinates are NaN/inf for {_ids('points', bad, self.point_ids)}")
        bad = ~np.all(np.isfinite(self.positions), axis=1) | ~np.all(np.isfinite(self.rotations), axis=(1, 2))
        if bad.any():
            raise AdjustmentError(f"a-priori pose is NaN/inf for {_ids('images', bad, self.image_ids)}")


def pointing_sigma_radians(pointing_sigma_urad: float | None) -> float:
    """The a-priori pointing sigma (µrad) in the radians the adjusters' constraint is written in.

    The value goes through degrees and back (``radians(degrees(µrad · 1e-6))``) because that is the
    conversion every run made while the adjusters were configured in degrees: 450 µrad becomes
    4.5000000000000004e-4 rad, not 4.5e-4, and keeping the round trip keeps every adjustment bit for bit
    what it was.

    Raises
    ------
    AdjustmentError : ``pointing_sigma_urad`` is None (:func:`stated_pointing_sigma_urad`)
    """
    return float(np.radians(math.degrees(stated_pointing_sigma_urad(pointing_sigma_urad) * 1e-6)))


def stated_pointing_sigma_urad(pointing_sigma_urad: float | None) -> float:
    """``pointing_sigma_urad`` as a float; :class:`AdjustmentError` when the problem states none (None)."""
    if pointing_sigma_urad is None:
        raise AdjustmentError("the adjustment problem states no a-priori pointing sigma (pointing_sigma_urad; a run "
                              "takes it from the mission's mission.json or apriori.pointing_sigma_urad)")
    return float(pointing_sigma_urad)
