"""What an image's pixel values mean: kind, saturation and the size of a "DN" in its units.

The matcher's thresholds are written in 12-bit DN (``match.saturated_dn``,
``match.min_dynamic_range_dn``). Real images come as raw DN of any bit depth,
8-bit browse products or calibrated float I/F with special pixels, so every image
carries its own facts, stored in the catalog (columns :data:`RADIOMETRY_COLUMNS`):

``pixel_kind``
    ``dn`` (integer counts), ``uint8`` (8-bit products) or ``reflectance`` (float I/F or radiance).
``saturation``
    the value at and above which a pixel is saturated, in the image's units; NaN when the
    product has none (calibrated floats: ISIS marks saturation as special pixels, which
    arrive here as NaN = invalid).
``dn_scale``
    the image units of one 12-bit-DN step of the matcher's thresholds: 1 for integer DN;
    for float products the mission's typical robust range (0.5-99.5 %) / 4095, so a
    "textureless" image is one whose contrast is below 8/4095 of a typical scene's, as for DN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

RADIOMETRY_COLUMNS = ["pixel_kind", "saturation", "dn_scale"]
PIXEL_KINDS = ("dn", "uint8", "reflectance")
#: The matcher's thresholds are in DN of a 12-bit camera (MDIS).
DN12_STEPS = 4095.0


@dataclass(frozen=True)
class Radiometry:
    """Pixel facts of one image (see the module docstring)."""

    pixel_kind: str = "dn"
    saturation: float = 4095.0
    dn_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.pixel_kind not in PIXEL_KINDS:
            raise ValueError(f"pixel_kind must be one of {PIXEL_KINDS}, got {self.pixel_kind!r}")
        if not (self.dn_scale > 0 and math.isfinite(self.dn_scale)):
            raise ValueError(f"dn_scale must be a positive number, got {self.dn_scale}")


#: The synthetic missions' 12-bit MDIS-like DN.
DN12 = Radiometry("dn", 4095.0, 1.0)


def radiometry_of_dtype(dtype: np.dtype, bits: int | None = None) -> Radiometry:
    """The radiometry of integer pixels of a dtype (``bits`` of the detector when known)."""
    dt = np.dtype(dtype)
    if dt == np.uint8:
        return Radiometry("uint8", 255.0, 1.0)
    if dt.kind in "ui":
        top = float(2 ** bits - 1) if bits else float(np.iinfo(dt).max)
        return Radiometry("dn", top, 1.0)
    raise ValueError(f"radiometry_of_dtype: {dt} is not an integer type; use float_radiometry")


def robust_range(image: NDArray[np.floating], valid: NDArray[np.bool_] | None = None) -> float:
    """0.5-99.5 % range of an image's valid pixels (every second pixel), NaN when none."""
    img = np.asarray(image, dtype=np.float32)
    sub = img[::2, ::2] if min(img.shape) >= 64 else img
    ok = np.isfinite(sub)
    if valid is not None:
        ok &= (valid[::2, ::2] if min(img.shape) >= 64 else valid)
    if not ok.any():
        return math.nan
    lo, hi = np.percentile(sub[ok], [0.5, 99.5])
    return float(hi - lo)


def float_radiometry(ranges: list[float]) -> Radiometry:
    """The radiometry of float images whose robust ranges are ``ranges`` (one per image of a mission)."""
    good = [r for r in ranges if math.isfinite(r) and r > 0]
    typical = float(np.median(good)) if good else 1.0
    return Radiometry("reflectance", math.nan, typical / DN12_STEPS)
