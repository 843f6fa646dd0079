"""Fuzzing the cube reader with mutated real cubes: a result or a CubeError naming the file, nothing else.

Mutations: label lines deleted, duplicated or given another value (numbers huge, negative, NaN,
broken PVL), the file truncated anywhere, bytes flipped in the label or in the tables. Every
reader is run on each input. ``MERCURY_DEM_FUZZ_EXAMPLES`` raises the number of inputs (default
150, about 8 s here; 3,000 ran clean in 165 s); a fixed seed corpus of inputs that broke earlier
versions or probe the size guards runs first (``@example``).
"""

from __future__ import annotations

import os
import struct
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, example, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from mercury_dem.exceptions import CubeError  # noqa: E402
from mercury_dem.sources import (  # noqa: E402
    alpha_cube,
    cube_spice,
    isis_serial_number,
    naif_keywords,
    open_cube,
    read_pixels,
    read_table,
    special_pixel_counts,
    table_names,
)
from tests.sources.cubes import APOLLO_0297, MDIS_SPICE  # noqa: E402

BASES = {"mdis": MDIS_SPICE.read_bytes(), "apollo": APOLLO_0297.read_bytes()}
#: Where the tables start in each base cube (0-based; the label says 1114113 and 1065537).
TABLES_FROM = {"mdis": 1114112, "apollo": 1065536}
VALUES = ["0", "-1", "-65537", "99999999999999999999", "1e308", "-1e308", "NaN", "nan", "inf", "-inf",
          "abc", '"', "(", "(1, 2", ")", "{", "16#FF#", "", "Null", "2147483648", "1.5", "Msb", "Lsb", "Tile",
          "BandSequential", "SignedWord", "UnsignedByte", "UnsignedWord", "Real", "End", "End_Object",
          "(0.0, 1.0)", "1 <MS>", "IsisCube", "TRUE", "-0.0", "4a1edaaeddcbbc41"]
COUNT = {"inputs": 0, "opened": 0, "errors": 0}


def _edit(name: str, old: str, new: str) -> bytes:
    """A base cube with one label edit, zero padding kept (for the fixed seed corpus)."""
    data = BASES[name]
    end = data.index(b"\nEnd\n") + 5
    label = data[:end].decode("latin-1")
    assert old in label, old
    edited = label.replace(old, new, 1).encode("latin-1")
    return edited.ljust(end, b"\0") + data[end:] if len(edited) <= end else edited + data[len(edited):]


def _table_value(name: str, table: str, field: str, value: float) -> bytes:
    """A base cube whose table ``table`` has ``field`` of its first record set to ``value`` (little-endian double;
    every table holding the same double gets it too: the tables share their ET)."""
    from mercury_dem.sources import open_cube, read_table

    path = {"mdis": MDIS_SPICE, "apollo": APOLLO_0297}[name]
    old = struct.pack("<d", float(read_table(open_cube(path), table).columns[field][0]))
    data = BASES[name]
    assert data.count(old) >= 1, (table, field)
    return data.replace(old, struct.pack("<d", value))


#: Inputs that broke earlier versions or probe a guard before an allocation.
SEEDS = [
    _edit("mdis", "      Samples = 512", "      Samples = 1000000000000"),  # core far beyond the file
    _edit("mdis", "TileLines   = 512", "TileLines   = 0"),
    _edit("mdis", "Type       = Real", "Type       = SignedWord\n      Base = 1e300\n"),  # float32 overflow
    _edit("mdis", "Name = J2000Q1", "Name = \"\""),  # empty field name (numpy needs field names)
    _edit("mdis", "Name = AV1", "Name = J2000Q0"),  # duplicate field name
    _edit("mdis", "Records             = 1", "Records             = 100000000000"),
    _edit("mdis", "4a1edaaeddcbbc41", "zz"),  # unreadable clock ET: falls back to the CK midpoint
    _edit("mdis", "ConstantRotation    = (0.001686595916635,", "ConstantRotation    = (abc,"),
    _edit("apollo", "AlphaEndingSample   = 15984.5", "AlphaEndingSample   = 7996.5"),
    _edit("apollo", "BetaSamples         = 500", "BetaSamples         = NaN"),
    _edit("apollo", 'ObservationType  = Nadir', 'ObservationType  = "Nadir'),  # unterminated quote
    BASES["mdis"][: 1114113 + 30],  # truncated inside the first table
    # An aggregation with no name: pvl's permissive parser did not return on it (CI hung for 90 min).
    _edit("mdis", "Object = Table\n  Name                 = InstrumentPosition",
          "Object = \n  Name                 = InstrumentPosition"),
    _edit("mdis", "End_Group", "End_Object"),  # aggregations that do not nest
    # Finite table values near 1e300 (a flipped exponent byte) overflowed in the arithmetic (RuntimeWarning):
    # found at 2000 inputs, --hypothesis-seed 2026, in a quaternion; positions and ET the same way.
    _table_value("mdis", "BodyRotation", "J2000Q0", 1.17521625e180),
    _table_value("mdis", "InstrumentPosition", "J2000X", 1e300),
    _table_value("mdis", "InstrumentPosition", "J2000XV", -1e300),
    _table_value("mdis", "SunPosition", "ET", 1e300),  # the ET of every table
]


#: A failing input here is a whole cube (~1 MB): printing it made hypothesis warn "Generating overly large repr",
#: which the suite's warnings-as-errors turned into the reported failure, hiding the real one (the 2000-input run
#: of 2026-11-26 with --hypothesis-seed 2026). The warning is ignored in this module; the blob replays the input.
pytestmark = pytest.mark.filterwarnings("ignore:Generating overly large repr")


def _label_end(data: bytes) -> int:
    return data.index(b"\nEnd\n") + 5


@st.composite
def mutated_cube(draw: st.DrawFn) -> bytes:
    name = draw(st.sampled_from(sorted(BASES)))
    data = BASES[name]
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["delete", "duplicate", "value", "truncate", "flip_tables", "flip_label"]))
        end = _label_end(data) if b"\nEnd\n" in data[:200000] else 0
        if op in ("delete", "duplicate", "value") and end:
            lines = data[:end].decode("latin-1").split("\n")
            i = draw(st.integers(0, len(lines) - 1))
            if op == "delete":
                del lines[i]
            elif op == "duplicate":
                lines.insert(i, lines[i])
            elif "=" in lines[i]:
                value = draw(st.one_of(st.sampled_from(VALUES), st.integers(-2**63, 2**63).map(str)))
                lines[i] = lines[i].split("=", 1)[0] + "= " + value
            new = "\n".join(lines).encode("latin-1")
            data = new.ljust(end, b"\0") + data[end:] if len(new) <= end else new + data[len(new):]
        elif op == "truncate" and data:
            data = data[: draw(st.integers(0, len(data) - 1))]
        elif op in ("flip_tables", "flip_label"):
            lo, hi = (TABLES_FROM[name], len(data)) if op == "flip_tables" else (0, min(max(end, 1), len(data)))
            if lo >= hi:
                continue
            buf = bytearray(data)
            flips = st.lists(st.tuples(st.integers(lo, hi - 1), st.integers(0, 255)), min_size=1, max_size=8)
            for pos, byte in draw(flips):
                buf[pos] = byte
            data = bytes(buf)
    return data


def exercise(path: Path) -> None:
    """Every reader on ``path``: results or CubeErrors that name the file."""
    COUNT["inputs"] += 1
    try:
        cube = open_cube(path)
    except CubeError as exc:
        assert str(path) in str(exc)
        COUNT["errors"] += 1
        return
    COUNT["opened"] += 1
    calls = [lambda: read_pixels(cube), lambda: special_pixel_counts(cube), lambda: naif_keywords(cube),
             lambda: alpha_cube(cube), lambda: cube_spice(cube), lambda: isis_serial_number(cube.label, str(path))]
    calls += [lambda n=n: read_table(cube, n) for n in table_names(cube)]
    for call in calls:
        try:
            call()
        except CubeError as exc:
            assert str(path) in str(exc), str(exc)


@pytest.fixture(scope="module")
def fuzz_path() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="cube_fuzz_") as d:
        yield Path(d) / "fuzzed_case.cub"


@pytest.mark.integration  # 60 mutated real cubes + 18 recorded seeds (3 s of CPU): the fast loop keeps the other readers' fuzzing
@settings(max_examples=int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "60")), deadline=None, database=None,
          print_blob=True, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=mutated_cube())
@example(data=SEEDS[0])
@example(data=SEEDS[1])
@example(data=SEEDS[2])
@example(data=SEEDS[3])
@example(data=SEEDS[4])
@example(data=SEEDS[5])
@example(data=SEEDS[6])
@example(data=SEEDS[7])
@example(data=SEEDS[8])
@example(data=SEEDS[9])
@example(data=SEEDS[10])
@example(data=SEEDS[11])
@example(data=SEEDS[12])
@example(data=SEEDS[13])
@example(data=SEEDS[14])
@example(data=SEEDS[15])
@example(data=SEEDS[16])
@example(data=SEEDS[17])
def test_mutated_cubes_give_results_or_cube_errors(fuzz_path: Path, data: bytes) -> None:
    fuzz_path.write_bytes(data)
    exercise(fuzz_path)


def test_unmutated_bases_read_fully(tmp_path: Path) -> None:
    for name, data in BASES.items():
        path = tmp_path / f"{name}.cub"
        path.write_bytes(data)
        cube_spice(open_cube(path))
        assert len(table_names(open_cube(path))) >= 4


@pytest.mark.parametrize("k", [14, 15, 17])  # 16: a velocity of a one-record table is never used
def test_huge_table_values_are_cube_errors(tmp_path: Path, k: int) -> None:
    """The table seeds above: a CubeError naming the file and the damaged table, not an overflow warning."""
    path = tmp_path / "damaged.cub"
    path.write_bytes(SEEDS[k])
    with pytest.raises(CubeError, match="table .* (holds|covers)") as err:
        cube_spice(open_cube(path))
    assert str(path) in str(err.value)
