"""Real image sources read without their mission software.

:mod:`~mercury_dem.sources.isis_cube` (label), :mod:`~mercury_dem.sources.isis_pixels` (pixels),
:mod:`~mercury_dem.sources.isis_tables` (attached tables, NAIF keywords, AlphaCube) and
:mod:`~mercury_dem.sources.isis_spice` (exterior orientation and serial number) read ISIS3
cubes that ``spiceinit attach=true`` has processed; every fault is a :class:`~mercury_dem.exceptions.CubeError` naming the file.
"""

from __future__ import annotations

from mercury_dem.sources.isis_cube import IsisCube, open_cube
from mercury_dem.sources.isis_pixels import read_pixels, special_pixel_counts
from mercury_dem.sources.isis_spice import CubeSpice, cube_spice, isis_serial_number
from mercury_dem.sources.isis_tables import AlphaCube, CubeTable, alpha_cube, naif_keywords, read_table, table_names

__all__ = [
    "AlphaCube",
    "CubeSpice",
    "CubeTable",
    "IsisCube",
    "alpha_cube",
    "cube_spice",
    "isis_serial_number",
    "naif_keywords",
    "open_cube",
    "read_pixels",
    "read_table",
    "special_pixel_counts",
    "table_names",
]
