"""Image footprints on the body and the overlap graph of a set of images.

Footprints are traced from points along the image border (not only its corners)
intersected with the datum sphere. Everything is done with 3-D unit vectors, so
the 0/360 seam and the poles need no special case: candidate pairs come from a
kd-tree on the footprint centres (scipy.spatial.cKDTree on unit vectors), and
each candidate's overlap is measured by projecting a grid of one image's ground
points into the other image with the camera model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from mercury_dem.geometry.body import xyz_to_lat_lon
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import intersect_sphere, pixel_rays


def image_footprint(
    camera: FramingCamera,
    position: ArrayLike,
    rotation: ArrayLike,
    per_side: int = 8,
    *,
    radius_m: float,
) -> NDArray[np.float64]:
    """Unit vectors (4*per_side, 3) of the image border on the sphere, counter-clockwise in the image.

    A border ray that misses the body (the limb is in view) is replaced by the
    sphere point nearest to the ray, so the footprint is clipped at the limb.
    """
    px = camera.edge_pixels(per_side)
    o, d = pixel_rays(camera, position, rotation, px)
    pts, hit = intersect_sphere(o, d, radius_m)
    if not np.all(hit):
        t = np.maximum(-np.sum(o * d, axis=-1), 0.0)
        closest = o + t[:, None] * d
        pts = np.where(hit[:, None], pts, closest)
    out: NDArray[np.float64] = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    return out


def image_footprints(
    camera: FramingCamera,
    positions: ArrayLike,
    rotations: ArrayLike,
    per_side: int = 8,
    *,
    radius_m: float,
) -> NDArray[np.float64]:
    """Footprints (N, 4*per_side, 3) of N images taken with the same camera (batched :func:`image_footprint`)."""
    c = np.asarray(positions, dtype=np.float64)
    r = np.asarray(rotations, dtype=np.float64)
    v = camera.pixel_to_camera(camera.edge_pixels(per_side))  # (K, 3) camera frame
    d = np.matmul(v[None], r)  # (N, K, 3): R^T v for every image
    o = np.broadcast_to(c[:, None, :], d.shape)
    pts, hit = intersect_sphere(o, d, radius_m)
    if not np.all(hit):
        t = np.maximum(-np.sum(o * d, axis=-1), 0.0)
        pts = np.where(hit[..., None], pts, o + t[..., None] * d)
    out: NDArray[np.float64] = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    return out


def footprint_latlon(footprint: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Latitude and east longitude (degrees) of footprint vertices."""
    return xyz_to_lat_lon(footprint)


def _tangent_basis(c: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Orthonormal tangent vectors (P,3) x 2 at unit vectors c (P,3)."""
    helper = np.where(np.abs(c[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    e1 = np.cross(helper, c)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(c, e1)
    return e1, e2


def gnomonic(points: NDArray[np.float64], centre: NDArray[np.float64]) -> NDArray[np.float64]:
    """Gnomonic coordinates (P, K, 2) of unit vectors (P, K, 3) about unit centres (P, 3).

    Points on or beyond 90 deg from the centre cannot be projected; they are pulled
    to 89 deg (footprints here are far smaller than a hemisphere).
    """
    e1, e2 = _tangent_basis(centre)
    dot = np.einsum("pkj,pj->pk", points, centre)
    dot = np.maximum(dot, np.cos(np.radians(89.0)))
    x = np.einsum("pkj,pj->pk", points, e1) / dot
    y = np.einsum("pkj,pj->pk", points, e2) / dot
    return np.stack([x, y], axis=-1)


@dataclass(frozen=True)
class OverlapGraph:
    """Overlapping image pairs, i < j, as aligned arrays.

    Attributes
    ----------
    i, j : (P,) int64 indices into the list of footprints
    fraction : (P,) overlap area over the smaller footprint's area
    area_m2 : (P,) overlap area on the datum sphere (gnomonic approximation), m^2
    """

    i: NDArray[np.int64]
    j: NDArray[np.int64]
    fraction: NDArray[np.float64]
    area_m2: NDArray[np.float64]

    def __len__(self) -> int:
        return int(self.i.size)

    def neighbours(self, k: int) -> NDArray[np.int64]:
        """Indices of the images overlapping image ``k``."""
        return np.concatenate([self.j[self.i == k], self.i[self.j == k]])


def footprint_caps(footprints: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Centre unit vectors (N,3) and angular radii (N,) radians of footprints (N, K, 3)."""
    f = np.asarray(footprints, dtype=np.float64)
    c = f.sum(axis=1)
    c /= np.linalg.norm(c, axis=-1, keepdims=True)
    cosang = np.clip(np.einsum("nkj,nj->nk", f, c), -1.0, 1.0)
    return c, np.arccos(cosang.min(axis=1))


def footprint_area_m2(footprints: ArrayLike, radius_m: float) -> NDArray[np.float64]:
    """Areas (N,) of footprints (N, K, 3) on the sphere (shoelace on a gnomonic projection about each centre)."""
    f = np.asarray(footprints, dtype=np.float64)
    c, _ = footprint_caps(f)
    xy = gnomonic(f, c)
    x, y = xy[..., 0], xy[..., 1]
    a = 0.5 * np.abs(np.sum(x * np.roll(y, -1, axis=1) - np.roll(x, -1, axis=1) * y, axis=1))
    out: NDArray[np.float64] = a * radius_m**2
    return out


def _image_grid_ground(
    camera: FramingCamera, positions: NDArray[np.float64], rotations: NDArray[np.float64], n: int, radius_m: float
) -> NDArray[np.float64]:
    """Ground points (N, n*n, 3) of an n x n grid of pixel centres in each image (NaN off-body)."""
    s = (np.arange(n) + 0.5) * camera.samples / n - 0.5
    l = (np.arange(n) + 0.5) * camera.lines / n - 0.5
    px = np.stack(np.meshgrid(s, l), axis=-1).reshape(-1, 2)
    v = camera.pixel_to_camera(px)
    d = np.matmul(v[None], rotations)  # (N, K, 3): R^T v for every image
    o = np.broadcast_to(positions[:, None, :], d.shape)
    pts, _ = intersect_sphere(o, d, radius_m)
    return pts


def _seen_fraction(
    ground: NDArray[np.float64],
    cameras: list[FramingCamera],
    cam_idx: NDArray[np.int64],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Fraction of each row of ground points (P, S, 3) inside image k (on the body side facing it)."""
    valid = np.isfinite(ground[..., 0])
    g = np.where(valid[..., None], ground, 0.0)
    rel = g - positions[:, None, :]
    facing = (rel * g).sum(axis=-1) < 0
    v = np.matmul(rel, rotations.transpose(0, 2, 1))  # (P, S, 3) camera frame; matmul beats einsum here
    inside = np.zeros(valid.shape, dtype=bool)
    for c, cam in enumerate(cameras):
        rows = cam_idx == c
        if np.any(rows):
            with np.errstate(invalid="ignore"):
                px = cam.camera_to_pixel(v[rows])
                inside[rows] = cam.in_image(px)
    ok = valid & facing & inside
    n_valid = np.maximum(valid.sum(axis=1), 1)
    out: NDArray[np.float64] = ok.sum(axis=1) / n_valid
    return out


def overlap_graph(
    cameras: list[FramingCamera],
    camera_index: ArrayLike,
    positions: ArrayLike,
    rotations: ArrayLike,
    min_fraction: float = 0.0,
    samples_per_side: int = 8,
    footprint_per_side: int = 4,
    *,
    radius_m: float,
    chunk_pairs: int = 20000,
) -> OverlapGraph:
    """All pairs of images whose a-priori footprints overlap.

    Parameters
    ----------
    cameras : the distinct cameras
    camera_index : (N,) index into ``cameras`` of each image
    positions : (N, 3) body-fixed metres; rotations : (N, 3, 3) body -> camera
    min_fraction : keep pairs that overlap by at least this fraction of the smaller image
    samples_per_side : each image is sampled on an n x n grid of ground points

    Candidate pairs are those whose bounding caps intersect, found with a kd-tree
    on the cap centres (about N log N, not N^2; 3-D unit vectors, so the seam and
    the poles need nothing special). Each candidate's overlap fraction is the
    larger of "share of image i's ground grid seen inside image j" and the
    converse, i.e. the overlap relative to the smaller image, computed with the
    camera models themselves (vectorized over pairs in chunks). The area is that
    fraction times the smaller footprint's area.
    """
    cam_idx = np.asarray(camera_index, dtype=np.int64)
    pos = np.asarray(positions, dtype=np.float64)
    rot = np.asarray(rotations, dtype=np.float64)
    n = pos.shape[0]
    empty = OverlapGraph(np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
    if n < 2:
        return empty
    fps = np.empty((n, 4 * footprint_per_side, 3))
    grid = np.empty((n, samples_per_side**2, 3))
    for c, cam in enumerate(cameras):
        rows = cam_idx == c
        if np.any(rows):
            fps[rows] = image_footprints(cam, pos[rows], rot[rows], footprint_per_side, radius_m=radius_m)
            grid[rows] = _image_grid_ground(cam, pos[rows], rot[rows], samples_per_side, radius_m)
    area = footprint_area_m2(fps, radius_m)
    centre, ang = footprint_caps(fps)
    from scipy.spatial import cKDTree  # here, not at import: 'mercury-dem info' never builds the tree

    tree = cKDTree(centre)
    r = 2.0 * np.sin(np.minimum(np.pi, ang + float(ang.max())) / 2.0)
    cand = tree.query_ball_point(centre, r, return_sorted=False)
    counts = np.fromiter((len(c) for c in cand), dtype=np.int64, count=n)
    ii = np.repeat(np.arange(n), counts)
    jj = np.concatenate([np.asarray(c, dtype=np.int64) for c in cand]) if ii.size else ii
    keep = ii < jj
    ii, jj = ii[keep], jj[keep]
    sep = np.arccos(np.clip(np.sum(centre[ii] * centre[jj], axis=-1), -1.0, 1.0))
    keep = sep <= ang[ii] + ang[jj]
    ii, jj = ii[keep], jj[keep]
    frac = np.zeros(ii.size)
    for s0 in range(0, ii.size, chunk_pairs):
        a, b = ii[s0 : s0 + chunk_pairs], jj[s0 : s0 + chunk_pairs]
        f_ab = _seen_fraction(grid[a], cameras, cam_idx[b], pos[b], rot[b])
        f_ba = _seen_fraction(grid[b], cameras, cam_idx[a], pos[a], rot[a])
        frac[s0 : s0 + chunk_pairs] = np.maximum(f_ab, f_ba)
    keep = (frac > 0) & (frac >= min_fraction)
    ii, jj, frac = ii[keep], jj[keep], frac[keep]
    return OverlapGraph(i=ii, j=jj, fraction=frac, area_m2=frac * np.minimum(area[ii], area[jj]))
