"""The shape of Mercury shipped with the package (GTMES_150V05, for the demo): the published bytes,
readable by name on any machine the package is installed on, and bad names refused."""

from __future__ import annotations

from pathlib import Path

import pytest

from mercury_dem.exceptions import ReferenceDataError
from mercury_dem.reference.sha import GTMES_PACKAGED, file_sha256, read_shadr, resolve_shape_path

# the PDS original (the project's shared copy and tests/data/real/ have the same digest)
PUBLISHED_SHA256 = "c49d07c14b09c1b1ed1b4bfc4b42d2ff058875f5e949b50128b83ffa94c659b3"


def test_packaged_gtmes_is_the_published_product() -> None:
    path = resolve_shape_path(GTMES_PACKAGED)
    assert path.is_file() and path.parent.name == "data" and path.parent.parent.name == "reference"
    assert file_sha256(path) == PUBLISHED_SHA256
    assert (path.parent / "GTMES_150V05_SHA.LBL").is_file() and (path.parent / "README.md").is_file()
    shape = read_shadr(GTMES_PACKAGED)
    assert shape.lmax == 150 and abs(shape.reference_radius_m - 2_439_400.0) < 1.0


def test_plain_paths_unchanged_and_bad_package_names_refused(tmp_path: Path) -> None:
    assert resolve_shape_path(tmp_path / "x.tab") == tmp_path / "x.tab"
    for bad in ("package:", "package:../sha.py", "package:.hidden"):
        with pytest.raises(ReferenceDataError, match="packaged data file"):
            read_shadr(bad)
    with pytest.raises(ReferenceDataError, match="NOPE.TAB"):
        read_shadr("package:NOPE.TAB")
