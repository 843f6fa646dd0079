"""Network checks and statistics (the equivalent of ISIS ``cnetcheck``), vectorized.

Every check is a handful of array operations (sorts, bincounts, one
connected-components call), so a network of 10^7 measures is checked in
seconds (ISIS's per-point loops take hours to days there).
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from mercury_dem.network.model import ControlNetwork, MeasureType, PointType

#: How many example ids a report lists per problem.
N_EXAMPLES = 10


@dataclass(frozen=True)
class NetworkReport:
    """Result of :func:`validate`. ``ok`` is True when nothing is wrong.

    Problems (make ``ok`` False): dangling point/image indices, non-finite
    measure pixels, measures outside their image (when sizes are known),
    duplicate (point, image) pairs, duplicate point ids, more than one island.
    Warnings (reported only): points with fewer than 2 active measures, points
    without a-priori coordinates, images with too few measures or none.
    Counts of "active" measures exclude ignored/rejected measures and points.
    """

    n_images: int
    n_points: int
    n_measures: int
    n_active_measures: int
    n_dangling_point_refs: int
    n_dangling_image_refs: int
    n_nonfinite_measures: int
    n_outside_image: int | None
    outside_by_image: dict[str, int]
    n_duplicate_measures: int
    duplicate_examples: list[tuple[str, str]]
    n_duplicate_point_ids: int
    n_points_lt2: int
    points_lt2_examples: list[str]
    n_points_no_apriori: int
    min_image_measures: int
    images_few_measures: list[str]
    images_without_measures: list[str]
    islands: list[list[str]]
    point_types: dict[str, int]
    measure_types: dict[str, int]
    measures_per_point: dict[str, float]
    seconds: float = field(default=0.0, compare=False)

    @property
    def n_islands(self) -> int:
        return len(self.islands)

    @property
    def ok(self) -> bool:
        return not self.problems()

    def problems(self) -> list[str]:
        """One line per problem found (empty when the network is sound)."""
        out = []
        if self.n_dangling_point_refs or self.n_dangling_image_refs:
            out.append(f"{self.n_dangling_point_refs} measures point to no point, {self.n_dangling_image_refs} to no image")
        if self.n_nonfinite_measures:
            out.append(f"{self.n_nonfinite_measures} measures have a non-finite sample or line")
        if self.n_outside_image:
            out.append(f"{self.n_outside_image} measures lie outside their image")
        if self.n_duplicate_measures:
            out.append(f"{self.n_duplicate_measures} duplicate (point, image) measures, e.g. {self.duplicate_examples[:3]}")
        if self.n_duplicate_point_ids:
            out.append(f"{self.n_duplicate_point_ids} duplicate point ids")
        if self.n_islands > 1:
            sizes = [len(i) for i in self.islands]
            out.append(f"{self.n_islands} islands of images (sizes {sizes[:10]}{'...' if len(sizes) > 10 else ''})")
        return out

    def warnings(self) -> list[str]:
        out = []
        if self.n_points_lt2:
            out.append(f"{self.n_points_lt2} points have fewer than 2 active measures")
        if self.n_points_no_apriori:
            out.append(f"{self.n_points_no_apriori} points have no a-priori coordinates")
        if self.images_few_measures:
            out.append(f"{len(self.images_few_measures)} images have fewer than {self.min_image_measures} active measures")
        if self.images_without_measures:
            out.append(f"{len(self.images_without_measures)} images have no active measure")
        return out

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict; the largest island is given by its size only."""
        d = {k: v for k, v in self.__dict__.items() if k != "islands"}
        d["ok"] = self.ok
        d["n_islands"] = self.n_islands
        d["island_sizes"] = [len(i) for i in self.islands]
        d["islands_besides_largest"] = self.islands[1:]
        d["problems"] = self.problems()
        d["warnings"] = self.warnings()
        return d

    def summary(self) -> str:
        """A few human-readable lines."""
        lines = [
            f"{self.n_images} images, {self.n_points} points, {self.n_measures} measures "
            f"({self.n_active_measures} active), {self.n_islands} island(s); checked in {self.seconds:.2f} s",
            "measures per point: " + ", ".join(f"{k} {v:.3g}" for k, v in self.measures_per_point.items()),
            "point types: " + ", ".join(f"{k} {v}" for k, v in self.point_types.items()),
        ]
        lines += [f"PROBLEM: {p}" for p in self.problems()]
        lines += [f"warning: {w}" for w in self.warnings()]
        lines.append("OK" if self.ok else "NOT OK")
        return "\n".join(lines)


def _image_sizes(network: ControlNetwork, image_sizes: Any) -> NDArray[np.float64] | None:
    if image_sizes is None:
        return None
    if isinstance(image_sizes, Mapping):
        out = np.full((network.n_images, 2), np.nan)
        for i, iid in enumerate(network.image_ids.tolist()):
            if iid in image_sizes:
                out[i] = image_sizes[iid]
        return out
    arr = np.asarray(image_sizes, np.float64)
    if arr.shape != (network.n_images, 2):
        raise ValueError(f"image_sizes must have shape ({network.n_images}, 2) (samples, lines), got {arr.shape}")
    return arr


def validate(
    network: ControlNetwork,
    image_sizes: Mapping[str, tuple[int, int]] | ArrayLike | None = None,
    min_image_measures: int = 3,
) -> NetworkReport:
    """Check a network and gather its statistics.

    Parameters
    ----------
    network : the network
    image_sizes : optional (samples, lines) of each image: a mapping image id ->
        (samples, lines), or an array (K, 2); a measure is outside when its pixel
        lies beyond the image edges (-0.5 .. size - 0.5, 0-based centres)
    min_image_measures : images with fewer active measures are listed

    Returns
    -------
    NetworkReport
    """
    t0 = time.perf_counter()
    net = network
    n, k, m = net.n_points, net.n_images, net.n_measures
    mp, mi = net.measure_point, net.measure_image
    bad_p = (mp < 0) | (mp >= n)
    bad_i = (mi < 0) | (mi >= k)
    sound = ~(bad_p | bad_i)
    mp_ok = np.where(bad_p, 0, mp)
    mi_ok = np.where(bad_i, 0, mi)
    finite = np.isfinite(net.sample) & np.isfinite(net.line)
    n_nonfinite = int((~finite).sum())
    # outside the image
    sizes = _image_sizes(net, image_sizes)
    outside_by_image: dict[str, int] = {}
    n_outside = None
    if sizes is not None:
        sz = sizes[mi_ok]
        known = sound & finite & np.all(np.isfinite(sz), axis=1)
        out = known & (
            (net.sample < -0.5) | (net.line < -0.5) | (net.sample > sz[:, 0] - 0.5) | (net.line > sz[:, 1] - 0.5)
        )
        n_outside = int(out.sum())
        if n_outside:
            cnt = np.bincount(mi_ok[out], minlength=k)
            top = np.argsort(-cnt, kind="stable")[: N_EXAMPLES]
            outside_by_image = {str(net.image_ids[i]): int(cnt[i]) for i in top if cnt[i]}
    # active measures
    if n:
        bad_point = net.point_ignored | net.point_rejected
        active = sound & ~(net.measure_ignored | net.measure_rejected | bad_point[mp_ok])
    else:
        active = np.zeros(m, bool)
    # duplicate (point, image) pairs
    key = mp_ok[sound].astype(np.int64) * max(k, 1) + mi_ok[sound]
    key.sort()
    dup = key[1:] == key[:-1]
    n_dup = int(dup.sum())
    dup_examples = []
    if n_dup:
        ex = np.unique(key[1:][dup])[:N_EXAMPLES]
        dup_examples = [(str(net.point_ids[e // max(k, 1)]), str(net.image_ids[e % max(k, 1)])) for e in ex]
    # duplicate point ids
    ids_sorted = np.sort(net.point_ids)
    n_dup_ids = int((ids_sorted[1:] == ids_sorted[:-1]).sum()) if n > 1 else 0
    # points with < 2 active measures, without a-priori
    per_point = np.bincount(mp_ok[active], minlength=n)
    lt2 = np.flatnonzero(per_point < 2)
    no_apriori = int((~np.all(np.isfinite(net.apriori_xyz), axis=1)).sum())
    # images
    per_image = np.bincount(mi_ok[active], minlength=k)
    few = np.flatnonzero((per_image > 0) & (per_image < min_image_measures))
    none = np.flatnonzero(per_image == 0)
    # islands: images connected through points they share (active measures)
    islands: list[list[str]] = []
    used_images = np.flatnonzero(per_image > 0)
    if used_images.size:
        g = coo_matrix(
            (np.ones(int(active.sum()), np.int8), (mi_ok[active], k + mp_ok[active])), shape=(k + n, k + n)
        ).tocsr()
        _, labels = connected_components(g, directed=True, connection="weak")
        lab = labels[used_images]
        uniq, inv, counts = np.unique(lab, return_inverse=True, return_counts=True)
        order = np.argsort(-counts, kind="stable")
        members = np.argsort(inv.ravel(), kind="stable")
        bounds = np.concatenate([[0], np.cumsum(counts)])
        ids_used = net.image_ids[used_images]
        islands = [ids_used[members[bounds[j] : bounds[j + 1]]].tolist() for j in order]
    mpp = per_point if n else np.zeros(1)
    return NetworkReport(
        n_images=k,
        n_points=n,
        n_measures=m,
        n_active_measures=int(active.sum()),
        n_dangling_point_refs=int(bad_p.sum()),
        n_dangling_image_refs=int(bad_i.sum()),
        n_nonfinite_measures=n_nonfinite,
        n_outside_image=n_outside,
        outside_by_image=outside_by_image,
        n_duplicate_measures=n_dup,
        duplicate_examples=dup_examples,
        n_duplicate_point_ids=n_dup_ids,
        n_points_lt2=int(lt2.size),
        points_lt2_examples=[str(x) for x in net.point_ids[lt2[:N_EXAMPLES]]],
        n_points_no_apriori=no_apriori,
        min_image_measures=min_image_measures,
        images_few_measures=net.image_ids[few].tolist(),
        images_without_measures=net.image_ids[none].tolist(),
        islands=islands,
        point_types={t.name.lower(): int((net.point_type == t).sum()) for t in PointType},
        measure_types={t.name.lower(): int((net.measure_type == t).sum()) for t in MeasureType},
        measures_per_point={
            "min": float(mpp.min()), "median": float(np.median(mpp)), "mean": float(mpp.mean()), "max": float(mpp.max())
        },
        seconds=time.perf_counter() - t0,
    )


def singular_parts(merged_all: ControlNetwork, merged: ControlNetwork, limit: int = 20) -> dict[str, Any]:
    """What a unit's merged network holds that the adjustment cannot determine, by name.

    ``images_without_measures``: images of the children's networks with no measure (left out of the
    adjustment: they keep their a-priori pointing unless another unit adjusts them);
    ``single_measure_points``: ids (the first ``limit``) and count of points seen by one image only
    (left unadjusted: one ray fixes no position). ``merged_all`` is the merge, ``merged`` the same
    without the images that have no measure.
    """
    dropped = sorted(set(map(str, merged_all.image_ids)) - set(map(str, merged.image_ids)))
    per_point = merged.measures_per_point()
    single = np.flatnonzero(per_point == 1)
    ids = [p.item() if hasattr(p, "item") else p for p in merged.point_ids[single[:limit]]]  # JSON-able
    return {
        "images_without_measures": dropped,
        "single_measure_points": {"count": int(single.size), "ids": ids},
    }
