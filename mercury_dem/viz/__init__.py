"""Tables and figures of a run for notebooks and the dashboard (read the store; no Dask).

- :mod:`~mercury_dem.viz.status`: unit/tile states, progress per level, σ0 per iteration;
- :mod:`~mercury_dem.viz.tables`: report.json as tables, images with problems;
- :mod:`~mercury_dem.viz.networks`: network statistics, residuals per level / point / image;
- :mod:`~mercury_dem.viz.pointing`: pointing error before/after vs truth;
- :mod:`~mercury_dem.viz.figures`: matplotlib figures of all of these, coverage and the DEM;
- :mod:`~mercury_dem.viz.session`: a configuration for a mission's area, a run in the background, following a run.
"""

from mercury_dem.viz.figures import (
    coverage_figure,
    dem_error,
    dem_validation_figure,
    hillshade_figure,
    pointing_figure,
    residual_histograms_figure,
    residual_map_figure,
    sigma0_figure,
    tile_status_figure,
)
from mercury_dem.viz.networks import image_residuals, network_statistics, point_residuals, residuals_by_level
from mercury_dem.viz.pointing import pointing_errors
from mercury_dem.viz.session import BackgroundRun, area_config, follow, progress_line
from mercury_dem.viz.status import (
    STATE_COLOURS,
    STATES,
    expected_units,
    level_progress,
    run_info,
    sigma0_history,
    tile_status,
    unit_status,
)
from mercury_dem.viz.tables import problem_images, read_report, report_tables

__all__ = [
    "BackgroundRun", "area_config", "follow", "progress_line", "STATES", "STATE_COLOURS", "coverage_figure", "dem_error", "dem_validation_figure", "expected_units",
    "hillshade_figure", "image_residuals", "level_progress", "network_statistics", "point_residuals",
    "pointing_errors", "pointing_figure", "problem_images", "read_report", "report_tables",
    "residual_histograms_figure", "residual_map_figure", "residuals_by_level", "run_info", "sigma0_figure",
    "sigma0_history", "tile_status", "tile_status_figure", "unit_status",
]
