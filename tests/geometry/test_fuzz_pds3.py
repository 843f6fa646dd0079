"""Fuzzing the PDS3 label reader (:func:`parse_pds3_label`, :func:`label_values`) and its use by
``mercury-dem geometry --label``: any label text gives a dict (finite values) or, in the command,
IsdError naming the label file; never another exception or a warning.

Seed: a short synthetic MDIS-like label (values from EN1072174528M_pds3.lbl, which lives
only in ../shared). ``MERCURY_DEM_FUZZ_EXAMPLES`` raises the number of inputs (default 200, ~3 s).
"""

from __future__ import annotations

import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from mercury_dem.commands.geometry import _label_run
from mercury_dem.exceptions import IsdError
from mercury_dem.geometry.caminfo import label_values, parse_pds3_label
from mercury_dem.geometry.isd import read_isd
from tests.fuzzing import mutate_lines

ISD = Path(__file__).resolve().parents[1] / "data" / "real" / "EN1072174528M_ale_isd.json"

SEED = """PDS_VERSION_ID = PDS3
/* geometry of EN1072174528M (abridged) */
MISSION_NAME                 = MESSENGER
INSTRUMENT_NAME              = "MERCURY DUAL IMAGING SYSTEM NARROW ANGLE
                                CAMERA"
RIGHT_ASCENSION              = 166.36588 <DEG>
DECLINATION                  = -43.07155 <DEG>
RA_DEC_REF_PIXEL             = (256.00000, 256.00000)
TARGET_CENTER_DISTANCE       = 2466.63167 <KM>
SLANT_DISTANCE               = 27.62593 <KM>
CENTER_LATITUDE              = 46.26998 <DEG>
CENTER_LONGITUDE             = 248.17066 <DEG>
HORIZONTAL_PIXEL_SCALE       = 1.40755 <M>
RETICLE_POINT_LATITUDE       = (46.27574, 46.28052, 46.25946, 46.26440) <DEG>
RETICLE_POINT_LONGITUDE      = (248.15510, 248.17933, 248.16185,
                                248.18619) <DEG>
SUB_SPACECRAFT_LATITUDE      = 46.31528 <DEG>
SUB_SPACECRAFT_LONGITUDE     = 248.41010 <DEG>
SPACECRAFT_ALTITUDE          = 26.63167 <KM>
SUB_SOLAR_LATITUDE           = 0.03430 <DEG>
SUB_SOLAR_LONGITUDE          = 180.75406 <DEG>
INCIDENCE_ANGLE              = 74.58267 <DEG>
PHASE_ANGLE                  = 90.08323 <DEG>
EMISSION_ANGLE               = 15.50437 <DEG>
FILTER_NUMBER                = N/A
OBJECT = IMAGE
  LINES = 512
END_OBJECT = IMAGE
GROUP = SUBFRAME1_PARAMETERS
  RETICLE_POINT_LONGITUDE = (N/A, N/A, N/A, N/A)
END_GROUP = SUBFRAME1_PARAMETERS
END
"""
TOKENS = ("nan", "NaN", "inf", "-inf", "1e400", "-1e400", "0", "-2466.6", "1e308", "N/A", "(", ")", "((1))",
          '"', "/*", "*/", "=", "END", "OBJECT = X", "END_OBJECT", "<KM>", "(1,", ",)", "()", "(,)", "\x00", "\ufffd")


def _edit_label(draw: st.DrawFn, how: str, lines: list[str], i: int) -> list[str]:
    key = lines[i].split("=", 1)[0]
    if how == "value":
        lines[i] = f"{key}= {draw(st.sampled_from(TOKENS) | st.text(max_size=8))}"
    elif how == "insert":
        lines.insert(i, draw(st.sampled_from(TOKENS)))
    elif how == "text":
        lines[i] = draw(st.text(max_size=30))
    else:
        depth = draw(st.integers(1, 5000))
        lines[i] = f"{key}= " + "(" * depth + "1" + ")" * depth
    return lines


@st.composite
def mutated_label(draw: st.DrawFn) -> str:
    return mutate_lines(draw, SEED, ("value", "insert", "text", "deep"), _edit_label)


@pytest.fixture(scope="module")
def geometry():
    return read_isd(ISD)


@pytest.fixture(scope="module")
def fuzz_path() -> Iterator[Path]:
    with tempfile.TemporaryDirectory(prefix="pds3_fuzz_") as d:
        yield Path(d) / "fuzzed_pds3.lbl"


def test_seed_label(geometry, fuzz_path: Path) -> None:
    fuzz_path.write_text(SEED)
    lab, info, rows, centre = _label_run(geometry, str(fuzz_path))
    assert lab["radius_m"] == pytest.approx(2440e3, abs=1e-3) and centre == (255.0, 255.0)
    assert all(r.ok for r in rows if r.ok is not None)


@settings(max_examples=int(os.environ.get("MERCURY_DEM_FUZZ_EXAMPLES", "200")), deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(text=mutated_label())
@example(text=SEED)
@example(text=SEED.replace("(46.27574,", "(" * 3000 + "1" + ")" * 3000 + " (46.27574,"))  # was: RecursionError
@example(text=SEED.replace("46.26998", "nan"))  # was: NaN passed on as a label value
@example(text=SEED.replace("2466.63167", "1e400"))  # was: infinite radius passed to compute_caminfo
@example(text=SEED.replace("2466.63167", "-5"))  # was: negative radius passed to compute_caminfo
@example(text=SEED.replace("27.62593 <KM>", "0"))  # was: ZeroDivisionError in the relative difference
@example(text=SEED.replace("(256.00000, 256.00000)", "(nan, 1e308)"))
@example(text=SEED.replace("(256.00000, 256.00000)", "(1e400, 256)"))
def test_damaged_label_gives_values_or_isd_error(geometry, fuzz_path: Path, text: str) -> None:
    raw = parse_pds3_label(text)
    assert isinstance(raw, dict)
    vals = label_values(raw)
    assert all(isinstance(v, float) and math.isfinite(v) for v in vals.values())
    assert vals.get("radius_m", 1.0) > 0
    fuzz_path.write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        _label_run(geometry, str(fuzz_path))
    except IsdError as exc:
        assert str(fuzz_path) in str(exc)
