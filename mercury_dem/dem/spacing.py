"""The no-value distance of a grid, from the spacing of its points.

A pixel whose nearest point is farther than the no-value distance ``D`` has no value.
``dem.max_distance_m`` > 0 fixes ``D``; left at 0 (the default) it follows the points:

    D = max(no_value_spacing_factor x g, one pixel),   g = the points' typical gap,

where ``g`` is the median, over an equal-area lattice of :data:`PROBES` places in the
points' latitude/longitude bounding box, of the distance from the place to its nearest
point (the ``distance_to_nearest_point`` a pixel there would get; chords on the datum
sphere, metres). ``g`` is the typical distance from a place *inside the data* to the
data, so ``D`` keeps the ordinary gaps of the sampling filled and leaves wider ones empty:

* tracks ``S`` apart, densely sampled along track (laser altimetry): a place is
  uniformly 0..S/2 from the nearest track, ``g = S/4``, and with the default factor 5
  ``D = 1.25 S``: a gap between tracks is filled up to ``2.5 S`` wide (its middle is at
  half its width from a track: one missing track is bridged) and no-value beyond;
* points scattered at random (density ``n`` per m^2): ``g = sqrt(ln 2 / (pi n))``, and a
  place farther than ``5 g`` from every point has probability ``2**-25`` (factor 4:
  ``2**-16``, about one pixel in a 240 x 240 map at 3 points per pixel): no holes in
  uniform data.

The median nearest-neighbour spacing *between points* would not do: along a track the
neighbours are the next shots (tens of metres for LOLA), not the next track (hundreds),
and every pixel between tracks would be no-value. The floor of one pixel (north-south
size) keeps a pixel that holds points valued when the points are denser than the grid.
``g`` counts empty parts of the box too, so a cloud that fills little of its box gets a
larger ``D`` (more filled, never fewer): the old fixed 50 km was the extreme of that.

This module holds the rule and its probe lattice; the gap's measurement and the resolved configuration
(:func:`mercury_dem.dem.grid.typical_gap_m`, :func:`mercury_dem.dem.grid.config_with_no_value_distance`)
sit beside the search they use, in ``dem/grid.py``, which imports this module (never the reverse).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

#: Probe places of the typical gap (an equal-area lattice of 64 x 64 over the points' box).
PROBES_PER_SIDE = 64
PROBES = PROBES_PER_SIDE * PROBES_PER_SIDE

#: The no-value distance is never below this many (north-south) pixels.
MIN_PIXELS = 1.0

#: At most about this many points (a regular stride) size the box the probes lie in.
BOX_SAMPLE = 200_000


def probe_lattice(box: tuple[float, float, float, float], per_side: int = PROBES_PER_SIDE
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Latitudes and longitudes (degrees, (per_side**2,) each) of an equal-area lattice over the box
    (lat_min, lat_max, west, east): cell centres, uniform in sin(latitude) and in longitude.
    """
    lat_min, lat_max, west, east = box
    t = (np.arange(per_side) + 0.5) / per_side
    s0, s1 = math.sin(math.radians(lat_min)), math.sin(math.radians(lat_max))
    lat = np.degrees(np.arcsin(np.clip(s0 + t * (s1 - s0), -1.0, 1.0)))
    lon = west + t * (east - west)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    return la.ravel(), np.mod(lo.ravel(), 360.0)


def no_value_distance_m(gap_m: float, factor: float, pixel_size_m: float, min_pixels: float = MIN_PIXELS) -> float:
    """The rule of the module docstring: ``max(factor x gap_m, min_pixels x pixel_size_m)``, metres."""
    return max(factor * gap_m, min_pixels * pixel_size_m)
