"""The pure parts of a unit adjusted from its merged store by blocks (never the merged network in memory).

:func:`mercury_dem.io.adjusted_network_store.adjust_stored_unit` drives it: the merged store's point blocks are
read by the blocked adjustment's shards (in this process or one actor per Dask worker) through
:class:`UnitBlockPrior` (the unit's image numbering and point prior centre applied to each block as it is read,
as :func:`~mercury_dem.adjust.unit.adjust_unit_network` applies them to its whole problem); the diagnosis
(islands, images without active measures, weak images) and the residual statistics are summed block by block
(:class:`BlockTally`), and :class:`StreamedUnitResult` carries what the unit's summary and ``bundleout.txt``
need, never a measure-sized array. Same numbers as the in-memory blocked path (the sums per image in the same
order: bit for bit; the network-wide RMS summed in another order: to rounding).

What this path does not do (the unit then takes the in-memory path, its summary says why:
:func:`streamed_fallback_reason`): altimetry passes, re-centring the point priors on the block, a-posteriori
sigmas, solving positions, a unit that is not adjusted by blocks.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from mercury_dem.adjust.datum import centred_points
from mercury_dem.adjust.diagnose import Diagnosis
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.exceptions import AdjustmentError
from mercury_dem.network.blocks import BlockData

__all__ = ["BlockTally", "StreamedUnitResult", "UnitBlockPrior", "streamed_fallback_reason"]


def streamed_fallback_reason(cfg: AdjustConfig, level: str, n_measures: int, *, altimetry: bool) -> str | None:
    """Why a unit of ``adjust.streamed_merge_levels`` is adjusted in memory after all; None: from its store.

    ``altimetry``: the mission has shots for this level (``adjust.altimetry_levels``).
    """
    from mercury_dem.adjust.cascade import adjusts_by_blocks

    if not adjusts_by_blocks(cfg, level, n_measures):
        return (f"not adjusted by blocks (adjust.blocked_levels / blocked_min_measures): the {level} is solved "
                "in memory, so its merged network is read back")
    if cfg.solve_positions:
        return "adjust.solve_positions: the blocked adjustment solves pointing only"
    if cfg.posterior_sigmas:
        return "adjust.posterior_sigmas: the a-posteriori sigmas are not yet computed from the stored blocks"
    if altimetry:
        return "altimetry passes (adjust.altimetry_levels) are not yet done from the stored blocks"
    if level in cfg.point_prior_recentre_levels:
        return "re-centring on the block (adjust.point_prior_recentre_levels) is not yet done from the stored blocks"
    return None


@dataclass(frozen=True)
class UnitBlockPrior:
    """Applied to each stored block as it is read (picklable: it travels to the workers).

    ``image_map``: the store's image index -> the unit's (its images with measures, as
    ``ControlNetwork.drop_unused_images`` keeps them; -1 for the others, which have no measure). The free
    points' a-priori coordinates are placed as ``centre_point_priors`` places them (``center``, the datum
    radius, the body's ``shape`` or None).
    """

    image_map: NDArray[np.int64]
    center: str
    datum_radius_m: float
    shape: Any = None

    def __call__(self, block: BlockData) -> BlockData:
        pts = centred_points(block.apriori_points, block.held_points, self.center, self.datum_radius_m, self.shape)
        return dataclasses.replace(block, apriori_points=pts, measure_image=self.image_map[block.measure_image])


@dataclass
class BlockTally:
    """The diagnosis and residual statistics summed block by block, in block order.

    ``add_graph`` before the solve (each block's active measures: images per point), ``add_result`` after it
    (accepted measures, frozen points, residuals in pixels).
    """

    n_images: int
    per_image: NDArray[np.int64] = field(init=False)
    edges: NDArray[np.int64] = field(init=False)
    underdetermined: list[NDArray[np.int64]] = field(default_factory=list)
    n_points: int = 0
    n_measures: int = 0
    sq_image: NDArray[np.float64] = field(init=False)
    keep_image: NDArray[np.int64] = field(init=False)
    sums: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    kept: int = 0
    rejected: int = 0

    def __post_init__(self) -> None:
        self.per_image = np.zeros(self.n_images, np.int64)
        self.edges = np.zeros(0, np.int64)
        self.sq_image = np.zeros(self.n_images)
        self.keep_image = np.zeros(self.n_images, np.int64)

    def add_graph(self, block: BlockData, min_point_measures: int) -> None:
        mi, mp = block.measure_image, block.measure_point
        self.per_image += np.bincount(mi, minlength=self.n_images)
        per_point = np.bincount(mp, minlength=len(block.apriori_points))
        self.underdetermined.append(np.flatnonzero(per_point < min_point_measures) + block.point_start)
        self.n_points += len(block.apriori_points)
        self.n_measures += len(mi)
        same = mp[1:] == mp[:-1]  # measures sorted by point: consecutive images of one point are linked
        a, b = mi[:-1][same], mi[1:][same]
        self.edges = np.unique(np.concatenate([self.edges, np.minimum(a, b) * self.n_images + np.maximum(a, b)]))

    def diagnosis(self, min_image_measures: int) -> Diagnosis:
        """As :func:`~mercury_dem.adjust.diagnose.diagnose` gives it on the whole problem (same islands, same order)."""
        k = self.n_images
        a, b = self.edges // max(k, 1), self.edges % max(k, 1)
        graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(k, k))
        _, lab = connected_components(graph, directed=False)
        has = self.per_image > 0
        islands: list[NDArray[np.int64]] = []
        if has.any():
            _, inv = np.unique(lab[has], return_inverse=True)
            members = np.flatnonzero(has)
            order = np.argsort(inv, kind="stable")
            islands = sorted(np.split(members[order], np.cumsum(np.bincount(inv))[:-1]), key=len, reverse=True)
        und = np.concatenate(self.underdetermined) if self.underdetermined else np.zeros(0, np.int64)
        return Diagnosis(islands=tuple(islands), images_without_measures=np.flatnonzero(~has),
                         weak_images=np.flatnonzero(has & (self.per_image < min_image_measures)),
                         underdetermined_points=und.astype(np.int64))

    def check_solvable(self, diag: Diagnosis, held: NDArray[np.bool_], image_ids: tuple[str, ...]) -> None:
        """:func:`~mercury_dem.adjust.diagnose.check_solvable` with islands allowed (a unit's configuration)."""
        no_meas = diag.images_without_measures[~held[diag.images_without_measures]]
        if len(no_meas):
            names = ", ".join(image_ids[i] for i in no_meas[:10])
            raise AdjustmentError(f"{len(no_meas)} images have no active measures and cannot be adjusted: {names}; "
                                  "remove them from the network or hold them")
        if len(diag.underdetermined_points) == self.n_points:
            raise AdjustmentError("every point has fewer than 2 measures: the network ties no images together")

    def add_result(self, measure_image: NDArray[np.int64], keep: NDArray[np.bool_], residuals: NDArray[np.float64],
                   accepted: NDArray[np.bool_]) -> None:
        """One block's measures (unit image index), which count in the RMS, their residuals (px), accepted."""
        sq = np.sum(residuals * residuals, axis=1)
        np.add.at(self.sq_image, measure_image[keep], sq[keep])  # in measure order, as rms_by_group's bincount
        self.keep_image += np.bincount(measure_image[keep], minlength=self.n_images)
        rk = residuals[keep]
        self.sums += np.sum(rk * rk, axis=0)
        self.kept += int(keep.sum())
        self.rejected += int((~accepted).sum())

    def rms(self) -> tuple[float, float, float]:
        """(RMS, sample RMS, line RMS) px of the kept measures (NaN without any)."""
        if not self.kept:
            return float("nan"), float("nan"), float("nan")
        s, n = self.sums, float(self.kept)
        return float(np.sqrt((s[0] + s[1]) / (2 * n))), float(np.sqrt(s[0] / n)), float(np.sqrt(s[1] / n))

    def rms_per_image(self) -> NDArray[np.float64]:
        with np.errstate(invalid="ignore", divide="ignore"):
            out: NDArray[np.float64] = np.sqrt(self.sq_image / (2.0 * self.keep_image))
        return out


@dataclass(frozen=True)
class StreamedUnitResult:
    """What :func:`~mercury_dem.adjust.unit.unit_summary` and :func:`~mercury_dem.adjust.report.text_report` read
    of an :class:`~mercury_dem.adjust.result.AdjustmentResult`, for a unit adjusted from its store: per image and
    per point at most, never per measure.
    """

    image_ids: tuple[str, ...]
    point_ids: NDArray[Any]
    rotations: NDArray[np.float64]
    positions: NDArray[np.float64]
    n_measures: int
    n_rejected: int
    rms_px: float
    rms_sample_px: float
    rms_line_px: float
    initial_rms_px: float
    sigma0: float
    underdetermined_points: NDArray[np.bool_]
    weak_images: NDArray[np.bool_]
    rms_per_image: NDArray[np.float64]
    accepted_per_image: NDArray[np.int64]
    diagnosis: Diagnosis
    iterations: int
    converged: bool
    reason: str
    log: tuple[dict[str, Any], ...]
    linear_method: str
    dof: int
    solve_seconds: float
    seconds: float
    posterior_seconds: float = 0.0

    @property
    def rejected(self) -> int:
        """The count (``unit_summary`` sums it)."""
        return self.n_rejected


@dataclass(frozen=True)
class StreamedProblemSize:
    """The sizes ``unit_summary`` reads of the problem."""

    n_images: int
    n_points: int
    n_measures: int
