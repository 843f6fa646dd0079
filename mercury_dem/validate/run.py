"""Accuracy of a run against the synthetic truth (pointing, points); used by reports and tests.

Only validation reads the mission's truth; the pipeline itself never does.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.pose import angles_from_rotation, image_to_ground


def pointing_error_urad(rotations: NDArray[np.float64], true_rotations: NDArray[np.float64]) -> NDArray[np.float64]:
    """Angle (µrad) of the rotation between estimated and true camera attitudes, per image."""
    d = np.matmul(rotations, np.swapaxes(true_rotations, -1, -2))
    return np.linalg.norm(angles_from_rotation(d), axis=-1) * 1e6


def common_rotation_removed_urad(rotations: NDArray[np.float64], true_rotations: NDArray[np.float64]) -> NDArray[np.float64]:
    """Pointing errors after removing the mean error rotation of the block.

    Without ground control a network may turn as a whole by a small common angle
    (a datum defect held only by the a-priori pointing constraints); this shows the
    relative pointing error with that common part removed.
    """
    d = np.matmul(rotations, np.swapaxes(true_rotations, -1, -2))
    w = angles_from_rotation(d)
    return np.linalg.norm(w - w.mean(axis=0), axis=-1) * 1e6


def true_point_positions(network: Any, mission: Any, points: NDArray[np.int64]) -> NDArray[np.float64]:
    """True body-fixed position of points: the first active measure's pixel through the true pose onto the true surface."""
    active = network.active_measures() if hasattr(network, "active_measures") else ~network.measure_rejected
    m_point, m_image = network.measure_point[active], network.measure_image[active]
    px = np.stack([network.sample[active], network.line[active]], axis=-1)
    order = np.argsort(m_point, kind="stable")
    first = order[np.r_[True, m_point[order][1:] != m_point[order][:-1]]] if order.size else order
    first_of = np.full(network.n_points, -1, dtype=np.int64)
    first_of[m_point[first]] = first
    out = np.full((points.size, 3), np.nan)
    sel = first_of[points]
    ok = sel >= 0
    surface = mission.surface()
    for img in np.unique(m_image[sel[ok]]):
        rows = np.flatnonzero(ok)[m_image[sel[ok]] == img]
        image_id = str(network.image_ids[img])
        c, r = mission.true_pose(image_id)
        xyz, _ = image_to_ground(mission.camera(image_id), c, r, px[sel[rows]], height=surface.height)
        out[rows] = xyz
    return out


def validate_run(network: Any, image_ids: list[str], rotations: NDArray[np.float64], mission: Any,
                 min_measures: NDArray[np.int64] | None = None) -> dict[str, Any]:
    """The ``validation`` block of report.json: pointing (a-priori vs adjusted) and point errors."""
    ids = [str(i) for i in image_ids]
    true_r = np.array([mission.true_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    apri_r = np.array([mission.a_priori_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    ifov = np.array([mission.camera(i).ifov_rad for i in ids]) * 1e6
    adj_err = pointing_error_urad(rotations, true_r)
    apr_err = pointing_error_urad(apri_r, true_r)
    rel_err = common_rotation_removed_urad(rotations, true_r)
    well = np.ones(len(ids), bool) if min_measures is None else (min_measures >= 30)
    pts = np.flatnonzero(np.all(np.isfinite(network.adjusted_xyz), axis=1) & ~network.point_rejected)
    truth = true_point_positions(network, mission, pts)
    perr = np.linalg.norm(network.adjusted_xyz[pts] - truth, axis=1)
    perr = perr[np.isfinite(perr)]

    def rms(x: NDArray[np.float64]) -> float | None:
        return float(np.sqrt(np.mean(x**2))) if x.size else None

    return {
        "pointing_error_urad": {
            "a_priori_rms": rms(apr_err),
            "adjusted_rms": rms(adj_err),
            "adjusted_rms_common_rotation_removed": rms(rel_err),
            "adjusted_rms_images_with_30_measures": rms(adj_err[well]),
            "images": len(ids),
            "images_with_30_measures": int(well.sum()),
        },
        "ifov_urad": float(np.mean(ifov)) if ifov.size else None,
        "adjusted_rms_in_ifov": (rms(adj_err) / float(np.mean(ifov))) if ifov.size else None,
        "point_error_m": {
            "median": float(np.median(perr)) if perr.size else None,
            "p95": float(np.percentile(perr, 95)) if perr.size else None,
            "points": int(perr.size),
        },
    }
