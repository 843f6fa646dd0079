"""Import cycles among mercury_dem modules: module- and function-level imports, strongly connected components.

Usage: ``python workflows/dev/import_cycles.py [REPO_ROOT]`` (default: this checkout). Prints every cycle
(an SCC of more than one module) and their count; used for the before/after table in docs/history/.
As a module (``tests/test_architecture_doc.py`` loads it by path): :func:`import_graph` (module -> the modules of
ours it imports), :func:`external_imports` (module -> the top-level outside packages it imports) and :func:`cycles`.
"""
from __future__ import annotations

import ast
import sys
from pathlib import Path


def modules(root: Path) -> dict[str, Path]:
    """Every module of ``root/mercury_dem`` by dotted name (a package by its own name)."""
    mods = {}
    for p in (root / "mercury_dem").rglob("*.py"):
        name = ".".join(p.relative_to(root).with_suffix("").parts)
        if name.endswith(".__init__"):
            name = name[:-9]
        mods[name] = p
    return mods


def _targets(tree: ast.AST) -> list[str]:
    out: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out += [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            out += [a.name for a in node.names]
    return out


def import_graph(root: Path) -> dict[str, set[str]]:
    """module -> the modules of ours it imports (module or function level, absolute imports)."""
    mods = modules(root)
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for m, p in mods.items():
        for t in _targets(ast.parse(p.read_text())):
            if t in mods and t != m:
                edges[m].add(t)
    return edges


def external_imports(root: Path) -> dict[str, set[str]]:
    """module -> the top-level names of the outside packages it imports (``dask``, ``distributed``, ...)."""
    out: dict[str, set[str]] = {}
    for m, p in modules(root).items():
        out[m] = {t.split(".")[0] for t in _targets(ast.parse(p.read_text()))
                  if not t.startswith("mercury_dem")}
    return out


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    sccs: list[list[str]] = []
    counter = [0]
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))

    def sc(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                sc(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                sccs.append(sorted(comp))

    for v in edges:
        if v not in index:
            sc(v)
    return sccs


if __name__ == "__main__":
    root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2]
    found = cycles(import_graph(root))
    for c in found:
        print(len(c), c)
    print("cycles (SCCs > 1):", len(found))
