"""One chip of a stereo pair from images to filtered dense points, and the chips that cover an image.

The dense stage's unit of work (docs/design/dense.md): :func:`chip_grid` cuts the left image (or the part
of it inside a tile) into chips with a collar; :func:`dense_chip` runs rectification, matching,
triangulation and the point filters on one chip and returns the points with what the run report needs
(hole and filter counts, the rectification's figures, the stated memory). Pure: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from mercury_dem.dense.disparity import HOLE_FLAGS, MatcherSettings, dense_disparity
from mercury_dem.dense.rectify import Chip, RectifiedChip, rectify_chip
from mercury_dem.dense.triangulate import DensePoints, PointFilter, filter_points, triangulate_chip
from mercury_dem.exceptions import GeometryError
from mercury_dem.geometry.pose import HeightFunction
from mercury_dem.match.pretransform import ImageGeometry


def chip_grid(samples: int, lines: int, size: int = 512, collar: int = 32,
              window: tuple[int, int, int, int] | None = None) -> list[Chip]:
    """Chips of interior ``size`` x ``size`` (smaller at the far edges) covering a window of an image once.

    Parameters
    ----------
    samples, lines : the image size
    size : interior side, pixels
    collar : context pixels on every side (may reach beyond the image: those pixels are flagged outside)
    window : (x0, y0, x1, y1) part of the image to cover (end-exclusive), default the whole image

    Returns
    -------
    list of :class:`Chip`, row-major; their interiors tile the window without overlap
    """
    x0, y0, x1, y1 = window or (0, 0, samples, lines)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, samples), min(y1, lines)
    return [Chip(x, y, min(size, x1 - x), min(size, y1 - y), collar)
            for y in range(y0, y1, size) for x in range(x0, x1, size)]


def split_chip(chip: Chip) -> list[Chip]:
    """The four quadrants of a chip's interior (row-major), each with the chip's collar; they tile it once."""
    w1, h1 = chip.width // 2, chip.height // 2
    return [Chip(chip.x0 + x, chip.y0 + y, w, h, chip.collar)
            for y, h in ((0, h1), (h1, chip.height - h1)) for x, w in ((0, w1), (w1, chip.width - w1))]


def rectify_split(
    left_image: NDArray[np.float32],
    right_image: NDArray[np.float32],
    left: ImageGeometry,
    right: ImageGeometry,
    chip: Chip,
    surface_height: HeightFunction | None = None,
    height_margin_m: float = 1000.0,
    max_vertical_px: float = 0.1,
    min_chip_px: int = 32,
    psf_sigma_px: float = 0.6,
) -> tuple[list[tuple[Chip, RectifiedChip]], int]:
    """Rectify a chip, splitting it into quadrants (recursively) while its rectification is not epipolar.

    A chip's rectification (:func:`mercury_dem.dense.rectify.rectify_chip`) maps the right image by one
    homography, exact for a plane: over a chip hundreds of kilometres wide (a whole 256^2 image at 2 km/px
    of the tiny mission) the curved, rough surface leaves pixels of vertical disparity, which no 1-D
    matcher recovers. The chip is split while its ``vertical_rms_px`` (the model's own figure, on its grid
    over the search range: no truth) exceeds ``max_vertical_px`` and its interior sides are at least
    ``2 * min_chip_px``. A part that cannot be rectified (off the body, not seen by the right image) is
    split too while it may, and dropped at the smallest size.

    Returns
    -------
    (chip, rectified chip) of the parts kept, row-major within each split; and how many smallest parts
    could not be rectified

    Raises
    ------
    GeometryError
        when no part of the chip can be rectified (the first part's reason)
    """
    out: list[tuple[Chip, RectifiedChip]] = []
    errors: list[GeometryError] = []

    def visit(c: Chip) -> None:
        can_split = min(c.width, c.height) >= 2 * min_chip_px
        try:
            rect = rectify_chip(left_image, right_image, left, right, c, surface_height, height_margin_m,
                                psf_sigma_px=psf_sigma_px)
        except GeometryError as exc:
            if not can_split:
                errors.append(exc)
                return
            rect = None
        if rect is not None and (rect.vertical_rms_px <= max_vertical_px or not can_split):
            out.append((c, rect))
            return
        for q in split_chip(c):
            visit(q)

    visit(chip)
    if not out:
        raise errors[0] if errors else GeometryError(f"chip at ({chip.x0}, {chip.y0}): no part rectified")
    return out, len(errors)


def _concat_points(parts: list[DensePoints]) -> DensePoints:
    def cat(f: str) -> NDArray[np.float64] | None:
        arrays = [getattr(p, f) for p in parts]
        return None if any(a is None for a in arrays) else np.concatenate(arrays)

    values: dict[str, Any] = {f: cat(f) for f in DensePoints.__dataclass_fields__}
    return DensePoints(**values)


@dataclass(frozen=True)
class ChipResult:
    """Dense points of one chip and its figures for the run report.

    Attributes
    ----------
    points : the filtered :class:`DensePoints` of the chip's interior
    interior_pixels : pixels of the chip's interior
    matched : interior pixels with a valid disparity (before the point filters)
    holes : hole flag -> interior pixels carrying it (:data:`mercury_dem.dense.disparity.HOLE_FLAGS`)
    removed : point filter -> points it removed
    disparity_range_px : the search range (min, max), rectified pixels (the widest of its parts)
    vertical_rms_px : the rectification error on the grid (the largest of its parts)
    sgm_memory_bytes : SGM's cost-volume bound for this chip (the largest of its parts: they run one by one)
    parts : the rectified parts the chip was split into (:func:`rectify_split`), 1 when not split
    parts_failed : smallest parts that could not be rectified (off the body or not seen by the right image)
    """

    points: DensePoints
    interior_pixels: int
    matched: int
    holes: dict[str, int]
    removed: dict[str, int]
    disparity_range_px: tuple[float, float]
    vertical_rms_px: float
    sgm_memory_bytes: int
    parts: int = 1
    parts_failed: int = 0

    def summary(self) -> dict[str, object]:
        """The figures without the points (JSON-ready)."""
        return {"interior_pixels": self.interior_pixels, "matched": self.matched, "points": len(self.points),
                "holes": self.holes, "removed": self.removed, "disparity_range_px": list(self.disparity_range_px),
                "vertical_rms_px": self.vertical_rms_px, "sgm_memory_bytes": self.sgm_memory_bytes,
                "parts": self.parts, "parts_failed": self.parts_failed}


def dense_chip(
    left_image: NDArray[np.float32],
    right_image: NDArray[np.float32],
    left: ImageGeometry,
    right: ImageGeometry,
    chip: Chip,
    surface_height: HeightFunction | None = None,
    height_margin_m: float = 1000.0,
    settings: MatcherSettings = MatcherSettings(),
    limits: PointFilter = PointFilter(),
    sigma_floor_px: float = 0.05,
    psf_sigma_px: float = 0.6,
    max_vertical_px: float = 0.1,
    min_chip_px: int = 32,
    sigma_scale: float = 1.0,
    sigma_height_floor_m: float = 0.0,
    sigma_height_cap_m: float | None = None,
) -> ChipResult:
    """Rectify (split while not epipolar: :func:`rectify_split`), match, triangulate and filter one chip
    (each step's parameters as in its module).

    Raises
    ------
    GeometryError
        when no part of the chip can be rectified (it does not see the body or the right image does not see it)
    """
    parts, failed = rectify_split(left_image, right_image, left, right, chip, surface_height, height_margin_m,
                                  max_vertical_px, min_chip_px, psf_sigma_px)
    points: list[DensePoints] = []
    holes = dict.fromkeys(HOLE_FLAGS, 0)
    removed: dict[str, int] = {}
    interior = matched = 0
    for _, rect in parts:
        dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                             rect.disparity_max_px, settings)
        inner = dm.holes[rect.interior_mask()]
        for k, bit in HOLE_FLAGS.items():
            holes[k] += int(np.count_nonzero(inner & bit))
        pts = triangulate_chip(rect, left, right, dm.disparity, dm.sigma_px, dm.score, sigma_floor_px,
                               sigma_scale=sigma_scale, sigma_height_floor_m=sigma_height_floor_m,
                               sigma_height_cap_m=sigma_height_cap_m)
        kept, rem = filter_points(pts, left, limits)
        for k, v in rem.items():
            removed[k] = removed.get(k, 0) + v
        points.append(kept)
        interior += int(inner.size)
        matched += int(np.count_nonzero(inner == 0))
    rects = [r for _, r in parts]
    return ChipResult(_concat_points(points), interior, matched, holes, removed,
                      (min(r.disparity_min_px for r in rects), max(r.disparity_max_px for r in rects)),
                      max(r.vertical_rms_px for r in rects), max(r.sgm_memory_bytes for r in rects),
                      len(parts), failed)
