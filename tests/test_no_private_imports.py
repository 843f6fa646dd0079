"""No module imports another module's private (``_name``) names: a guard that reads the package's source (AST).

A helper that two modules share is part of the owner's interface: public, with a docstring that says what
it promises. Imported as ``_name`` it was neither (issue #32: 27 such imports, the blocked adjuster built on
four private helpers of the in-memory solver, ``dem/buckets.py`` on nine of ``dem/search.py``).
Dunder names (``__version__``) are not private. Tests may still reach into a module's internals.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mercury_dem"


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def _module_name(path: Path, root: Path) -> str:
    parts = path.relative_to(root.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _absolute(node: ast.ImportFrom, module: str, is_package: bool) -> str:
    """The absolute module an ``ImportFrom`` reads (relative imports resolved against ``module``)."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - node.level + 1]
    return ".".join(base + ([node.module] if node.module else []))


def offenders(root: Path = PACKAGE) -> list[str]:
    """``path:line module.name`` for every private name of another package module imported or read."""
    top = root.name
    out = []
    for path in sorted(root.rglob("*.py")):
        module = _module_name(path, root)
        rel = path.relative_to(root).as_posix()
        tree = ast.parse(path.read_text(), filename=str(path))
        aliases: dict[str, str] = {}  # local name -> package module, from ``import top.x.y as m``
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                src = _absolute(node, module, path.name == "__init__.py")
                if (src == top or src.startswith(top + ".")) and src != module:
                    out += [f"{rel}:{node.lineno} {src}.{a.name}" for a in node.names if _private(a.name)]
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith(top + ".") and a.asname and a.name != module:
                        aliases[a.asname] = a.name
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and _private(node.attr) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases):
                out.append(f"{rel}:{node.lineno} {aliases[node.value.id]}.{node.attr}")
    return sorted(set(out))


def test_no_module_imports_private_names_of_another() -> None:
    """Every ``_name`` read from another package module is reported, with its place."""
    found = offenders()
    assert not found, ("private names imported across modules (make the helper public, with a docstring, in the "
                       "module that owns it, or move it):\n" + "\n".join(found))


def test_the_check_finds_each_kind_of_private_import(tmp_path: Path) -> None:
    """The guard itself: absolute, relative and module-alias reads of another module's ``_name`` are found;
    a module's own private names, dunders and public names are not.
    """
    pkg = tmp_path / "mercury_dem"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("__version__ = '1'\n")
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "sub" / "owner.py").write_text("def _helper():\n    return 1\n\n\ndef public():\n    return _helper()\n")
    (pkg / "sub" / "fine.py").write_text("from mercury_dem import __version__\nfrom mercury_dem.sub.owner import public\n")
    (pkg / "sub" / "absolute.py").write_text("from mercury_dem.sub.owner import _helper, public\n")
    (pkg / "sub" / "relative.py").write_text("from .owner import _helper\n")
    (pkg / "sub" / "aliased.py").write_text("import mercury_dem.sub.owner as o\n\nx = o._helper()\n")
    assert offenders(pkg) == [
        "sub/absolute.py:1 mercury_dem.sub.owner._helper",
        "sub/aliased.py:3 mercury_dem.sub.owner._helper",
        "sub/relative.py:1 mercury_dem.sub.owner._helper",
    ]
