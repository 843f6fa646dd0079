"""No function or method in ``mercury_dem/pipeline/`` is longer than 60 lines (issue 32: a stage runner loads,
calls the library and saves; an algorithm that needs more lines belongs in a library package).

Length is ``end_lineno - lineno + 1`` of the ``def`` (decorators not counted; a nested function counts in its
enclosing function and on its own). Reads source only (AST); imports nothing of the package.
"""

from __future__ import annotations

import ast
from pathlib import Path

PIPELINE = Path(__file__).resolve().parents[1] / "mercury_dem" / "pipeline"
LIMIT = 60

#: Functions allowed over the limit. It held the DEM, dense, ortho and registration runners while issue 32 moved
#: their algorithms out; all of them landed (session 17), so it is empty. Never add to it.
ALLOWED: frozenset[str] = frozenset()


def long_functions(source: str, module: str, limit: int = LIMIT) -> dict[str, int]:
    """``module.qualified_name`` -> length of every function or method of ``source`` longer than ``limit`` lines."""
    out: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = f"{prefix}{child.name}"
                length = (child.end_lineno or child.lineno) - child.lineno + 1
                if length > limit:
                    out[f"{module}.{name}"] = length
                visit(child, f"{name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return out


def pipeline_long_functions() -> dict[str, int]:
    """:func:`long_functions` of every module of ``mercury_dem/pipeline/``."""
    out: dict[str, int] = {}
    for path in sorted(PIPELINE.glob("*.py")):
        out.update(long_functions(path.read_text(), path.stem))
    return out


def test_no_pipeline_function_is_longer_than_60_lines() -> None:
    """Every function of the pipeline but the allowed ones fits in 60 lines."""
    found = pipeline_long_functions()
    over = {k: v for k, v in found.items() if k not in ALLOWED}
    assert not over, (f"functions in mercury_dem/pipeline/ over {LIMIT} lines: {over}; move the algorithm to its "
                      "library package (pure, tested) and keep the runner to load -> call -> save")


def test_the_allowlist_names_only_functions_that_exist_and_are_long() -> None:
    """An entry whose function got short (or went away) is removed, so the list only shrinks."""
    found = pipeline_long_functions()
    stale = sorted(k for k in ALLOWED if k not in found)
    assert not stale, f"no longer over {LIMIT} lines (or gone): remove from ALLOWED: {stale}"


def test_the_check_catches_a_long_function_and_method() -> None:
    """Self-check: 61 lines is caught (function, method, nested function), 60 is not."""
    body = "\n".join(f"    x{i} = {i}" for i in range(LIMIT))  # def line + 60 = 61 lines
    short = "\n".join(f"    y{i} = {i}" for i in range(LIMIT - 1))  # def line + 59 = 60 lines: allowed
    source = (f"def long():\n{body}\n\n\ndef short():\n{short}\n\n\nclass C:\n    def method(self):\n"
              + "\n".join(f"    {line}" for line in body.splitlines()) + "\n")
    assert long_functions(source, "m") == {"m.long": LIMIT + 1, "m.C.method": LIMIT + 1}
    nested = "def outer():\n    def inner():\n" + "\n".join(f"    {line}" for line in body.splitlines()) + "\n"
    assert long_functions(nested, "m") == {"m.outer": LIMIT + 2, "m.outer.inner": LIMIT + 1}
