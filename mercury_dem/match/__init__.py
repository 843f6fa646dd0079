"""Feature matching of overlapping images (FAST + SIFT after a geometric pre-transform, guided,
with an NCC fallback, the ratio/symmetry/F/H outlier chain and sub-pixel refinement).

Public API: :func:`match_tile`, :func:`match_pair`, :func:`prepare_image`, :class:`ImageGeometry`,
:class:`TileMatches`, :class:`PairReport`, :class:`PairResult`.
"""

from mercury_dem.match.pair import match_pair
from mercury_dem.match.prepare import ImageFeatures, prepare_image
from mercury_dem.match.pretransform import ImageGeometry
from mercury_dem.match.result import PairReport, PairResult, TileMatches
from mercury_dem.match.tile import match_tile

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
