"""Cube labels and pixels: real cubes against GDAL's ISIS3 driver, synthetic cubes of every layout."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from mercury_dem.exceptions import CubeError, GeometryError
from mercury_dem.sources import open_cube, read_pixels, special_pixel_counts
from tests.sources.cubes import APOLLO_0297, MDIS_LEV1, MDIS_SPICE, shared, write_cube


def _rasterio_band(path: Path, band: int = 1) -> np.ma.MaskedArray:
    """GDAL's reading, Base/Multiplier applied (GDAL reports them as scale/offset only)."""
    rasterio = pytest.importorskip("rasterio")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # NotGeoreferencedWarning: a level-1 cube has no map
        with rasterio.open(path) as ds:
            raw = ds.read(band, masked=True)
            scale, offset = ds.scales[band - 1], ds.offsets[band - 1]
    return raw.astype(np.float64) * scale + offset


def _assert_same_as_gdal(path: Path, band: int = 1) -> None:
    cube = open_cube(path)
    image, valid = read_pixels(cube, band)
    ref = _rasterio_band(path, band)
    assert image.shape == ref.shape == (cube.lines, cube.samples)
    np.testing.assert_array_equal(valid, ~np.ma.getmaskarray(ref))
    np.testing.assert_array_equal(image[valid], np.asarray(ref.data, np.float32)[valid])
    assert np.all(np.isnan(image[~valid]))


def test_label_facts_of_the_mdis_cube() -> None:
    cube = open_cube(MDIS_SPICE)
    assert (cube.samples, cube.lines, cube.bands) == (512, 512, 1)
    assert (cube.pixel_type, cube.byte_order, cube.core_format) == ("Real", "Lsb", "Tile")
    assert (cube.core_start_byte, cube.tile_samples, cube.tile_lines) == (65537, 512, 512)
    assert (cube.base, cube.multiplier) == (0.0, 1.0)
    assert cube.spacecraft_name == "Messenger" and cube.instrument_id == "MDIS-NAC"
    assert cube.target_name == "Mercury"
    assert cube.start_time == "2015-04-24T04:42:19.666463"  # kept as written, not a datetime
    assert cube.spacecraft_clock_count == "2/0072174528:989000"
    assert cube.exposure_duration_s == pytest.approx(0.001)
    assert cube.summing == 2  # FpuBinningMode 1, PixelBinningMode 0: 2x2, as ISIS's MdisCamera
    assert cube.filter == "748 BP 53"


def test_real_pixels_match_gdal() -> None:
    for path in (MDIS_LEV1, MDIS_SPICE, APOLLO_0297):
        _assert_same_as_gdal(path)


def test_lev1_special_pixels_are_counted() -> None:
    cube = open_cube(MDIS_LEV1)
    image, valid = read_pixels(cube)
    counts = special_pixel_counts(cube)
    assert counts == {"Null": 1536, "Lrs": 0, "Lis": 0, "His": 0, "Hrs": 0}  # mdiscal's nulled edge columns
    assert int((~valid).sum()) == 1536
    assert 1e-4 < np.nanmin(image) and np.nanmax(image) < 0.05  # I/F


def test_raw_dn_cube_without_spice_reads() -> None:
    path = shared("mdis/EN1072174528M/EN1072174528M_raw_dn.cub")
    image, valid = read_pixels(open_cube(path))
    assert valid.all() and image.min() == 256 and image.max() == 395
    spliced, _ = read_pixels(open_cube(MDIS_SPICE))
    np.testing.assert_array_equal(image, spliced)  # README: the same pixels byte for byte


SPECIALS = {  # stored value of Null, Lrs, Lis, His, Hrs by type
    "Real": np.array([0xFF7FFFFB, 0xFF7FFFFC, 0xFF7FFFFD, 0xFF7FFFFE, 0xFF7FFFFF], np.uint32).view(np.float32),
    "SignedWord": np.array([-32768, -32767, -32766, -32765, -32764], np.int16),
    "UnsignedWord": np.array([0, 1, 2, 65534, 65535], np.uint16),
    "UnsignedByte": np.array([0, 0, 0, 255, 255], np.uint8),
}


@pytest.mark.parametrize("pixel_type", list(SPECIALS))
@pytest.mark.parametrize("byte_order", ["Lsb", "Msb"])
@pytest.mark.parametrize("fmt", ["Tile", "BandSequential"])
def test_synthetic_layouts(tmp_path: Path, pixel_type: str, byte_order: str, fmt: str) -> None:
    """7 x 5 x 2 cube in 3 x 2 tiles (partial edge tiles padded), specials in band 2, Base/Multiplier."""
    rng = np.random.default_rng(3)
    stored = rng.integers(10, 200, size=(2, 5, 7)).astype(SPECIALS[pixel_type].dtype)
    stored[1, 0, :5] = SPECIALS[pixel_type]
    base, mult = (0.0, 1.0) if pixel_type == "Real" else (-3.5, 0.25)
    path = write_cube(tmp_path / "s.cub", stored, pixel_type, byte_order, fmt, base=base, multiplier=mult)
    cube = open_cube(path)
    assert (cube.samples, cube.lines, cube.bands, cube.core_format) == (7, 5, 2, fmt)
    for band in (1, 2):
        image, valid = read_pixels(cube, band)
        expect = stored[band - 1].astype(np.float64)
        ok = np.ones((5, 7), bool)
        if band == 2:
            ok[0, :5] = False
        np.testing.assert_array_equal(valid, ok)
        np.testing.assert_allclose(image[ok], (base + mult * expect)[ok])
        _assert_same_as_gdal(path, band)
    want = {"Real": [1, 1, 1, 1, 1], "SignedWord": [1, 1, 1, 1, 1], "UnsignedWord": [1, 1, 1, 1, 1],
            "UnsignedByte": [3, 0, 0, 0, 2]}[pixel_type]
    assert list(special_pixel_counts(cube, 2).values()) == want


def test_real_nan_is_special_like_isis(tmp_path: Path) -> None:
    stored = np.array([[[1.0, np.nan, -np.inf, 2.0]]], np.float32)
    image, valid = read_pixels(open_cube(write_cube(tmp_path / "n.cub", stored, tile=(4, 1))))
    np.testing.assert_array_equal(valid, [[True, False, False, True]])
    assert special_pixel_counts(open_cube(tmp_path / "n.cub"))["Lrs"] == 2  # ISIS: below VALID_MIN4 -> Lrs


@pytest.mark.parametrize("edit, fault", [
    ({"pixel_type": "SignedInteger"}, "pixel type 'SignedInteger' is not supported"),
    ({"fmt": "Interleaved"}, "core format 'Interleaved'"),
    ({"start_byte": 2049, "truncate": 100}, "truncated"),
])
def test_bad_cubes_raise_cube_error(tmp_path: Path, edit: dict, fault: str) -> None:
    path = tmp_path / "bad.cub"
    truncate = edit.pop("truncate", 0)
    ptype = edit.pop("pixel_type", "Real")
    write_cube(path, np.zeros((1, 4, 4), np.float32), **edit)
    if ptype != "Real":
        path.write_bytes(path.read_bytes().replace(b"Type       = Real", f"Type = {ptype}".encode().ljust(17)))
    if truncate:
        path.write_bytes(path.read_bytes()[:-truncate])
    with pytest.raises(CubeError, match=fault) as err:
        open_cube(path)
    assert str(path) in str(err.value) and isinstance(err.value, GeometryError)


def test_not_a_cube_and_missing_file(tmp_path: Path) -> None:
    png = tmp_path / "x.cub"
    png.write_bytes(b"\x89PNG\r\n" + b"\0" * 100)
    with pytest.raises(CubeError, match="not an ISIS3 cube"):
        open_cube(png)
    with pytest.raises(CubeError, match="cannot be read"):
        open_cube(tmp_path / "absent.cub")
    pvl_only = tmp_path / "y.cub"
    pvl_only.write_bytes(b"Object = Something\n  A = 1\nEnd_Object\nEnd\n")
    with pytest.raises(CubeError, match="no IsisCube"):
        open_cube(pvl_only)


def test_band_out_of_range(tmp_path: Path) -> None:
    cube = open_cube(write_cube(tmp_path / "b.cub", np.zeros((2, 3, 3), np.float32)))
    for band in (0, 3):
        with pytest.raises(CubeError, match=r"band .* does not exist"):
            read_pixels(cube, band)
