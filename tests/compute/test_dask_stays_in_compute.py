"""Dask is imported by the execution layer only (issue 32 item 3): a guard that reads the package's source (AST)."""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[2] / "mercury_dem"

#: Modules outside ``compute/`` that import Dask, each for a stated reason (docs/design.md, "Execution").
ALLOWED_OUTSIDE = {
    "cluster/jobqueue.py": "the batch-system launcher (dask-jobqueue's configuration)",
    "cluster/idle_timeout.py": "a scheduler plugin loaded by `dask scheduler --preload`",
}


def _imports_dask(tree: ast.AST) -> bool:
    for node in ast.walk(tree):
        names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) and node.level == 0 else [])
        if any(n.split(".")[0] in ("dask", "distributed", "dask_jobqueue") for n in names):
            return True
    return False


def test_only_compute_and_the_named_modules_import_dask() -> None:
    importers = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py")
                 if _imports_dask(ast.parse(p.read_text(), str(p)))}
    outside = {m for m in importers if not m.startswith("compute/")}
    assert outside == set(ALLOWED_OUTSIDE), sorted(outside ^ set(ALLOWED_OUTSIDE))
    assert {"compute/client.py", "compute/clusters.py"} <= importers
