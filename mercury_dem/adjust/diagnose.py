"""Pre-solve diagnosis of a network: islands and under-determined images and points.

A bundle adjustment of a network made of disconnected parts (islands) is
singular up to the priors: each part can move on its own. Images without
measures and points measured once carry no geometric information. These are
found before solving and reported by id, so an unsolvable system is a clear
:class:`~mercury_dem.exceptions.AdjustmentError`, never a ``LinAlgError``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray
from scipy.sparse.csgraph import connected_components

from mercury_dem.adjust.problem import AdjustmentProblem
from mercury_dem.exceptions import AdjustmentError


@dataclass(frozen=True)
class Diagnosis:
    """What :func:`diagnose` found (indices into the problem's images and points).

    Attributes
    ----------
    islands : tuple of int arrays, images of each connected component with measures, largest first
    images_without_measures : image indices with no measure at all
    weak_images : image indices with fewer than ``min_image_measures`` measures (but some)
    underdetermined_points : point indices with fewer than ``min_point_measures`` measures
    """

    islands: tuple[NDArray[np.int64], ...]
    images_without_measures: NDArray[np.int64]
    weak_images: NDArray[np.int64]
    underdetermined_points: NDArray[np.int64]

    def summary(self) -> dict[str, int]:
        return {
            "islands": len(self.islands),
            "images_without_measures": len(self.images_without_measures),
            "weak_images": len(self.weak_images),
            "underdetermined_points": len(self.underdetermined_points),
        }


def _names(idx: NDArray[np.int64], ids: object, limit: int = 10) -> str:
    shown = ", ".join(str(ids[i]) for i in idx[:limit])  # type: ignore[index]
    return shown + (f" and {len(idx) - limit} more" if len(idx) > limit else "")


def diagnose(problem: AdjustmentProblem, min_point_measures: int = 2, min_image_measures: int = 3) -> Diagnosis:
    """Islands of the image graph (images linked by shared points) and under-determined unknowns.

    The graph is bipartite (images and points as nodes, measures as edges), so
    connected components cost O(M) with ``scipy.sparse.csgraph``.
    """
    n_img, n_pt = problem.n_images, problem.n_points
    img, pt = problem.measure_image, problem.measure_point
    graph = sp.coo_matrix((np.ones(len(img)), (img, n_img + pt)), shape=(n_img + n_pt, n_img + n_pt))
    _, labels = connected_components(graph, directed=False)
    per_image = np.bincount(img, minlength=n_img)
    per_point = np.bincount(pt, minlength=n_pt)
    has = per_image > 0
    lab = labels[:n_img]
    islands: list[NDArray[np.int64]] = []
    if has.any():
        ulab, inv = np.unique(lab[has], return_inverse=True)
        members = np.flatnonzero(has)
        order = np.argsort(inv, kind="stable")
        splits = np.cumsum(np.bincount(inv))[:-1]
        islands = sorted(np.split(members[order], splits), key=len, reverse=True)
    return Diagnosis(
        islands=tuple(islands),
        images_without_measures=np.flatnonzero(~has),
        weak_images=np.flatnonzero(has & (per_image < min_image_measures)),
        underdetermined_points=np.flatnonzero(per_point < min_point_measures),
    )


def check_solvable(
    problem: AdjustmentProblem, diagnosis: Diagnosis, held_images: NDArray[np.bool_], allow_islands: bool = False
) -> None:
    """Raise :class:`AdjustmentError` naming the images/points that make the network unsolvable."""
    ids = problem.image_ids
    no_meas = diagnosis.images_without_measures[~held_images[diagnosis.images_without_measures]]
    if len(no_meas):
        raise AdjustmentError(
            f"{len(no_meas)} images have no measures and cannot be adjusted: {_names(no_meas, ids)}; "
            "remove them from the network or hold them"
        )
    if len(diagnosis.islands) > 1 and not allow_islands:
        small = diagnosis.islands[1:]
        desc = "; ".join(f"[{_names(isl, ids, 5)}]" for isl in small[:5])
        raise AdjustmentError(
            f"the image network has {len(diagnosis.islands)} islands (disconnected groups; the largest has "
            f"{len(diagnosis.islands[0])} images). Smaller islands: {desc}"
            f"{' ...' if len(small) > 5 else ''}. Add tie points between them, adjust them separately, "
            "or set adjust.allow_islands"
        )
    if len(diagnosis.underdetermined_points) == problem.n_points:
        raise AdjustmentError(
            f"every point has fewer than 2 measures (e.g. points {_names(diagnosis.underdetermined_points, problem.point_ids)}): "
            "the network ties no images together"
        )
