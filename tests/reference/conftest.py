"""Paths of the real reference files: the package's data, the copies in tests/data/real (always there)
and the shared data folder beside the project (absent from a user's fresh clone: tests skip)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mercury_dem.reference.sha import resolve_shape_path

ROOT = Path(__file__).resolve().parents[2]
REAL = ROOT / "tests" / "data" / "real"
SHARED_DATA = ROOT / ".." / "shared" / "data"

#: MLA's GTMES_150V05 as the package ships it (mercury_dem/reference/data; its README gives the source)
SHA_TAB = resolve_shape_path("package:GTMES_150V05_SHA.TAB")
ORACLE_POINTS = REAL / "gtmes150v05_l148_oracle_points.csv"
ORACLE_TIF = SHARED_DATA / "mla" / "gtmes150v05_l148_height_m_0p5deg_DERIVED.tif"
LOLA_DIR = REAL  # copies of ../shared/data/moon/lola (public domain, SOURCE.md)


def shared(path: Path) -> Path:
    """The shared file, or skip the test with a message saying where it was looked for."""
    if not path.exists():
        pytest.skip(f"{path} is absent (the shared data folder beside the project is not in a fresh clone)")
    return path


@pytest.fixture(scope="session")
def gtmes():
    from mercury_dem.reference.sha import read_shadr

    return read_shadr(SHA_TAB)
