"""How many images see each point of a lat/lon grid, and with what stereo convergence.

Points on the datum sphere are projected into every image with its pose (the
a-priori one unless told otherwise); a point is seen when it falls inside the
image, in front of the camera and on the visible hemisphere. The stereo
convergence of a point is the largest angle between two of the view directions
that see it. Used by ``mercury-dem info`` and the tests of the presets.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import DATUM_RADIUS_M, latlon_to_xyz
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import project


def grid_points(
    step_deg: float, bounds: tuple[float, float, float, float] | None = None
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Cell-centre latitudes and longitudes (2-D, ij) of a lat/lon grid over ``bounds`` (whole body if None)."""
    la0, la1, lo0, lo1 = bounds if bounds is not None else (-90.0, 90.0, 0.0, 360.0)
    lat = np.arange(la0 + step_deg / 2, la1, step_deg)
    lon = np.arange(lo0 + step_deg / 2, lo1, step_deg)
    return np.meshgrid(lat, lon, indexing="ij")


def coverage(
    cameras: Sequence[FramingCamera],
    positions: NDArray[np.float64],
    rotations: NDArray[np.float64],
    lat: NDArray[np.float64],
    lon: NDArray[np.float64],
    radius_m: float = DATUM_RADIUS_M,
) -> tuple[NDArray[np.int64], NDArray[np.float64], list[NDArray[np.int64]]]:
    """Images seeing each point.

    Returns
    -------
    count : (same shape as lat) number of images seeing the point
    convergence_deg : largest angle between two view directions of the point (0 when < 2 views)
    seen_by : per image, the flat indices of the points it sees
    """
    pts = latlon_to_xyz(lat.ravel(), lon.ravel(), 0.0, radius_m)
    normal = pts / radius_m
    n_pts = pts.shape[0]
    count = np.zeros(n_pts, np.int64)
    seen_by: list[NDArray[np.int64]] = []
    rows: list[NDArray[np.int64]] = []
    views: list[NDArray[np.float64]] = []
    for cam, c, r in zip(cameras, positions, rotations):
        # Cheap cull: only points within the angular reach of the image.
        to_cam = c - pts
        dist = np.linalg.norm(to_cam, axis=-1)
        facing = np.sum(to_cam * normal, axis=-1) > 0
        idx = np.flatnonzero(facing)
        px, depth = project(cam, c, r, pts[idx])
        ok = (depth > 0) & cam.in_image(px)
        idx = idx[ok]
        seen_by.append(idx)
        count[idx] += 1
        rows.append(idx)
        views.append(to_cam[idx] / dist[idx, None])
    conv = np.zeros(n_pts)
    if rows:
        pid = np.concatenate(rows)
        v = np.concatenate(views)
        order = np.argsort(pid, kind="stable")
        pid, v = pid[order], v[order]
        for off in range(1, int(count.max(initial=0))):
            same = pid[off:] == pid[:-off]
            if not same.any():
                break
            a, b = v[:-off][same], v[off:][same]
            ang = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))
            np.maximum.at(conv, pid[:-off][same], ang)
    return count.reshape(lat.shape), conv.reshape(lat.shape), seen_by


def mission_coverage(
    mission: Mission, step_deg: float = 1.0, bounds: tuple[float, float, float, float] | None = None
) -> dict[str, NDArray[Any]]:
    """Coverage of a mission (a-priori poses) on a lat/lon grid: lat, lon, count, convergence_deg."""
    lat, lon = grid_points(step_deg, bounds)
    ids = mission.image_ids
    cams = [mission.camera(i) for i in ids]
    pos, rot = mission.a_priori_poses()
    count, conv, _ = coverage(cams, pos, rot, lat, np.mod(lon, 360.0), mission.body.datum_radius_m)
    return {"lat": lat, "lon": lon, "count": count, "convergence_deg": conv}
