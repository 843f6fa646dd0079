"""docs/architecture.md stays true against the code: the packages it names exist and are all named, its layer
table matches the import graph (``workflows/dev/import_cycles.py``'s, module and function level), its known
exceptions are real, its list of modules importing Dask is the code's, every file it names exists, and it stays
a 15-minute read (at most 3,000 words). Reads source only (AST); imports nothing of the package."""

from __future__ import annotations

import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "architecture.md"
PACKAGE = ROOT / "mercury_dem"
DASK = {"dask", "distributed", "dask_jobqueue"}


def _checker() -> ModuleType:
    spec = importlib.util.spec_from_file_location("import_cycles", ROOT / "workflows" / "dev" / "import_cycles.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # its command line runs only under __main__
    return module


CHECKER = _checker()
TEXT = DOC.read_text()


def _section(title: str) -> str:
    start = TEXT.index(f"\n## {title}")
    nxt = TEXT.find("\n## ", start + 1)
    return TEXT[start: nxt if nxt > 0 else None]


def _package_of(module: str) -> str:
    """``mercury_dem.dem.grid`` -> ``dem``; ``mercury_dem.cli`` -> ``cli``; ``mercury_dem`` -> ``mercury_dem``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def _module_of(path: str) -> str:
    """``network/synthetic.py`` -> ``mercury_dem.network.synthetic``; ``validate/`` -> ``mercury_dem.validate``."""
    return "mercury_dem." + path.rstrip("/").removesuffix(".py").replace("/", ".")


def layers() -> dict[str, int]:
    """package -> layer, from the table of the section on layers (rows that start with a number)."""
    out: dict[str, int] = {}
    for line in _section("Layers").splitlines():
        m = re.match(r"^\|\s*(\d+)\s*\|([^|]*)\|", line)
        if m:
            for name in re.findall(r"`([^`]+)`", m.group(2)):
                assert name not in out, f"{name} in two layers"
                out[name] = int(m.group(1))
    return out


def exceptions() -> list[tuple[str, str]]:
    return re.findall(r"^- `([^`]+)` → `([^`]+)`", _section("Layers"), flags=re.M)


def _excused(src: str, dst: str, rule: tuple[str, str]) -> bool:
    a, b = (_module_of(x) for x in rule)
    return (src == a or src.startswith(a + ".")) and (dst == b or dst.startswith(b + "."))


def test_every_package_is_in_exactly_one_layer() -> None:
    named = set(layers())
    real = {p.name for p in PACKAGE.iterdir() if (p / "__init__.py").exists()}
    real |= {p.stem for p in PACKAGE.glob("*.py") if p.stem != "__init__"} | {"mercury_dem"}
    assert named - real == set(), f"the layer table names packages that do not exist: {sorted(named - real)}"
    assert real - named == set(), f"packages missing from the layer table: {sorted(real - named)}"


def test_imports_follow_the_layers() -> None:
    """No module imports a package of a higher layer, except the stated exceptions."""
    layer = layers()
    rules = exceptions()
    used = {r: 0 for r in rules}
    wrong = []
    for src, targets in CHECKER.import_graph(ROOT).items():
        for dst in targets:
            if layer[_package_of(dst)] <= layer[_package_of(src)]:
                continue
            hit = [r for r in rules if _excused(src, dst, r)]
            for r in hit:
                used[r] += 1
            if not hit:
                wrong.append(f"{src} (layer {layer[_package_of(src)]}) imports {dst} "
                             f"(layer {layer[_package_of(dst)]})")
    assert not wrong, "imports against docs/architecture.md's layers:\n" + "\n".join(sorted(wrong))
    stale = [r for r, n in used.items() if n == 0]
    assert not stale, f"stated exceptions the code no longer has (remove them from the page): {stale}"


def test_the_dask_list_is_the_code() -> None:
    stated = {_module_of(p) for p in re.findall(r"^- `([^`]+\.py)`", _section("Where Dask lives"), flags=re.M)}
    real = {m for m, ext in CHECKER.external_imports(ROOT).items() if ext & DASK}
    assert stated == real, (f"import Dask but not listed: {sorted(real - stated)}; "
                            f"listed but do not: {sorted(stated - real)}")


def test_the_library_never_imports_the_benchmark_harness() -> None:
    users = sorted(m for m, ext in CHECKER.external_imports(ROOT).items() if "harness" in ext)
    assert not users, users


def test_every_file_and_link_it_names_exists() -> None:
    missing = []
    for name in set(re.findall(r"`([\w./-]+\.(?:py|md|yaml))`", TEXT)):
        if not any((base / name).exists() for base in (PACKAGE, ROOT, ROOT / "docs")):
            missing.append(name)
    for link in set(re.findall(r"\]\(([^)#]+)\)", TEXT)):
        if not (DOC.parent / link).exists():
            missing.append(link)
    assert not missing, f"docs/architecture.md names files that do not exist: {sorted(missing)}"


@pytest.mark.parametrize("limit", [3000])
def test_a_fifteen_minute_read(limit: int) -> None:
    assert len(TEXT.split()) <= limit
