"""The SHADR reader and the spherical-harmonic evaluation, against the pyshtools oracle."""

from __future__ import annotations

import math

import numpy as np
import pytest

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.reference.sha import ShapeHarmonics, evaluate, evaluate_grid, file_sha256, parse_shadr, read_shadr

from .conftest import ORACLE_POINTS, ORACLE_TIF, SHA_TAB, shared

DATUM_M = 2_439_400.0


def test_coefficient_file_is_the_pds_original():
    if not SHA_TAB.exists():
        pytest.skip(f"{SHA_TAB} is absent")
    assert file_sha256(SHA_TAB).startswith("c49d07c1")


def test_header_and_coefficients(gtmes):
    assert gtmes.lmax == 150
    assert gtmes.reference_radius_m == 2_439_400.0
    assert gtmes.normalization_state == 2
    assert gtmes.c_m.shape == (151, 151)
    # First and last rows of the table, km -> m.
    assert gtmes.mean_radius_m == pytest.approx(2439.4019745643300e3, abs=1e-6)
    assert gtmes.s_m[1, 1] == pytest.approx(0.4539511786420000e-01 * 1e3)
    assert gtmes.c_m[150, 150] == pytest.approx(-0.1234380760400000e-02 * 1e3)
    assert gtmes.c_sigma_m[0, 0] == pytest.approx(0.2996878638666667e-01 * 1e3)
    assert np.all(np.triu(gtmes.c_m, 1) == 0.0)


def test_points_match_pyshtools_oracle(gtmes):
    """408 pixels of the pyshtools degree-148 grid (tests/data/real): within 1 m (we get < 1 mm)."""
    lat, lon, h = np.loadtxt(ORACLE_POINTS, delimiter=",", skiprows=1, unpack=True)
    ours = evaluate(gtmes, lat, lon, lmax=148) - DATUM_M
    assert np.max(np.abs(ours - h)) < 1e-3  # the oracle is float32 printed to 0.1 mm


def test_grid_matches_pyshtools_oracle(gtmes):
    """The whole 720 x 360 oracle grid; pixel-is-area, so centres are half a pixel in."""
    import rasterio

    with rasterio.open(shared(ORACLE_TIF)) as ds:
        oracle = ds.read(1).astype(np.float64)
        tr = ds.transform
    lat = tr.f + tr.e * (np.arange(ds.height) + 0.5)
    lon = tr.c + tr.a * (np.arange(ds.width) + 0.5)
    assert lat[0] == 90.0 and lon[0] == 0.0 and lat[-1] == -89.5
    ours = evaluate_grid(gtmes, lat, lon, lmax=148) - DATUM_M
    assert np.max(np.abs(ours - oracle)) < 1e-3  # measured 0.23 mm: float32 rounding of the oracle


def test_grid_equals_points(gtmes):
    lats = np.array([-90.0, -33.3, 0.0, 12.0, 89.999, 90.0])
    lons = np.array([-10.0, 0.0, 123.4, 359.9, 720.0])
    grid = evaluate_grid(gtmes, lats, lons, lmax=60)
    la, lo = np.meshgrid(lats, lons, indexing="ij")
    np.testing.assert_allclose(evaluate(gtmes, la, lo, lmax=60), grid, rtol=0, atol=1e-6)
    # A pole has one radius whatever the longitude.
    assert np.ptp(grid[0]) < 1e-6 and np.ptp(grid[-1]) < 1e-6


def _single(l_: int, m_: int, c: float = 0.0, s: float = 0.0, lmax: int = 4) -> ShapeHarmonics:
    cm = np.zeros((lmax + 1, lmax + 1))
    sm = np.zeros_like(cm)
    cm[l_, m_], sm[l_, m_] = c, s
    return ShapeHarmonics(1.0, lmax, cm, sm, np.zeros_like(cm), np.zeros_like(cm))


@pytest.mark.parametrize(
    ("l_", "m_", "closed_form"),
    [
        (0, 0, lambda t, u: 1.0),
        (1, 0, lambda t, u: math.sqrt(3) * t),
        (1, 1, lambda t, u: math.sqrt(3) * u),
        (2, 0, lambda t, u: math.sqrt(5) * (3 * t * t - 1) / 2),
        (2, 1, lambda t, u: math.sqrt(15) * t * u),
        (2, 2, lambda t, u: math.sqrt(15) / 2 * u * u),
        (3, 3, lambda t, u: math.sqrt(70) / 4 * u**3),
    ],
)
def test_four_pi_normalised_legendre(l_, m_, closed_form):
    """Closed forms of the 4π-normalised functions (no Condon-Shortley phase)."""
    lat = np.array([-70.0, -5.0, 0.0, 30.0, 88.0])
    got = evaluate(_single(l_, m_, c=1.0), lat, np.zeros_like(lat), lmax=None)
    t, u = np.sin(np.radians(lat)), np.cos(np.radians(lat))
    np.testing.assert_allclose(got, [closed_form(a, b) for a, b in zip(t, u, strict=True)], rtol=1e-12, atol=1e-14)


def test_normalisation_integral_is_four_pi():
    """∫ Y² dΩ = 4π for a high-degree harmonic (Gauss-Legendre in latitude)."""
    x, w = np.polynomial.legendre.leggauss(140)
    lat = np.degrees(np.arcsin(x))
    lon = np.arange(0.0, 360.0, 360.0 / 256)
    for l_, m_ in [(37, 0), (60, 17), (120, 119)]:
        y = evaluate_grid(_single(l_, m_, c=1.0, lmax=120), lat, lon, lmax=None)
        integral = np.sum(w[:, None] * y**2) * (2 * np.pi / lon.size)
        assert integral == pytest.approx(4 * np.pi, rel=1e-10)


def test_sine_term_and_longitude_sign():
    sh = _single(3, 2, s=1.0)
    a = evaluate(sh, 20.0, 30.0, lmax=None)
    b = evaluate(sh, 20.0, -30.0, lmax=None)
    assert a == pytest.approx(-b) and a != 0.0


def test_lmax_out_of_range(gtmes):
    with pytest.raises(ValueError, match="lmax"):
        evaluate(gtmes, 0.0, 0.0, lmax=151)


def test_nan_points_give_nan(gtmes):
    r = evaluate(gtmes, [np.nan, 10.0, 91.0], [0.0, np.nan, 0.0], lmax=10)
    assert np.all(np.isnan(r))


def _table(rows: list[str], degree: int = 1) -> str:
    head = f"2.4394E+03, 1.0E+00, 0.0E+00, {degree:4d}, {degree:4d},    2, 0.0E+00, 0.0E+00"
    return "\r\n".join([head, *rows]) + "\r\n"


GOOD_ROWS = ["0, 0, 2439.4, 0.0, 0.01, 0.0", "1, 0, 0.1, 0.0, 0.01, 0.0", "1, 1, 0.2, 0.3, 0.01, 0.01"]


def test_parse_small_table():
    sh = parse_shadr(_table(GOOD_ROWS))
    assert sh.lmax == 1 and sh.c_m[1, 1] == pytest.approx(200.0) and sh.s_m[1, 1] == pytest.approx(300.0)


@pytest.mark.parametrize(
    ("rows", "message"),
    [
        (GOOD_ROWS[:2], "truncated"),
        ([*GOOD_ROWS[:2], "1, 0, 0.1, 0.0, 0.01, 0.0"], "repeated"),
        ([*GOOD_ROWS[:2], "1, 2, 0.2, 0.3, 0.01, 0.01"], "outside"),
        ([*GOOD_ROWS[:2], "1, 1, nan, 0.3, 0.01, 0.01"], "nan"),
        ([*GOOD_ROWS[:2], "1, 1, 0.2x, 0.3, 0.01, 0.01"], "not a number"),
        ([*GOOD_ROWS[:2], "1, 1, 0.2, 0.3, 0.01"], "fields"),
    ],
)
def test_bad_tables_name_file_and_line(rows, message):
    with pytest.raises(ReferenceDataError, match=message) as err:
        parse_shadr(_table(rows), source="shape.tab")
    assert "shape.tab" in str(err.value)


def test_unreadable_file_names_it(tmp_path):
    with pytest.raises(ReferenceDataError, match="missing.tab"):
        read_shadr(tmp_path / "missing.tab")
    bad = tmp_path / "binary.tab"
    bad.write_bytes(b"\xff\xfe" + _table(GOOD_ROWS).encode())
    with pytest.raises(ReferenceDataError, match="binary.tab.*not ASCII"):
        read_shadr(bad)


def test_matches_pyshtools_when_installed(gtmes):
    """Direct oracle: pyshtools' own expansion at a few points (skipped unless installed)."""
    pysh = pytest.importorskip("pyshtools", exc_type=ImportError)
    lat = np.array([-75.0, -12.5, 0.0, 33.3, 80.0])
    lon = np.array([5.0, 100.0, 200.0, 300.0, 359.0])
    clm = pysh.SHCoeffs.from_array(np.stack([gtmes.c_m, gtmes.s_m]), normalization="4pi", csphase=1)
    theirs = clm.expand(lat=lat, lon=lon, lmax_calc=148)
    np.testing.assert_allclose(evaluate(gtmes, lat, lon, lmax=148), theirs, rtol=0, atol=1e-6)
