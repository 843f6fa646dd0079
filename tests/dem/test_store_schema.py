"""The DEM store's schema (mercury_dem.dem.store_schema) and the stage's memory model (mercury_dem.dem.memory)."""

from __future__ import annotations

import dataclasses
import json

import pytest

from mercury_dem.config.dem import DemConfig
from mercury_dem.dem.grid import LAYERS, GridSpec
from mercury_dem.dem.memory import check_memory, estimate_memory_bytes
from mercury_dem.dem.store_schema import ATTRS, COORD_ATTRS, gridding_attr, root_attrs
from mercury_dem.exceptions import GridError
from mercury_dem.geometry.body import MERCURY, MOON

CFG = DemConfig(pixels_per_degree=4, lat_min=-10, lat_max=10, lon_min=0, lon_max=20, chunk_size=32)


def test_every_layer_and_coordinate_has_cf_attributes():
    assert set(ATTRS) == set(LAYERS)
    assert all(a["units"] and a["long_name"] for a in ATTRS.values())
    assert COORD_ATTRS["lat"]["units"] == "degrees_north" and COORD_ATTRS["lon"]["units"] == "degrees_east"


@pytest.mark.parametrize("body", [MERCURY, MOON])
def test_root_attributes_name_the_body_its_datum_and_the_grid(body):
    grid = GridSpec.from_config(CFG, body.datum_radius_m)
    a = root_attrs(grid, CFG, {"source": "test", "title": "mine"}, body)
    assert a["datum_radius_m"] == body.datum_radius_m and json.loads(a["body"])["name"] == body.name
    assert a["crs_code"] == body.crs("geographic") and a["pixels_per_degree"] == 4
    assert a["grid_bounds_deg"] == [-10, 10, 0, 20] and a["source"] == "test" and a["title"] == "mine"
    # Mercury's datum (2439.4 km) is not its IAU sphere: the text says heights never refer to the IAU sphere
    assert ("never refer" in a["height_reference"]) == (not body.datum_is_iau_sphere)
    assert f"{body.datum_radius_m / 1000:g} km" in a["height_reference"]


def test_gridding_attribute_records_the_settings_a_pixel_depends_on():
    g = json.loads(gridding_attr(dataclasses.replace(CFG, max_distance_m=1234.5, neighbours=7)))
    assert g["max_distance_m"] == 1234.5 and g["neighbours"] == 7 and g["method"] == "median11"


def test_memory_model_scales_with_points_and_pixels():
    grid = GridSpec.from_config(CFG, MERCURY.datum_radius_m)
    a, b = estimate_memory_bytes(grid, 1000, CFG), estimate_memory_bytes(grid, 3000, CFG)
    assert b["dem_worker"] - a["dem_worker"] == 240 * 2000  # ~120 B a point, twice while it is pickled
    assert a["products"] == grid.shape[0] * grid.shape[1] * 20  # five float32 full-map layers
    assert a["peak"] == max(a["dem_worker"], a["products"])
    assert check_memory(grid, 1000, CFG) == a
    tight = dataclasses.replace(CFG, memory_limit_gb=a["peak"] / 1e9 * 0.99)
    with pytest.raises(GridError, match="memory_limit_gb"):
        check_memory(grid, 1000, tight)
