"""True accuracy of matches against the synthetic truth (issue 4, section 4).

The true error of an accepted match: the ground point seen at the reference
measure (true pose of the reference, true surface) is projected into the match
image with its true pose and compared with the match measure, in match pixels.
Pairs are classed by illumination (incidence and sun-azimuth difference) and
scale ratio, and each class gets its outlier share, median and 95th percentile
error, and the share of truly overlapping pairs that gave enough matches.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.geometry.body import MERCURY
from mercury_dem.geometry.camera import FramingCamera
from mercury_dem.geometry.pose import image_to_ground, project

#: The datum of the scenes :func:`standard_pairs` and :func:`convergent_views` build: Mercury's, as the MDIS
#: cameras they fly (a scene of its own, not a default: the functions that measure errors take the datum).
SCENE_DATUM_RADIUS_M = MERCURY.datum_radius_m

HeightFunction = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


@dataclass(frozen=True)
class TruePose:
    """The true geometry of one image."""

    camera: FramingCamera
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]


def true_errors(
    image_ids: Sequence[str],
    image_a: NDArray[np.int64],
    image_b: NDArray[np.int64],
    points_a: NDArray[np.float64],
    points_b: NDArray[np.float64],
    truth: Mapping[str, TruePose],
    height: HeightFunction,
    *,
    datum_radius_m: float,
) -> NDArray[np.float64]:
    """True error (M,) in match pixels of every match; NaN where the reference ray misses the surface.

    Parameters
    ----------
    image_ids : ids indexed by ``image_a``/``image_b``
    image_a, image_b : ndarray (M,) int, reference and match image of each match
    points_a, points_b : ndarray (M, 2), 0-based (sample, line) in the original images
    truth : image id -> true camera and pose
    height : the true surface height (lat, lon) -> m above the datum
    datum_radius_m : the body's datum sphere (m), which ``height`` is measured from
    """
    ia = np.asarray(image_a, np.int64)
    ib = np.asarray(image_b, np.int64)
    out = np.full(ia.shape[0], np.nan)
    if ia.size == 0:
        return out
    keys = ia * (len(image_ids) + 1) + ib
    for key in np.unique(keys):
        sel = np.flatnonzero(keys == key)
        ta, tb = truth[image_ids[ia[sel[0]]]], truth[image_ids[ib[sel[0]]]]
        g, hit = image_to_ground(ta.camera, ta.position, ta.rotation, points_a[sel], height=height,
                                 datum_radius_m=datum_radius_m)
        px, depth = project(tb.camera, tb.position, tb.rotation, np.where(hit[:, None], g, 0.0))
        err = np.linalg.norm(px - points_b[sel], axis=-1)
        out[sel] = np.where(hit & (depth > 0), err, np.nan)
    return out


def true_error_components(
    image_ids: Sequence[str],
    image_a: NDArray[np.int64],
    image_b: NDArray[np.int64],
    points_a: NDArray[np.float64],
    points_b: NDArray[np.float64],
    truth: Mapping[str, TruePose],
    height: HeightFunction,
    step_m: float = 100.0,
    *,
    datum_radius_m: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The true error of every match split along and across the epipolar line, in match pixels.

    The reference measure fixes a ray; every point of that ray projects onto the epipolar
    line in the match image. An error **along** it is what a different height on the
    reference ray gives: a bundle adjustment absorbs it into the point's height (it sets
    the DEM's resolution, it cannot bend the pointing). Only the error **across** it
    contradicts the geometry, so only that part can pull an image's pointing. An
    area-based matcher measures the parallax of its window's surface, not of the
    keypoint's own height, so between convergent views its error is mostly along the
    line (issue 21; ``docs/benchmarks/match.md``).

    Parameters
    ----------
    image_ids, image_a, image_b, points_a, points_b, truth, height : as :func:`true_errors`
    step_m : height step along the reference ray that gives the epipolar direction, metres

    Returns
    -------
    along, across : ndarray (M,), signed along-line and absolute across-line errors
        (``hypot(along, across)`` is :func:`true_errors`); NaN where the reference ray
        misses the surface; where both views share one viewpoint (no epipolar line) the
        whole error counts as across
    """
    ia = np.asarray(image_a, np.int64)
    ib = np.asarray(image_b, np.int64)
    along = np.full(ia.shape[0], np.nan)
    across = np.full(ia.shape[0], np.nan)
    if ia.size == 0:
        return along, across
    keys = ia * (len(image_ids) + 1) + ib
    for key in np.unique(keys):
        sel = np.flatnonzero(keys == key)
        ta, tb = truth[image_ids[ia[sel[0]]]], truth[image_ids[ib[sel[0]]]]
        g, hit = image_to_ground(ta.camera, ta.position, ta.rotation, points_a[sel], height=height,
                                 datum_radius_m=datum_radius_m)
        g = np.where(hit[:, None], g, 0.0)
        ray = g - ta.position
        ray /= np.maximum(np.linalg.norm(ray, axis=1, keepdims=True), 1e-12)
        up = g / np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
        # the point one step higher on the same reference ray
        g2 = g - ray * (step_m / np.maximum(np.abs(np.sum(ray * up, axis=1)), 1e-6))[:, None]
        px, depth = project(tb.camera, tb.position, tb.rotation, g)
        px2, _ = project(tb.camera, tb.position, tb.rotation, g2)
        d = px2 - px
        n = np.linalg.norm(d, axis=1)
        ok = hit & (depth > 0)
        line = n > 1e-9  # identical viewpoints: no epipolar line, no height explains any error
        u = d / np.maximum(n, 1e-12)[:, None]
        e = np.asarray(points_b, np.float64)[sel] - px
        along[sel] = np.where(ok, np.where(line, np.sum(e * u, axis=1), 0.0), np.nan)
        across[sel] = np.where(ok, np.where(line, np.abs(e[:, 0] * u[:, 1] - e[:, 1] * u[:, 0]),
                                            np.linalg.norm(e, axis=1)), np.nan)
    return along, across


def true_overlap(a: TruePose, b: TruePose, height: HeightFunction, grid: int = 16, *,
                 datum_radius_m: float) -> float:
    """Overlap of two images as a fraction of the smaller one (0..1), on the true surface.

    The share of each image's grid whose ground point the other image sees; the
    larger share is intersection / smaller area.
    """

    def share(p: TruePose, q: TruePose) -> float:
        t = (np.arange(grid) + 0.5) / grid
        ss, ll = np.meshgrid(t * p.camera.samples - 0.5, t * p.camera.lines - 0.5)
        px = np.stack([ss.ravel(), ll.ravel()], -1)
        g, hit = image_to_ground(p.camera, p.position, p.rotation, px, height=height, datum_radius_m=datum_radius_m)
        if not hit.any():
            return 0.0
        proj, depth = project(q.camera, q.position, q.rotation, g[hit])
        inside = (depth > 0) & q.camera.in_image(np.nan_to_num(proj, nan=-1e9))
        return float(inside.sum()) / float(px.shape[0])

    return max(share(a, b), share(b, a))


def illumination_class(incidence_difference_deg: float, sun_azimuth_difference_deg: float) -> str:
    """'similar' (incidence within 15 deg and sun azimuth within 30 deg), 'incidence'
    (incidence differs more, sun on the same side) or 'azimuth' (sun azimuth differs more than 30 deg).
    """
    if sun_azimuth_difference_deg > 30.0:
        return "azimuth"
    if incidence_difference_deg > 15.0:
        return "incidence"
    return "similar"


def scale_class(scale_ratio: float) -> str:
    """'<=1.5x', '1.5-4x' or '>4x'."""
    if scale_ratio <= 1.5:
        return "<=1.5x"
    return "1.5-4x" if scale_ratio <= 4.0 + 1e-6 else ">4x"


def summarize(
    errors: NDArray[np.float64],
    pair: NDArray[np.int64],
    rows: Sequence[Mapping[str, Any]],
    overlaps: Sequence[float],
    min_matches: int = 20,
    outlier_px: float = 2.0,
    min_overlap: float = 0.10,
) -> dict[str, dict[str, float]]:
    """Accuracy per pair class and overall.

    Parameters
    ----------
    errors : ndarray (M,), true error of each match (``true_errors``)
    pair : ndarray (M,), report row of each match
    rows : pair report rows (``PairReport.as_row()``), with incidence/azimuth difference and scale ratio
    overlaps : true overlap of each pair (fraction of the smaller image)

    Returns
    -------
    dict: class name ('all', 'similar', 'incidence', 'azimuth', 'scale <=1.5x', ...) ->
        n_pairs, n_overlapping (true overlap >= ``min_overlap``), share_with_min_matches (of those),
        n_measures, outlier_share (> ``outlier_px``), median_px, p95_px (in the match image's
        pixels), median_coarse_px, p95_coarse_px (in pixels of the coarser image of each pair:
        where the match image is s times finer the error is divided by s -- a correspondence
        cannot be more precise than the coarser image allows, and a finer image's measure of
        s x 0.2 px is the same ground error as the coarser one's 0.2 px; rows without
        ``match_px_per_ref_px`` count as scale 1)
    """
    err = np.asarray(errors, np.float64)
    pair = np.asarray(pair, np.int64)
    counts = np.bincount(pair, minlength=len(rows)) if pair.size else np.zeros(len(rows), np.int64)
    finer = np.array([max(1.0, float(r.get("match_px_per_ref_px", 1.0))) if np.isfinite(r.get("match_px_per_ref_px", 1.0))
                      else 1.0 for r in rows] + [1.0])
    err_coarse = err / finer[np.where((pair >= 0) & (pair < len(rows)), pair, len(rows))] if err.size else err
    cls_illum = [illumination_class(r["incidence_difference_deg"], r["sun_azimuth_difference_deg"]) for r in rows]
    cls_scale = ["scale " + scale_class(r["scale_ratio"]) for r in rows]
    groups: dict[str, list[int]] = {"all": list(range(len(rows)))}
    for k, (ci, cs) in enumerate(zip(cls_illum, cls_scale)):
        groups.setdefault(ci, []).append(k)
        groups.setdefault(cs, []).append(k)
    out: dict[str, dict[str, float]] = {}
    for name, members in groups.items():
        m = np.asarray(members, np.int64)
        in_group = np.isin(pair, m)
        e = err[in_group]
        ec = err_coarse[in_group]
        ec = ec[np.isfinite(ec)]
        e = e[np.isfinite(e)]
        ov = np.asarray(overlaps, np.float64)[m] >= min_overlap
        n_ov = int(ov.sum())
        ok = counts[m][ov] >= min_matches
        out[name] = {
            "n_pairs": float(m.size),
            "n_overlapping": float(n_ov),
            "share_with_min_matches": float(ok.mean()) if n_ov else float("nan"),
            "n_measures": float(e.size),
            "outlier_share": float(np.mean(e > outlier_px)) if e.size else float("nan"),
            "median_px": float(np.median(e)) if e.size else float("nan"),
            "p95_px": float(np.percentile(e, 95)) if e.size else float("nan"),
            "median_coarse_px": float(np.median(ec)) if ec.size else float("nan"),
            "p95_coarse_px": float(np.percentile(ec, 95)) if ec.size else float("nan"),
        }
    return out


def format_summary(summary: Mapping[str, Mapping[str, float]]) -> str:
    """A Markdown table of :func:`summarize` output."""
    lines = [
        "| class | pairs | overlapping | with >= min matches | measures | outliers > 2 px | median px | p95 px "
        "| median coarser-image px | p95 coarser-image px |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in summary.items():
        lines.append(
            f"| {name} | {s['n_pairs']:.0f} | {s['n_overlapping']:.0f} | {100 * s['share_with_min_matches']:.0f}% "
            f"| {s['n_measures']:.0f} | {100 * s['outlier_share']:.2f}% | {s['median_px']:.3f} | {s['p95_px']:.3f} "
            f"| {s.get('median_coarse_px', float('nan')):.3f} | {s.get('p95_coarse_px', float('nan')):.3f} |"
        )
    return "\n".join(lines)


# --------------------------------------------------------------------------- standard pair scenes
@dataclass(frozen=True)
class SceneView:
    """A true view: camera, pose and sun (body-fixed metres)."""

    camera: FramingCamera
    position: NDArray[np.float64]
    rotation: NDArray[np.float64]
    sun: NDArray[np.float64]


@dataclass(frozen=True)
class ScenePair:
    """A pair of true views with the class it is meant to test."""

    name: str
    ref: SceneView
    match: SceneView


def standard_pairs(
    camera: FramingCamera, lat_deg: float = 5.0, lon_deg: float = 3.0, altitude_m: float | None = None
) -> list[ScenePair]:
    """The pair classes of issue 4, section 4, around one site (true geometry only; render them yourself).

    ``altitude_m`` defaults to about 1.8 km/pixel for a 256-pixel WAC (scaled by
    the camera's IFOV). Similar illumination: a stereo pair, 2x scale with 30 deg
    rotation, 4x finer and 4x coarser with rotation; incidence 30 deg vs 70 deg
    with the sun on the same side at 1x, 2x coarser and 2x finer (rotated) and 4x;
    sun azimuth 45 and 90 deg apart.
    """
    from mercury_dem.geometry.body import latlon_to_unit, latlon_to_xyz
    from mercury_dem.geometry.pose import look_at_rotation, rotation_from_angles

    alt = altitude_m if altitude_m is not None else 1.79e3 / camera.ifov_rad
    up = latlon_to_unit(lat_deg, lon_deg)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    centre = latlon_to_xyz(lat_deg, lon_deg, 0.0, SCENE_DATUM_RADIUS_M)
    k = alt / 2500e3

    def sun(inc: float, az: float) -> NDArray[np.float64]:
        i, a = np.radians(inc), np.radians(az)
        return centre + 5.8e10 * (np.cos(i) * up + np.sin(i) * (np.sin(a) * east + np.cos(a) * north))

    def view(h: float, inc: float, az: float, de: float = 0.0, dn: float = 0.0, twist: float = 0.0,
             ae: float = 0.0, an: float = 0.0) -> SceneView:
        c = centre + h * k * up + de * k * east + dn * k * north
        r = look_at_rotation(c, centre + ae * k * east + an * k * north, north)
        r = rotation_from_angles(np.array([0.0, 0.0, np.radians(twist)])) @ r
        return SceneView(camera, c, r, sun(inc, az))

    ref = view(2500e3, 50, 90)
    ref30 = view(2500e3, 30, 90, de=100e3)
    return [
        ScenePair("stereo", ref, view(2500e3, 52, 95, de=400e3, ae=20e3)),
        ScenePair("scale2_rot30", ref, view(5000e3, 45, 80, dn=-300e3, twist=30)),
        ScenePair("scale2_finer_rot45", ref, view(1250e3, 48, 92, de=-100e3, twist=45)),
        ScenePair("scale4_finer", ref, view(625e3, 50, 90, dn=50e3, an=40e3, twist=-60)),
        ScenePair("scale4_coarser", ref, view(10000e3, 48, 92, de=-500e3, twist=120)),
        ScenePair("inc30_70", ref30, view(2500e3, 70, 95, de=-300e3)),
        ScenePair("inc30_70_scale2", ref30, view(5000e3, 70, 95, dn=-200e3, twist=70)),
        ScenePair("inc30_70_scale2_finer", ref30, view(1250e3, 70, 95, dn=-100e3, twist=170)),
        ScenePair("inc30_70_scale4", ref30, view(10000e3, 72, 90, dn=-200e3, twist=-20)),
        ScenePair("azimuth45", ref, view(2500e3, 50, 135, de=200e3)),
        ScenePair("azimuth90", ref, view(2500e3, 50, 180, de=200e3)),
    ]


def convergent_views(
    surface: Any, emissions_deg: Sequence[float], rng: np.random.Generator, render_settings: Any = None,
    lat_deg: float = 5.0, lon_deg: float = 3.0,
) -> tuple[dict[str, Any], dict[str, Any], dict[str, TruePose]]:
    """Views of one site from the same range, tilted north by ``emissions_deg`` (WAC 256^2, 1.8 km/pixel,
    sun 45 deg from the east): the convergence study's scene (``bench_match.py --convergence``).

    Rendered with ``render_settings`` (default: the mission renderer); a-priori poses perturbed as the
    missions' (450 µrad, 100 m). Returns (images, geometries, true poses) keyed ``v0``, ``v1``, ...
    """
    from mercury_dem.geometry.body import latlon_to_unit, latlon_to_xyz
    from mercury_dem.geometry.camera import mdis_wac
    from mercury_dem.geometry.pose import look_at_rotation, rotation_from_angles
    from mercury_dem.match import ImageGeometry
    from mercury_dem.synth.render import render_image

    cam = mdis_wac(256)
    up = latlon_to_unit(lat_deg, lon_deg)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    centre = latlon_to_xyz(lat_deg, lon_deg, 0.0, SCENE_DATUM_RADIUS_M)
    alt = 1.79e3 / cam.ifov_rad
    sun = centre + 5.8e10 * (np.cos(np.radians(45)) * up + np.sin(np.radians(45)) * east)
    images: dict[str, Any] = {}
    geom: dict[str, Any] = {}
    truth: dict[str, TruePose] = {}
    for j, e_deg in enumerate(emissions_deg):
        c = centre + alt * (np.cos(np.radians(e_deg)) * up + np.sin(np.radians(e_deg)) * north)
        r = look_at_rotation(c, centre, east)
        images[f"v{j}"] = (render_image(surface, cam, c, r, sun, rng) if render_settings is None
                           else render_image(surface, cam, c, r, sun, rng, render_settings))
        r_ap = rotation_from_angles(rng.normal(0, 450e-6, 3)) @ r
        geom[f"v{j}"] = ImageGeometry.of(cam, c + rng.normal(0, 100, 3), r_ap, sun, SCENE_DATUM_RADIUS_M)
        truth[f"v{j}"] = TruePose(cam, c, r)
    return images, geom, truth


# --------------------------------------------------------------------------- control networks
def network_true_errors(
    image_ids: Sequence[str],
    measure_point: NDArray[np.int64],
    measure_image: NDArray[np.int64],
    pixels: NDArray[np.float64],
    truth: Mapping[str, TruePose],
    height: HeightFunction,
    *,
    datum_radius_m: float,
) -> NDArray[np.float64]:
    """True error (M,) in pixels of every measure of a control network against its point's anchor.

    The anchor of a point is its first measure (in measure order): the ground
    point seen there (true pose, true surface) is projected into every other
    measure's image and compared with that measure. Anchors get 0; NaN where the
    anchor's ray misses the surface or the point is behind a camera. A point whose
    measures all see one ground feature has every error near the matching error;
    a track that joined two features shows their offset.

    Parameters
    ----------
    image_ids : (K,) ids indexed by ``measure_image``
    measure_point, measure_image : (M,) int, point and image of each measure
    pixels : (M, 2) 0-based (sample, line)
    truth : image id -> true camera and pose
    height : the true surface height (lat, lon) -> m above the datum
    """
    mp = np.asarray(measure_point, np.int64)
    mi = np.asarray(measure_image, np.int64)
    m = mp.size
    if m == 0:
        return np.zeros(0)
    first = np.full(int(mp.max()) + 1, -1, np.int64)
    first[mp[::-1]] = np.arange(m)[::-1]
    anchor = first[mp]
    others = np.flatnonzero(anchor != np.arange(m))
    out = np.zeros(m)
    err = true_errors(image_ids, mi[anchor[others]], mi[others], pixels[anchor[others]], pixels[others], truth, height,
                      datum_radius_m=datum_radius_m)
    out[others] = err
    return out


def rays_histogram(measure_point: NDArray[np.int64], top: int = 6) -> dict[str, int]:
    """Points by number of measures (rays): {'2': n, '3': n, ..., f'>={top}': n}."""
    mp = np.asarray(measure_point, np.int64)
    if mp.size == 0:
        return {}
    rays = np.bincount(mp)
    rays = rays[rays > 0]
    out = {str(k): int((rays == k).sum()) for k in range(int(rays.min()), top)}
    out[f">={top}"] = int((rays >= top).sum())
    return out
