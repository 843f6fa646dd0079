"""Reference heights a run's DEM is compared with (real missions: laser altimetry, shape models)."""

from __future__ import annotations

from dataclasses import dataclass

from mercury_dem.config.base import ConfigSection, param


@dataclass(frozen=True)
class ReferenceConfig(ConfigSection):
    """The ``reference`` section: reference heights the DEM is compared with."""

    dem: str | None = param(
        None, "A reference DEM raster GDAL reads (e.g. a LOLA LDEM cube: heights = DN x Multiplier above the "
        "label's Base radius); the run's DEM minus it is reported (report.json dem.reference)",
    )
    altimetry: tuple[str, ...] = param(
        (), "Laser altimeter shot tables (PDS LOLA/MLA RDR CSV); the DEM minus each shot's radius is reported",
    )
    shape_harmonics: str | None = param(
        None, "A PDS spherical-harmonic shape model (e.g. MLA's GTMES_150V05_SHA.TAB); the DEM minus its "
        "expansion to shape_lmax is reported",
    )
    shape_lmax: int = param(148, "Degree of the shape model's expansion", lo=1, hi=2800)
    max_point_distance_m: float = param(
        1000.0, "Compare only DEM pixels this close to a control point (farther ones are interpolated "
        "across gaps up to dem.max_distance_m, not measured)", unit="m", lo=0.0,
    )
