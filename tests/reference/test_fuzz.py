"""Fuzzing the readers: mutated or truncated SHADR tables and shot CSVs give a valid result or a
ReferenceDataError naming the file, never another exception, never a hang.

``MERCURY_DEM_FUZZ_EXAMPLES`` sets the number of inputs per mutating test (default 500, 2-8 s);
the cut-anywhere test of the 1.4 MB table runs a hundredth of it (at least 5)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.reference.lola import AltimetryShots, read_altimetry_csv
from mercury_dem.reference.sha import ShapeHarmonics, read_shadr

from .conftest import LOLA_DIR, SHA_TAB

pytestmark = pytest.mark.timeout(60)

EXAMPLES = int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "500"))

# A degree-6 SHADR table: the real header (degree rewritten) and the real first 28 rows, so each
# example parses in well under a millisecond.
_SHA_LINES = SHA_TAB.read_bytes().split(b"\r\n")
_SHA_SMALL = b"\r\n".join([_SHA_LINES[0].replace(b"  150,  150,", b"    6,    6,"), *_SHA_LINES[1:29]]) + b"\r\n"
_LOLA_HEAD = LOLA_DIR / "lidarPoints_head.csv"
# The real shots when the shared folder is there, else three rows in the same layout.
_CSV = (
    _LOLA_HEAD.read_bytes()[:4000]
    if _LOLA_HEAD.exists()
    else b"2010-01-27T06:19:47.01382601,  99.0636769,  60.0187875, 1734.913521,   56.906246,    24.820,"
    b"    0.0328,    10, 25.87, 49.23,   0,4, 25,  19235960, 0.9025116784, 317845253.197826028,    2.640677,"
    b"     8.589,  99.0812678,  60.0160924, 1791.819609,1736.94373,   0.264,   0.272,  76.587,  76.811,"
    b" 0.0000000000,   0.000,   2.962\n" * 3
)
_HEADER_CSV = b"UTC,Pt_Longitude,PT_LATITUDE,pt_radius,Flg\n" + b"".join(
    b"2011-04-01T00:00:%06.3f,%.3f,45.0,2438.0%02d,0\n" % (0.125 * i, 10 + 0.01 * i, i) for i in range(20)
)
# The MLA RDR header (altitude in km above 2440 km, the channel as the quality mark), made-up values.
_MLA_CSV = b"geoc_long,geoc_lat,altitude,EphemerisTime,MET,frm,chn,UTC,TOF_ns_ET,Sat_long,Sat_lat,Sat_alt\n" + b"".join(
    b"%.4f,%.4f,%.5f,%.6f,%d,%d,%d,2012-06-01T07:03:%06.3f,%.1f,%.4f,%.4f,%.3f\n"
    % (100.0 + 1e-3 * i, 70.0 + 0.007 * i, -1.2 + 0.001 * i, 3.9e8 + 0.125 * i, 250000000 + i // 8, i % 8, i % 6,
       47.0 + 0.125 * i, 2.7e6, 100.0 + 1e-3 * i, 70.0 + 0.007 * i, 400.0) for i in range(20)
)


@st.composite
def _mutated(draw, base: bytes) -> bytes:
    """Truncate, then apply a few byte substitutions, deletions, insertions and line swaps."""
    data = bytearray(base[: draw(st.integers(0, len(base)))] if draw(st.booleans()) else base)
    for _ in range(draw(st.integers(0, 6))):
        op = draw(st.sampled_from(["sub", "del", "ins", "dup_line", "digit"]))
        if not data and op != "ins":
            continue
        i = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "sub":
            data[i] = draw(st.integers(0, 255))
        elif op == "del":
            del data[i : i + draw(st.integers(1, 40))]
        elif op == "ins":
            data[i:i] = draw(st.sampled_from([b",", b"\n", b"nan", b"-", b"9" * 30, b"e400", b"\x00", b"\xff", b" "]))
        elif op == "digit":
            data[i] = ord(str(draw(st.integers(0, 9))))
        else:
            lines = bytes(data).split(b"\n")
            j = draw(st.integers(0, len(lines) - 1))
            lines.insert(j, lines[j])
            data = bytearray(b"\n".join(lines))
    return bytes(data)


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("reference_fuzz")


def _write(folder: Path, name: str, data: bytes) -> Path:
    path = folder / name
    path.write_bytes(data)
    return path


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_mutated(_SHA_SMALL))
def test_fuzz_shadr(fuzz_dir, data):
    path = _write(fuzz_dir, "fuzz_shape.tab", data)
    try:
        sh = read_shadr(path)
    except ReferenceDataError as exc:
        assert "fuzz_shape.tab" in str(exc)
        return
    assert isinstance(sh, ShapeHarmonics)
    assert np.all(np.isfinite(sh.c_m)) and sh.c_m.shape == (sh.lmax + 1, sh.lmax + 1)


@settings(max_examples=max(5, EXAMPLES // 100), deadline=None)
@given(st.integers(0, 1_400_315))
def test_fuzz_truncated_real_shadr(fuzz_dir, cut):
    """The real 1.4 MB table cut anywhere: only a cut in the final padding still reads."""
    path = _write(fuzz_dir, "cut_shape.tab", SHA_TAB.read_bytes()[:cut])
    try:
        sh = read_shadr(path)
    except ReferenceDataError as exc:
        assert "cut_shape.tab" in str(exc)
    else:
        assert sh.lmax == 150


@settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.one_of(_mutated(_CSV), _mutated(_HEADER_CSV), _mutated(_MLA_CSV)))
def test_fuzz_altimetry_csv(fuzz_dir, data):
    path = _write(fuzz_dir, "fuzz_shots.csv", data)
    try:
        shots = read_altimetry_csv(path, 1_737_400.0 if data[:4] not in (b"UTC,", b"geoc") else 2_439_400.0)
    except ReferenceDataError as exc:
        assert "fuzz_shots.csv" in str(exc)
        return
    assert isinstance(shots, AltimetryShots)
    t = shots.table
    assert shots.n_rows == len(t) + sum(shots.dropped.values())
    if len(t):
        assert np.all(np.isfinite(t[["lat", "lon", "radius_m"]].to_numpy()))
        assert t["lon"].between(0.0, 360.0, inclusive="left").all()
        assert t["profile_id"].is_monotonic_increasing
