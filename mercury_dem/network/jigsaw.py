"""The pure parts of ``adjust-isis`` (an ISIS ``jigsaw`` for existing ISIS networks).

An ISIS network names its images by serial number; the cameras we are given have
keys (their ISIS serial number, a serial given by the user, their image id = file
stem). This module matches the two, cuts out the part of the network that can be
adjusted (measures of images with a camera, points with at least two of them),
and puts the adjustment's results back into the whole network, keeping its ids,
types and a-priori values. No files, no printing.

Rules (as ISIS ``jigsaw`` does them): ignored points and measures stay out of the
solve and keep their flags; ``jigsawRejected`` flags of the input are cleared before
the solve (every measure is judged again) and set by the outlier rejection; a point
that ends with fewer than two accepted measures is flagged ``jigsawRejected`` and
keeps its input adjusted coordinates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mercury_dem.exceptions import NetworkError
from mercury_dem.network.model import ControlNetwork


@dataclass(frozen=True)
class SerialMatch:
    """Network images matched to cameras.

    Attributes
    ----------
    camera_of_image : (K,) int, camera index of each network image (``network.image_ids``), -1 for none
    unmatched : serial numbers of the network with no camera, with their measure counts
    unused_cameras : indices of cameras no network serial number matched
    """

    camera_of_image: NDArray[np.int64]
    unmatched: dict[str, int]
    unused_cameras: tuple[int, ...]


def match_serials(network: ControlNetwork, camera_keys: Sequence[Sequence[str]]) -> SerialMatch:
    """Match every network image (serial number) to the camera that has it among its keys.

    ``camera_keys[c]`` are the names camera ``c`` answers to (serial numbers, image id).
    A key shared by two cameras is an error (:class:`NetworkError` naming both indices'
    keys) only when the network uses it.
    """
    owner: dict[str, int] = {}
    clash: dict[str, tuple[int, int]] = {}
    for c, keys in enumerate(camera_keys):
        for k in dict.fromkeys(str(x) for x in keys if x):
            if k in owner and owner[k] != c:
                clash[k] = (owner[k], c)
            owner.setdefault(k, c)
    ids = [str(s) for s in network.image_ids.tolist()]
    for s in ids:
        if s in clash:
            a, b = clash[s]
            raise NetworkError(f"serial number {s!r} is claimed by two cameras ({list(camera_keys[a])} and "
                               f"{list(camera_keys[b])}); give each image once")
    cam = np.array([owner.get(s, -1) for s in ids], np.int64)
    counts = np.bincount(network.measure_image, minlength=network.n_images)
    unmatched = {ids[k]: int(counts[k]) for k in np.flatnonzero(cam < 0)}
    used = set(cam[cam >= 0].tolist())
    return SerialMatch(cam, unmatched, tuple(c for c in range(len(camera_keys)) if c not in used))


@dataclass(frozen=True)
class JigsawCut:
    """The adjustable part of a network and where its rows come from.

    Attributes
    ----------
    network : the sub-network (images: the used cameras; jigsawRejected flags cleared)
    camera_index : (K',) camera index of each sub-network image
    measure_index : (M',) row of each sub-network measure in the whole network
    point_index : (N',) row of each sub-network point in the whole network
    """

    network: ControlNetwork
    camera_index: NDArray[np.int64]
    measure_index: NDArray[np.int64]
    point_index: NDArray[np.int64]


def cut_adjustable(network: ControlNetwork, camera_of_image: NDArray[np.int64], min_point_measures: int = 2) -> JigsawCut:
    """The measures of images with a camera, not ignored, on points that are not ignored
    and keep at least ``min_point_measures`` such measures.

    Raises NetworkError when nothing is left.
    """
    cam_m = camera_of_image[network.measure_image]
    ok = (cam_m >= 0) & ~network.measure_ignored & ~network.point_ignored[network.measure_point]
    per_point = np.bincount(network.measure_point[ok], minlength=network.n_points)
    ok &= per_point[network.measure_point] >= min_point_measures
    measure_index = np.flatnonzero(ok)
    if measure_index.size == 0:
        raise NetworkError("no measure is left to adjust: every measure belongs to an image without a camera, "
                           "is ignored, or is the only measure of its point")
    point_index, new_point = np.unique(network.measure_point[measure_index], return_inverse=True)
    cams, new_image = np.unique(cam_m[measure_index], return_inverse=True)
    n = network
    apcov = None if n.apriori_covariance is None else n.apriori_covariance[point_index]
    sub = ControlNetwork(
        image_ids=np.array([f"camera-{c}" for c in cams.tolist()]) if cams.size else np.zeros(0, "U1"),
        point_ids=n.point_ids[point_index],
        point_type=n.point_type[point_index],
        apriori_xyz=n.apriori_xyz[point_index],
        adjusted_xyz=n.adjusted_xyz[point_index],
        point_ignored=np.zeros(point_index.size, bool),
        point_rejected=np.zeros(point_index.size, bool),
        measure_point=new_point.ravel().astype(np.int64),
        measure_image=new_image.ravel().astype(np.int64),
        sample=n.sample[measure_index],
        line=n.line[measure_index],
        sigma=n.sigma[measure_index],
        measure_type=n.measure_type[measure_index],
        measure_ignored=np.zeros(measure_index.size, bool),
        measure_rejected=np.zeros(measure_index.size, bool),
        residuals=np.full((measure_index.size, 2), np.nan),
        apriori_pixels=n.apriori_pixels[measure_index],
        apriori_covariance=apcov,
        metadata=dict(n.metadata),
    )
    return JigsawCut(sub, cams.astype(np.int64), measure_index, point_index)


def merge_adjustment(network: ControlNetwork, cut: JigsawCut, adjusted: ControlNetwork,
                     min_point_measures: int = 2) -> ControlNetwork:
    """The whole network with the sub-network's adjustment written back.

    Measures in the solve get their residuals (pixels) and jigsawRejected flags; the
    others get NaN residuals and no jigsawRejected flag (ignored ones stay ignored).
    Points in the solve with at least ``min_point_measures`` accepted measures get the
    adjusted coordinates; the rest of them are flagged jigsawRejected and keep the
    input's adjusted coordinates. Ids, types, a-priori values and sigmas are kept.
    """
    m_rej = np.zeros(network.n_measures, bool)
    m_rej[cut.measure_index] = adjusted.measure_rejected
    res = np.full((network.n_measures, 2), np.nan)
    res[cut.measure_index] = adjusted.residuals
    accepted = np.bincount(adjusted.measure_point[~adjusted.measure_rejected], minlength=adjusted.n_points)
    good = (accepted >= min_point_measures) & np.all(np.isfinite(adjusted.adjusted_xyz), axis=1)
    xyz = np.array(network.adjusted_xyz, copy=True)
    xyz[cut.point_index[good]] = adjusted.adjusted_xyz[good]
    p_rej = np.zeros(network.n_points, bool)
    p_rej[cut.point_index[~good]] = True
    return network.replace(adjusted_xyz=xyz, residuals=res, measure_rejected=m_rej, point_rejected=p_rej)


def parse_serials_csv(text: str, source: str) -> list[tuple[str, str, int]]:
    """``file,serial`` lines -> (file, serial, line number); a header ``file,serial``, blank lines
    and ``#`` comments are skipped. A serial may contain commas only if the line is quoted CSV.

    Raises NetworkError naming ``source`` and the line for anything else.
    """
    import csv
    import io

    out: list[tuple[str, str, int]] = []
    for no, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        cells = [c.strip() for c in row]
        if not cells or not any(cells) or cells[0].startswith("#"):
            continue
        if no == 1 and [c.lower() for c in cells] == ["file", "serial"]:
            continue
        if len(cells) != 2 or not cells[0] or not cells[1]:
            raise NetworkError(f"{source} line {no}: expected 'file,serial' (two non-empty fields), got {row!r}")
        out.append((cells[0], cells[1], no))
    if not out:
        raise NetworkError(f"{source}: no 'file,serial' line")
    return out


def camera_keys_with_serials(
    image_ids: Sequence[str], own_serials: Sequence[str | None], given: Mapping[int, str],
) -> list[list[str]]:
    """The keys each camera answers to: the given serial (else its own), then its image id."""
    keys = []
    for k, (image_id, own) in enumerate(zip(image_ids, own_serials)):
        serial = given.get(k, own)
        keys.append([s for s in (serial, image_id) if s])
    return keys


__all__ = ["SerialMatch", "match_serials", "JigsawCut", "cut_adjustable", "merge_adjustment",
           "parse_serials_csv", "camera_keys_with_serials"]
