"""DEM pre-transform of a pair: the partner image resampled into the base image's frame through a surface.

The datum pre-transform (:mod:`mercury_dem.match.pretransform`) maps base pixels to the
partner through the datum sphere (one homography), so the relief's parallax stays in
the warped image; between convergent views it varies inside a correlation window and
biases area-based matching along the epipolar line (docs/design/match.md, "View
convergence"). Here every base pixel's ray is intersected with a height model instead
(``image_to_ground`` with a height function) and projected into the partner, giving a
per-pixel resampling map (``cv2.remap``). With the true surface and poses the warped
partner lies pixel for pixel on the base image (up to occlusion and photometry); with a
first DEM what remains is the DEM's error times the pair's parallax per metre.

Positions found in the warped frame map back to the partner's pixels through the same
map (bilinear), which is the warp's own sampling function, so the map's approximations
never enter the measures.

Written here rather than with a library: the map is a ray-surface intersection of the
project's own camera model (no GDAL/ISIS orthorectifier applies to these synthetic
cameras); the resampling itself is OpenCV's.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from mercury_dem.config.match import MatchConfig
from mercury_dem.geometry.pose import image_to_ground, project
from mercury_dem.match.pretransform import ImageGeometry, pair_geometry

HeightFunction = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


def dem_maps(
    base: ImageGeometry,
    partner: ImageGeometry,
    height: HeightFunction | None,
    stride: int = 1,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Partner pixel (sample, line) of every base pixel through a height model.

    Parameters
    ----------
    base, partner : geometries of the image kept in its own frame and of the image resampled onto it
    height : (lat, lon) degrees -> metres above the datum; None for the datum sphere
    stride : rays are cast every ``stride`` base pixels and the map interpolated bilinearly between
        (1: every pixel; relief shorter than ``stride`` pixels is then not followed)

    Returns
    -------
    map_x, map_y : ndarray (lines, samples) float32 of the base image, partner pixel coordinates
        (0-based, pixel centres); NaN where the base ray misses the surface or the point is behind
        the partner camera
    """
    cam = base.camera
    n_s = (cam.samples - 1) // stride + 2
    n_l = (cam.lines - 1) // stride + 2
    ss, ll = np.meshgrid(np.arange(n_s, dtype=np.float64) * stride, np.arange(n_l, dtype=np.float64) * stride)
    px = np.stack([ss.ravel(), ll.ravel()], axis=-1)
    ground, hit = image_to_ground(cam, base.position, base.rotation, px, height=height,
                                  datum_radius_m=base.datum_radius_m)
    q, depth = project(partner.camera, partner.position, partner.rotation, np.where(hit[:, None], ground, 0.0))
    bad = ~hit | ~(depth > 0) | ~np.all(np.isfinite(q), axis=-1)
    q[bad] = np.nan
    mx = q[:, 0].reshape(n_l, n_s)
    my = q[:, 1].reshape(n_l, n_s)
    if stride == 1:
        return mx[: cam.lines, : cam.samples].astype(np.float32), my[: cam.lines, : cam.samples].astype(np.float32)
    # bilinear interpolation of the coarse map at every base pixel (NaN spreads to its cells)
    t_s = np.arange(cam.samples, dtype=np.float64) / stride
    t_l = np.arange(cam.lines, dtype=np.float64) / stride
    i_s = np.minimum(t_s.astype(np.int64), n_s - 2)
    i_l = np.minimum(t_l.astype(np.int64), n_l - 2)
    f_s = (t_s - i_s)[None, :]
    f_l = (t_l - i_l)[:, None]

    def up(m: NDArray[np.float64]) -> NDArray[np.float32]:
        a = m[np.ix_(i_l, i_s)]
        b = m[np.ix_(i_l, i_s + 1)]
        c = m[np.ix_(i_l + 1, i_s)]
        d = m[np.ix_(i_l + 1, i_s + 1)]
        out = (a * (1 - f_s) + b * f_s) * (1 - f_l) + (c * (1 - f_s) + d * f_s) * f_l
        return out.astype(np.float32)

    return up(mx), up(my)


def warp_with_maps(
    partner_image: NDArray[np.float32],
    map_x: NDArray[np.float32],
    map_y: NDArray[np.float32],
    scale: float,
    psf_sigma_px: float = 0.7,
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """The partner image resampled onto the base frame by the maps, and where it is valid.

    Parameters
    ----------
    partner_image : ndarray (lines, samples) float32, DN
    map_x, map_y : from :func:`dem_maps`
    scale : partner pixels per base pixel; above 1.05 the partner is low-pass filtered first
        (sigma ``psf_sigma_px * sqrt(scale**2 - 1)``, as :func:`pretransform.warp_to_reference`)
    psf_sigma_px : point-spread sigma of the images in their own pixels

    Returns
    -------
    warped : ndarray like the maps, float32 (partner border replicated outside it)
    valid : ndarray bool, True where the bilinear sample lies inside the partner image (one pixel
        inside its border) and the map is defined
    """
    src = np.asarray(partner_image, np.float32)
    if scale > 1.05:
        src = np.asarray(cv2.GaussianBlur(src, (0, 0), sigmaX=psf_sigma_px * float(np.sqrt(scale * scale - 1.0))),
                         np.float32)
    finite = np.isfinite(map_x) & np.isfinite(map_y)
    mx = np.where(finite, map_x, -10.0).astype(np.float32)
    my = np.where(finite, map_y, -10.0).astype(np.float32)
    warped = np.asarray(cv2.remap(src, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
                        np.float32)
    h, w = partner_image.shape[:2]
    valid = finite & (mx >= 1.0) & (my >= 1.0) & (mx <= w - 2.0) & (my <= h - 2.0)
    return warped, valid


def map_points(
    map_x: NDArray[np.float32], map_y: NDArray[np.float32], points: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Warped-frame positions (N, 2) (sample, line) -> partner pixels, bilinear in the maps.

    NaN where a point lies outside the maps or next to an undefined map value.
    """
    p = np.asarray(points, np.float64).reshape(-1, 2)
    h, w = map_x.shape
    out = np.full(p.shape, np.nan)
    inside = (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] <= h - 1)
    if not inside.any():
        return out
    s, line = p[inside, 0], p[inside, 1]
    i0 = np.minimum(s.astype(np.int64), w - 2)
    j0 = np.minimum(line.astype(np.int64), h - 2)
    fs, fl = s - i0, line - j0
    for k, m in enumerate((map_x, map_y)):
        a, b = m[j0, i0].astype(np.float64), m[j0, i0 + 1].astype(np.float64)
        c, d = m[j0 + 1, i0].astype(np.float64), m[j0 + 1, i0 + 1].astype(np.float64)
        out[inside, k] = (a * (1 - fs) + b * fs) * (1 - fl) + (c * (1 - fs) + d * fs) * fl
    return out


def match_pair_on_surface(
    images: Mapping[str, NDArray[Any]],
    geometry: Mapping[str, ImageGeometry],
    map_geometry: Mapping[str, ImageGeometry],
    pair: tuple[str, str],
    height: HeightFunction | None,
    config: MatchConfig,
    stride: int = 1,
    *,
    pointing_sigma_urad: float,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Match one pair with the DEM pre-transform: measures in the pair's original images.

    The coarser image (as the matcher's ``warp_finer``, from the a-priori datum scale) is the
    base; the other is resampled onto it through ``height`` with the poses of ``map_geometry``
    (:func:`dem_maps`, :func:`warp_with_maps`) and the two are matched by :func:`match_tile`
    as a pair with identical geometry (``geometry`` of the base: its guidance window), without
    track propagation. Measures whose warped-side position lies within a refinement half-window
    of the resampled data's edge are dropped; the rest map back through the map.

    Parameters
    ----------
    images : image id -> (lines, samples) DN (uint16 12-bit, or float)
    geometry : image id -> a-priori geometry (the matcher's guidance and scale)
    map_geometry : image id -> geometry the resampling map is built with (a-priori, adjusted, or
        true poses in a study)
    pair : (reference id, match id)
    height : the surface of the map, (lat, lon) degrees -> metres; None for the datum sphere
    config : matcher configuration
    stride : ray spacing of the map, base pixels (:func:`dem_maps`)
    pointing_sigma_urad : the a-priori pointing sigma (µrad per axis) sizing the guidance window (:func:`match_tile`)

    Returns
    -------
    points_a, points_b : ndarray (M, 2) (sample, line), 0-based pixels of ``pair[0]`` and ``pair[1]``
    """
    from mercury_dem.match.tile import match_tile  # the matcher imports nothing from here

    a, b = pair
    empty = np.zeros((0, 2))
    pg = pair_geometry(geometry[a], geometry[b])
    if isinstance(pg, str):
        return empty, empty
    swap = config.warp_finer and pg.match_px_per_ref_px < 1.0 / config.swap_scale_ratio
    base, partner = (b, a) if swap else (a, b)
    scale = 1.0 / pg.match_px_per_ref_px if swap else pg.match_px_per_ref_px
    mx, my = dem_maps(map_geometry[base], map_geometry[partner], height, stride=stride)
    warped, valid = warp_with_maps(np.asarray(images[partner], np.float32), mx, my, scale, config.psf_sigma_px)
    dtype = np.asarray(images[base]).dtype
    if np.issubdtype(dtype, np.integer):
        warped = np.clip(np.rint(warped), 0, np.iinfo(dtype).max).astype(dtype)
    side = 2 * (config.refine_window_px // 2) + 1
    valid_core = cv2.erode(valid.astype(np.uint8), np.ones((side, side), np.uint8)).astype(bool)
    virtual = "\x00resampled"
    vg = dataclasses.replace(geometry[base], sun_position=geometry[partner].sun_position)
    m, _ = match_tile({base: images[base], virtual: warped}, {base: geometry[base], virtual: vg},
                      [(base, virtual)], config, tracks=False,
                      pointing_sigma_urad=pointing_sigma_urad)
    pk = np.stack([m.sample_a, m.line_a], -1)
    pv = np.stack([m.sample_b, m.line_b], -1)
    if len(pv):
        iv = np.clip(np.rint(pv).astype(np.int64), 0, np.array(valid.shape[::-1]) - 1)
        keep = valid_core[iv[:, 1], iv[:, 0]]
        pk, pv = pk[keep], pv[keep]
    pw = map_points(mx, my, pv)
    ok = np.all(np.isfinite(pw), axis=1)
    pk, pw = pk[ok], pw[ok]
    return (pw, pk) if swap else (pk, pw)
