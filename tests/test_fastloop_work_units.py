"""The xdist work units of ``make test-fast`` (``--dist loadgroup``, tests/conftest.py): a test's module, or the
group of modules sharing a costly session fixture; every grouped module exists (a renamed one would silently
fall back to its own unit and build the fixture again on the other worker).
"""

from __future__ import annotations

from pathlib import Path

from tests.conftest import SHARED_FIXTURE_GROUPS, work_unit

ROOT = Path(__file__).resolve().parents[1]


def test_a_test_is_its_module_unless_its_module_is_grouped() -> None:
    assert work_unit("tests/plan/test_tree.py::test_children_agree_with_the_tile_grid[3]") == "tests/plan/test_tree.py"
    assert work_unit("tests/products/test_isis_pds4_products.py::test_x[moon_100_130]") == "products_regional_dems"
    assert work_unit("tests/products/test_product_metadata.py::test_y") == "products_regional_dems"


def test_every_grouped_module_exists_once() -> None:
    modules = [m for ms in SHARED_FIXTURE_GROUPS.values() for m in ms]
    assert len(modules) == len(set(modules))
    assert all((ROOT / m).is_file() for m in modules), [m for m in modules if not (ROOT / m).is_file()]
