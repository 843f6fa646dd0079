"""One chip of a stereo pair from images to filtered dense points, and the chips that cover an image.

The dense stage's unit of work (docs/design/dense.md): :func:`chip_grid` cuts the left image (or the part
of it inside a tile) into chips with a collar; :func:`dense_chip` runs rectification, matching,
triangulation and the point filters on one chip and returns the points with what the run report needs
(hole and filter counts, the rectification's figures, the stated memory). Pure: arrays in, arrays out.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from mercury_dem.dense.disparity import HOLE_FLAGS, MatcherSettings, dense_disparity
from mercury_dem.dense.rectify import Chip, rectify_chip
from mercury_dem.dense.triangulate import DensePoints, PointFilter, filter_points, triangulate_chip
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
    disparity_range_px : the search range (min, max), rectified pixels
    vertical_rms_px : the rectification error on the grid
    sgm_memory_bytes : SGM's cost-volume bound for this chip
    """

    points: DensePoints
    interior_pixels: int
    matched: int
    holes: dict[str, int]
    removed: dict[str, int]
    disparity_range_px: tuple[float, float]
    vertical_rms_px: float
    sgm_memory_bytes: int

    def summary(self) -> dict[str, object]:
        """The figures without the points (JSON-ready)."""
        return {"interior_pixels": self.interior_pixels, "matched": self.matched, "points": len(self.points),
                "holes": self.holes, "removed": self.removed, "disparity_range_px": list(self.disparity_range_px),
                "vertical_rms_px": self.vertical_rms_px, "sgm_memory_bytes": self.sgm_memory_bytes}


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
) -> ChipResult:
    """Rectify, match, triangulate and filter one chip (each step's parameters as in its module).

    Raises
    ------
    GeometryError
        when the chip cannot be rectified (it does not see the body or the right image does not see it)
    """
    rect = rectify_chip(left_image, right_image, left, right, chip, surface_height, height_margin_m,
                        psf_sigma_px=psf_sigma_px)
    dm = dense_disparity(rect.left, rect.right, rect.left_valid, rect.right_valid, rect.disparity_min_px,
                         rect.disparity_max_px, settings)
    inner = dm.holes[rect.interior_mask()]
    holes = {k: int(np.count_nonzero(inner & bit)) for k, bit in HOLE_FLAGS.items()}
    pts = triangulate_chip(rect, left, right, dm.disparity, dm.sigma_px, dm.score, sigma_floor_px)
    kept, removed = filter_points(pts, left, limits)
    return ChipResult(kept, int(inner.size), int(np.count_nonzero(inner == 0)), holes, removed,
                      (rect.disparity_min_px, rect.disparity_max_px), rect.vertical_rms_px, rect.sgm_memory_bytes)
