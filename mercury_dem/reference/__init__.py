"""Reference heights a DEM of a real body is compared with.

* :mod:`~mercury_dem.reference.sha` — spherical-harmonic shape models (MLA's GTMES for
  Mercury): PDS SHADR reader, evaluation at points and on grids;
* :mod:`~mercury_dem.reference.lola` — altimetry shot tables (LOLA/MLA RDR CSV) with profile
  ids, and LOLA's LDEM cube as heights;
* :mod:`~mercury_dem.reference.sampling` — bilinear sampling of (lat, lon) grids across the seam;
* :mod:`~mercury_dem.reference.compare` — DEM − reference statistics on one stated datum.

Readers raise :class:`mercury_dem.exceptions.ReferenceDataError` naming the file and fault;
the rest are pure functions. See docs/design/reference.md.
"""

from __future__ import annotations

from mercury_dem.reference.compare import (
    compare_dem_with_harmonics,
    compare_dem_with_shots,
    compare_heights,
    difference_statistics,
    residuals_at_shots,
)
from mercury_dem.reference.lola import AltimetryShots, read_altimetry_csv, read_lola_ldem
from mercury_dem.reference.sampling import sample_grid, sample_reference_dem
from mercury_dem.reference.sha import ShapeHarmonics, evaluate, evaluate_grid, read_shadr

__all__ = [
    "AltimetryShots",
    "ShapeHarmonics",
    "compare_dem_with_harmonics",
    "compare_dem_with_shots",
    "compare_heights",
    "difference_statistics",
    "evaluate",
    "evaluate_grid",
    "read_altimetry_csv",
    "read_lola_ldem",
    "read_shadr",
    "residuals_at_shots",
    "sample_grid",
    "sample_reference_dem",
]
