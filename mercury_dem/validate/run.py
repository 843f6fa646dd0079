"""Accuracy of a run against the synthetic truth (pointing, points); used by reports and tests.

Only validation reads the mission's truth; the pipeline itself never does.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mercury_dem.mission import Mission
    from mercury_dem.network.model import ControlNetwork

from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.pose import angles_from_rotation, image_to_ground, project


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


def pointing_error_components_urad(rotations: NDArray[np.float64],
                                   true_rotations: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Error angles split in the camera frame: (cross-boresight angle, twist about the boresight), µrad.

    The cross-boresight part moves every pixel of the image by about angle / IFOV
    pixels; the twist turns the image about its centre and moves a pixel at r pixels
    from the centre by only twist · r pixels (0.05 px at the edge of a 256-pixel
    image for 400 µrad), so a network barely constrains it.
    """
    w = angles_from_rotation(np.matmul(rotations, np.swapaxes(true_rotations, -1, -2)))
    return np.hypot(w[..., 0], w[..., 1]) * 1e6, np.abs(w[..., 2]) * 1e6


def image_space_error_px(camera: Any, position: NDArray[np.float64], rotation: NDArray[np.float64],
                         true_position: NDArray[np.float64], true_rotation: NDArray[np.float64],
                         height: Any, per_side: int = 9, *, datum_radius_m: float) -> float:
    """RMS displacement (pixels of this image) of where a pose projects the true ground.

    A grid of ``per_side`` x ``per_side`` pixels is cast from the true pose onto the
    true surface (``height(lat, lon)`` in m) and projected back with the estimated
    ``position``/``rotation``. This is the pointing error in units of the image's own
    IFOV, with position errors and the twist weighed by what they do to the image —
    the figure a cartographer registers images by. NaN if no grid ray hits the body.
    """
    g = np.linspace(0.0, camera.samples - 1.0, per_side)
    h = np.linspace(0.0, camera.lines - 1.0, per_side)
    px = np.stack(np.meshgrid(g, h), axis=-1).reshape(-1, 2)
    ground, hit = image_to_ground(camera, true_position, true_rotation, px, height=height,
                                  datum_radius_m=datum_radius_m)
    if not np.any(hit):
        return float("nan")
    proj, _ = project(camera, position, rotation, ground[hit])
    return float(np.sqrt(np.mean(np.sum((proj - px[hit]) ** 2, axis=-1))))


def true_point_positions(network: ControlNetwork, mission: Mission, points: NDArray[np.int64]) -> NDArray[np.float64]:
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
    surface = mission.need_truth().surface()
    for img in np.unique(m_image[sel[ok]]):
        rows = np.flatnonzero(ok)[m_image[sel[ok]] == img]
        image_id = str(network.image_ids[img])
        c, r = mission.need_truth().true_pose(image_id)
        xyz, _ = image_to_ground(mission.camera(image_id), c, r, px[sel[rows]], height=surface.height,
                                 datum_radius_m=mission.body.datum_radius_m)
        out[rows] = xyz
    return out


def per_image_pointing(image_ids: list[str], rotations: NDArray[np.float64], mission: Mission,
                       positions: NDArray[np.float64] | None = None) -> dict[str, NDArray[Any]]:
    """Per image: pointing errors of the a-priori and the given (adjusted) attitudes against the truth.

    Arrays, one entry per image: ``a_priori_urad``/``adjusted_urad`` (total angle),
    ``adjusted_relative_urad`` (common rotation removed), the ``*_boresight_urad`` and
    ``*_twist_urad`` components, ``a_priori_px``/``adjusted_px`` (:func:`image_space_error_px`,
    the image's own pixels), ``ifov_urad`` and ``instrument``. ``positions`` are the
    solution's positions (default: the a-priori ones). The report's ``validation`` block
    and :func:`mercury_dem.viz.pointing_errors` are both built from this.
    """
    ids = [str(i) for i in image_ids]
    rotations = np.asarray(rotations, np.float64).reshape(-1, 3, 3)
    true_c = np.array([mission.need_truth().true_pose(i)[0] for i in ids]).reshape(-1, 3)
    true_r = np.array([mission.need_truth().true_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    apri_c = np.array([mission.a_priori_pose(i)[0] for i in ids]).reshape(-1, 3)
    apri_r = np.array([mission.a_priori_pose(i)[1] for i in ids]).reshape(-1, 3, 3)
    pos = apri_c if positions is None else np.asarray(positions, np.float64).reshape(-1, 3)
    cams = [mission.camera(i) for i in ids]
    adj_bore, adj_twist = pointing_error_components_urad(rotations, true_r)
    apr_bore, apr_twist = pointing_error_components_urad(apri_r, true_r)
    surface = mission.need_truth().surface()
    datum = mission.body.datum_radius_m
    catalog = getattr(mission, "catalog", None)
    if catalog is not None and {"image_id", "instrument"} <= set(catalog.columns):
        instrument_of = catalog.set_index("image_id")["instrument"]
        instruments = np.array([str(instrument_of.get(i, "")) for i in ids])
    else:  # a mission without a catalog table: the camera names
        instruments = np.array([str(getattr(c, "name", "")) for c in cams])
    return {
        "a_priori_urad": pointing_error_urad(apri_r, true_r),
        "adjusted_urad": pointing_error_urad(rotations, true_r),
        "adjusted_relative_urad": (common_rotation_removed_urad(rotations, true_r) if ids
                                   else np.zeros(0)),
        "a_priori_boresight_urad": apr_bore, "adjusted_boresight_urad": adj_bore,
        "a_priori_twist_urad": apr_twist, "adjusted_twist_urad": adj_twist,
        "a_priori_px": np.array([image_space_error_px(c, apri_c[k], apri_r[k], true_c[k], true_r[k],
                                                      surface.height, datum_radius_m=datum)
                                 for k, c in enumerate(cams)]),
        "adjusted_px": np.array([image_space_error_px(c, pos[k], rotations[k], true_c[k], true_r[k],
                                                      surface.height, datum_radius_m=datum)
                                 for k, c in enumerate(cams)]),
        "ifov_urad": np.array([c.ifov_rad for c in cams]) * 1e6,
        "instrument": instruments,
    }


def validate_run(network: ControlNetwork, image_ids: list[str], rotations: NDArray[np.float64], mission: Mission,
                 min_measures: NDArray[np.int64] | None = None,
                 positions: NDArray[np.float64] | None = None) -> dict[str, Any]:
    """The ``validation`` block of report.json: pointing (a-priori vs adjusted) and point errors.

    ``adjusted_rms_in_ifov`` is the RMS over images of :func:`image_space_error_px`
    (each image in its own pixels, i.e. its own IFOV). The angular figures in
    ``pointing_error_urad`` include the twist about the boresight, which the
    measures of a narrow image hardly see (see :func:`pointing_error_components_urad`);
    they are reported in full, split into ``boresight_*`` and ``twist_*``.
    ``positions`` are the solution's positions (default: the a-priori ones).
    """
    ids = [str(i) for i in image_ids]
    e = per_image_pointing(ids, rotations, mission, positions)
    adj_err, apr_err, rel_err = e["adjusted_urad"], e["a_priori_urad"], e["adjusted_relative_urad"]
    adj_bore, adj_twist = e["adjusted_boresight_urad"], e["adjusted_twist_urad"]
    apr_bore, apr_twist = e["a_priori_boresight_urad"], e["a_priori_twist_urad"]
    img_adj, img_apr, ifov, instruments = e["adjusted_px"], e["a_priori_px"], e["ifov_urad"], e["instrument"]
    well = np.ones(len(ids), bool) if min_measures is None else (min_measures >= 30)
    pts = np.flatnonzero(np.all(np.isfinite(network.adjusted_xyz), axis=1) & ~network.point_rejected)
    truth = true_point_positions(network, mission, pts)
    perr = np.linalg.norm(network.adjusted_xyz[pts] - truth, axis=1)
    perr = perr[np.isfinite(perr)]

    def rms(x: NDArray[np.float64]) -> float | None:
        x = x[np.isfinite(x)]
        return float(np.sqrt(np.mean(x**2))) if x.size else None

    by_instrument = {
        str(name): {"images": int((instruments == name).sum()),
                    "a_priori_rms": rms(img_apr[instruments == name]),
                    "adjusted_rms": rms(img_adj[instruments == name])}
        for name in np.unique(instruments)
    }
    return {
        "pointing_error_urad": {
            "a_priori_rms": rms(apr_err),
            "adjusted_rms": rms(adj_err),
            "adjusted_rms_common_rotation_removed": rms(rel_err),
            "adjusted_rms_images_with_30_measures": rms(adj_err[well]),
            "a_priori_boresight_rms": rms(apr_bore),
            "adjusted_boresight_rms": rms(adj_bore),
            "a_priori_twist_rms": rms(apr_twist),
            "adjusted_twist_rms": rms(adj_twist),
            "images": len(ids),
            "images_with_30_measures": int(well.sum()),
        },
        "image_space_error_px": {
            "a_priori_rms": rms(img_apr),
            "adjusted_rms": rms(img_adj),
            "adjusted_rms_images_with_30_measures": rms(img_adj[well]),
            "adjusted_max": float(np.nanmax(img_adj)) if np.isfinite(img_adj).any() else None,
            "by_instrument": by_instrument,
        },
        "ifov_urad": float(np.mean(ifov)) if ifov.size else None,
        "adjusted_rms_in_ifov": rms(img_adj),
        "point_error_m": {
            "median": float(np.median(perr)) if perr.size else None,
            "p95": float(np.percentile(perr, 95)) if perr.size else None,
            "points": int(perr.size),
        },
    }
