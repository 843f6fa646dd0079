"""Feature matching of overlapping images (FAST + SIFT after a geometric pre-transform, guided,
with an NCC fallback, the ratio/symmetry/F/H outlier chain and sub-pixel refinement).

Public API: :func:`match_tile`, :func:`match_pair`, :func:`prepare_image`, :class:`ImageGeometry`,
:class:`TileMatches`, :class:`PairReport`, :class:`PairResult`.
"""

from mercury_dem.match.matcher import (
    ImageFeatures,
    PairReport,
    PairResult,
    TileMatches,
    match_pair,
    match_tile,
    prepare_image,
)
from mercury_dem.match.pretransform import ImageGeometry

__all__ = [
    "ImageFeatures",
    "ImageGeometry",
    "PairReport",
    "PairResult",
    "TileMatches",
    "match_pair",
    "match_tile",
    "prepare_image",
]
