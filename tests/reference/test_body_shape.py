"""The bodies' packaged shapes (GTMES for Mercury, LOLA LDEM_4 reduced for the Moon), the reader of
the lunar cube (known values, fuzzing), and the check of a DEM against its body's shape."""

from __future__ import annotations

import hashlib
import os
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.geometry.body import MERCURY, MOON
from mercury_dem.reference.body_shape import (
    LUNAR_SHAPE_PACKAGED,
    body_shape,
    read_shape_cube,
    shape_check,
    truth_shape,
)
from mercury_dem.pipeline.reference_check import shape_check_lines

ROOT = Path(__file__).resolve().parents[2]
LDEM_SHA256 = "4d6e40bdf778c837a9f30a178b74e0db2c6111dc3a7a51a5a2e60ea6544d7b65"  # tests/data/real/SOURCE.md
EXAMPLES = int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "150"))
_BASE = LUNAR_SHAPE_PACKAGED.read_bytes()
_LABEL_END = _BASE.index(b"\nEnd\n") + 5


def test_packaged_lunar_shape_is_the_tested_copy_and_in_the_wheel() -> None:
    assert hashlib.sha256(_BASE).hexdigest() == LDEM_SHA256
    assert (ROOT / "tests/data/real/ldem_4_reduced.cub").read_bytes() == _BASE
    data = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]
    assert "data/*.cub" in data["mercury_dem.reference"]
    assert "ldem_4_reduced.cub" in (LUNAR_SHAPE_PACKAGED.parent / "README.md").read_text()


def test_lunar_shape_known_values() -> None:
    # README (tests/data/real/SOURCE.md, docs/design/reference.md): radius = 1737400 + 0.5 DN m,
    # heights -7811 ... +9141 m, 0.75 deg pixels, centres 89.6250283 deg (the label's rounded resolution)
    g = read_shape_cube(LUNAR_SHAPE_PACKAGED)
    assert g.shape == (240, 480) and g.attrs["datum_radius_m"] == 1737400.0 and g.attrs["multiplier"] == 0.5
    assert float(g.min()) == -7811.0 and float(g.max()) == 9141.0
    assert g["lat"].values[0] == pytest.approx(89.6250283, abs=1e-6) and np.all(np.diff(g["lat"].values) < 0)
    assert g["lon"].values[0] == pytest.approx(0.375, abs=1e-3) and np.all(np.diff(g["lon"].values) > 0)
    from mercury_dem.reference.lola import read_lola_ldem  # the GDAL reader of user-named LDEMs agrees

    gd = read_lola_ldem(LUNAR_SHAPE_PACKAGED)
    assert np.array_equal(gd.values, g.values) and np.allclose(gd["lon"], g["lon"]) and np.allclose(gd["lat"], g["lat"])


def test_body_shapes() -> None:
    moon, mercury = body_shape("MOON"), body_shape("mercury")
    assert moon is not None and mercury is not None and body_shape("MARS") is None
    assert moon.reference_radius_m == MOON.datum_radius_m and mercury.reference_radius_m == MERCURY.datum_radius_m
    # Apollo 15 Metric 0297's area (ISIS's CameraStatistics with a LOLA shape: radii 1735-1744 km)
    r = moon.radius_m(np.array([-20.0]), np.array([145.0]))
    assert 1_733_000 < r[0] < 1_745_000
    # GTMES against the pyshtools oracle points within the grid's interpolation error (0.25 deg, degree 148)
    pts = np.genfromtxt(ROOT / "tests/data/real/gtmes150v05_l148_oracle_points.csv", delimiter=",", names=True)
    cols = pts.dtype.names
    h = mercury.radius_m(pts[cols[0]], pts[cols[1]]) - 2_439_400.0
    assert np.sqrt(np.mean((h - pts[cols[2]]) ** 2)) < 30.0
    xyz = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]) * 2e6
    assert np.allclose(mercury.radius_at_xyz(xyz), mercury.radius_m([90.0, 0.0], [0.0, 0.0]))


def _moon_block(datum_radius_m: float) -> xr.DataArray:
    """A 2 x 2 deg Moon block at the Apollo strip whose radii are the shape's plus 300 m of 'relief',
    stored as heights above ``datum_radius_m``."""
    moon = body_shape("MOON")
    assert moon is not None
    lat = np.linspace(-19.0, -21.0, 41)
    lon = np.linspace(144.0, 146.0, 41)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    relief = 300.0 * np.sin(np.radians(la) * 40) * np.cos(np.radians(lo) * 40)
    elev = moon.radius_m(la, lo) + relief - datum_radius_m
    return xr.DataArray(elev, dims=("lat", "lon"), coords={"lat": lat, "lon": lon})


def test_shape_check_passes_a_right_dem_and_names_a_wrong_datum() -> None:
    moon = body_shape("MOON")
    good = shape_check(_moon_block(MOON.datum_radius_m), body_name="MOON", datum_radius_m=MOON.datum_radius_m,
                       shape=moon)
    assert good["status"] == "ok" and abs(good["bias_m"]) <= 300 and good["by_latitude"]  # the relief's mean
    # A Moon block gridded with Mercury's datum: heights ~ -702 km, compared on the Moon's datum
    bad = shape_check(_moon_block(MERCURY.datum_radius_m), body_name="MOON", datum_radius_m=MOON.datum_radius_m,
                      shape=moon)
    assert bad["status"] == "gross_error" and bad["bias_m"] == pytest.approx(-702_000, abs=1000)
    assert "Mercury's datum" in bad["cause"] and "wrong datum radius" in bad["cause"]
    text = "\n".join(shape_check_lines(bad))
    assert "ERROR" in text and "-702.2 km" in text and "3 km" in text
    km = shape_check(_moon_block(MOON.datum_radius_m) * 1000.0, body_name="MOON",
                     datum_radius_m=MOON.datum_radius_m, shape=moon)
    assert km["status"] == "gross_error" and "units" in km["cause"]
    none = shape_check(_moon_block(MOON.datum_radius_m), body_name="MARS", datum_radius_m=3_396_190.0, shape=None)
    assert none["status"] == "not_compared" and "no packaged shape model of Mars" in shape_check_lines(none)[0]


def test_a_synthetic_missions_truth_is_its_shape() -> None:
    """A synthetic body has no packaged shape: its truth DEM (regional, longitudes across 0) is the shape,
    so a synthetic DEM on the wrong datum is a gross error too, and a right one (its truth plus noise) is not."""
    rng = np.random.default_rng(3)
    lat = np.arange(19.9375, -10.0, -0.125)
    lon = np.arange(-14.9375, 15.0, 0.125)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    truth = 1500.0 * np.sin(np.radians(la) * 30) * np.cos(np.radians(lo) * 20)
    truth_da = xr.DataArray(truth, dims=("lat", "lon"), coords={"lat": lat, "lon": lon},
                            attrs={"datum_radius_m": MOON.datum_radius_m})
    shape = truth_shape(truth_da, body_name="moon", source="truth/dem.zarr")
    assert shape.body == "MOON" and "8 px/deg" in shape.name
    inner = (slice(8, -8), slice(8, -8))
    dem = xr.DataArray((truth + rng.normal(0, 50.0, truth.shape))[inner], dims=("lat", "lon"),
                       coords={"lat": lat[inner[0]], "lon": np.mod(lon[inner[1]], 360.0)})
    good = shape_check(dem, body_name="MOON", datum_radius_m=MOON.datum_radius_m, shape=shape)
    assert good["status"] == "ok" and abs(good["bias_m"]) < 5.0 and 40.0 < good["rmse_m"] < 60.0
    wrong = dem + (MOON.datum_radius_m - MERCURY.datum_radius_m)  # radii minus Mercury's datum
    bad = shape_check(wrong, body_name="MOON", datum_radius_m=MOON.datum_radius_m, shape=shape)
    assert bad["status"] == "gross_error" and "Mercury's datum" in bad["cause"]


@st.composite
def _mutated_cube(draw: st.DrawFn) -> bytes:
    data = _BASE
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["delete", "duplicate", "value", "truncate", "flip_pixels", "flip_label"]))
        end = data.index(b"\nEnd\n") + 5 if b"\nEnd\n" in data[:70000] else 0
        if op in ("delete", "duplicate", "value") and end:
            lines = data[:end].decode("latin-1").split("\n")
            i = draw(st.integers(0, len(lines) - 1))
            if op == "delete":
                del lines[i]
            elif op == "duplicate":
                lines.insert(i, lines[i])
            elif "=" in lines[i]:
                value = draw(st.sampled_from(["0", "-1", "1e308", "NaN", "abc", "(", "", "0.5", "2.0", "1000.0",
                                              "360.0", "-5458204.8 <meters>", "Equirectangular", "Planetographic",
                                              "PositiveWest", "Real", "UnsignedByte", "Msb", "22742.52",
                                              "1737400.0", "2439400.0", "180"]))
                lines[i] = lines[i].split("=", 1)[0] + "= " + value
            new = "\n".join(lines).encode("latin-1")
            data = new.ljust(end, b"\0") + data[end:] if len(new) <= end else new + data[len(new):]
        elif op == "truncate" and data:
            data = data[: draw(st.integers(0, len(data) - 1))]
        elif op in ("flip_pixels", "flip_label"):
            lo, hi = (65536, min(len(data), 65536 + 480 * 240 * 2)) if op == "flip_pixels" else (0, max(end, 1))
            if lo >= min(hi, len(data)):
                continue
            buf = bytearray(data)
            for pos, byte in draw(st.lists(st.tuples(st.integers(lo, min(hi, len(data)) - 1), st.integers(0, 255)),
                                           min_size=1, max_size=8)):
                buf[pos] = byte
            data = bytes(buf)
    return data


@pytest.fixture(scope="module")
def fuzz_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("shape_fuzz") / "fuzzed_ldem.cub"


@pytest.mark.timeout(120)
@settings(max_examples=EXAMPLES, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture])
@given(data=_mutated_cube())
def test_fuzz_shape_cube(fuzz_path: Path, data: bytes) -> None:
    """A mutated cube gives a valid global grid or a ReferenceDataError naming the file; nothing else."""
    fuzz_path.write_bytes(data)
    try:
        g = read_shape_cube(fuzz_path)
    except ReferenceDataError as exc:
        assert str(fuzz_path) in str(exc)
        return
    v = g.values
    assert v.ndim == 2 and g.sizes["lat"] == v.shape[0] and g.sizes["lon"] == v.shape[1]
    assert np.isfinite(v).any() and np.nanmax(np.abs(v)) <= 30_000.0
    lon, lat = g["lon"].values, g["lat"].values
    assert np.all((lon >= 0) & (lon < 360)) and np.all(np.abs(lat) <= 90.5 + 1e-9) and np.isfinite(lat).all()
