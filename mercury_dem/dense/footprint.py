"""Which pixels of a DEM grid a block of images sees, and the holes of DEM layers within that footprint.

The hole fraction of a DEM means something only against the ground it should cover: the pixels the block's
images see from at least two viewpoints (where a height can be measured at all). Counting holes against the
union of two DEMs' values (what the dense stage first did) makes the fallback layer's holes zero by construction
and says nothing about the ground no DEM reaches. Own code: a projection of the grid's pixel centres into each
image with :func:`mercury_dem.geometry.pose.project` and a bounds test; no library does this for a framing camera.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import latlon_to_xyz
from mercury_dem.geometry.pose import intersect_sphere, pixel_rays, project


def views_per_pixel(lat: NDArray[np.float64], lon: NDArray[np.float64], height_m: NDArray[np.float64],
                    images: Iterable[Any], datum_radius_m: float) -> NDArray[np.int32]:
    """How many of ``images`` see each pixel centre of the (lat, lon) grid at ``height_m`` (same shape as the
    grid; NaN heights are taken at the median finite height, or the datum).

    ``images`` are objects with ``camera``, ``position`` and ``rotation`` (body -> camera), e.g.
    :class:`mercury_dem.match.pretransform.ImageGeometry`; a pixel is seen when it projects in front of the
    camera inside the image's frame (pixel centres at 0 .. samples - 1, so edges at -0.5 and samples - 0.5).
    Occlusion by relief is not tested. Only the pixels within the image's traced footprint
    (its edge rays on the spheres of the heights' range, 5 % margin) are projected.
    Memory: a kd-tree and a few float64 arrays of the grid's size.
    """
    from scipy.spatial import cKDTree

    la, lo = np.meshgrid(np.asarray(lat, np.float64), np.asarray(lon, np.float64), indexing="ij")
    h = np.asarray(height_m, np.float64)
    fill = float(np.nanmedian(h)) if np.isfinite(h).any() else 0.0
    hh = np.where(np.isfinite(h), h, fill).ravel()
    xyz = latlon_to_xyz(la.ravel(), lo.ravel(), height_m=hh, datum_radius_m=datum_radius_m)
    unit = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
    # each image projects only the pixels near its footprint (blocks of many images); an unbalanced tree builds
    # faster and its queries here are few
    tree = cKDTree(unit, balanced_tree=False, compact_nodes=False)
    count = np.zeros(la.size, np.int32)
    heights = (float(hh.min()), float(hh.max()))
    for g in images:
        edge = _edge_directions(g, datum_radius_m, heights)
        if edge.shape[0] < 3:  # the image does not see the surface
            continue
        centre = edge.mean(axis=0)
        centre /= np.linalg.norm(centre)
        reach = float(np.linalg.norm(edge - centre, axis=1).max()) * 1.05 + 2e-3  # chord on the unit sphere
        near = np.asarray(tree.query_ball_point(centre, reach), dtype=np.int64)
        if near.size == 0:
            continue
        px, depth = project(g.camera, g.position, g.rotation, xyz[near])
        with np.errstate(invalid="ignore"):
            seen = ((depth > 0) & (px[:, 0] >= -0.5) & (px[:, 0] <= g.camera.samples - 0.5)
                    & (px[:, 1] >= -0.5) & (px[:, 1] <= g.camera.lines - 0.5))
        count[near[seen]] += 1
    return count.reshape(la.shape)


def _edge_directions(g: Any, datum_radius_m: float, heights: tuple[float, float]) -> NDArray[np.float64]:
    """Unit vectors of where the image's edge rays (and centre) meet the spheres of the lowest and highest height."""
    cam = g.camera
    px = np.concatenate([cam.edge_pixels(16), [[(cam.samples - 1) / 2.0, (cam.lines - 1) / 2.0]]])
    o, d = pixel_rays(cam, g.position, g.rotation, px)
    out = [intersect_sphere(o, d, datum_radius_m + h) for h in heights]
    pts = np.concatenate([p[hit] for p, hit in out])
    unit: NDArray[np.float64] = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    return unit


def hole_fractions(footprint: NDArray[np.bool_], layers: Mapping[str, NDArray[np.float64]]) -> dict[str, Any]:
    """Share of the ``footprint`` pixels without a finite value in each of ``layers`` (name -> grid), with the
    footprint's pixel count; None per layer when the footprint is empty.
    """
    n = int(np.count_nonzero(footprint))
    out: dict[str, Any] = {"footprint_pixels": n}
    for name, a in layers.items():
        out[name] = float(np.count_nonzero(footprint & ~np.isfinite(a)) / n) if n else None
    return out
