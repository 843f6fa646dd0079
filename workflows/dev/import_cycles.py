"""Import cycles among mercury_dem modules: module- and function-level imports, strongly connected components.

Usage: ``python workflows/dev/import_cycles.py [REPO_ROOT]`` (default: this checkout). Prints every cycle
(an SCC of more than one module) and their count; used for the before/after table in docs/design.md.
"""
import ast
import sys
from pathlib import Path

root = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2]
mods = {}
for p in (root / "mercury_dem").rglob("*.py"):
    name = ".".join(p.relative_to(root).with_suffix("").parts)
    if name.endswith(".__init__"): name = name[:-9]
    mods[name] = p
edges = {m: set() for m in mods}
for m, p in mods.items():
    tree = ast.parse(p.read_text())
    for node in ast.walk(tree):
        targets = []
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            targets = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        for t in targets:
            if t in mods and t != m:
                edges[m].add(t)
# Tarjan
index, low, stack, on, sccs = {}, {}, [], set(), []
sys.setrecursionlimit(10000)
def sc(v, c=[0]):
    index[v] = low[v] = c[0]; c[0] += 1; stack.append(v); on.add(v)
    for w in edges[v]:
        if w not in index: sc(w); low[v] = min(low[v], low[w])
        elif w in on: low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = stack.pop(); on.discard(w); comp.append(w)
            if w == v: break
        if len(comp) > 1: sccs.append(sorted(comp))
for v in mods:
    if v not in index: sc(v)
for c in sccs: print(len(c), c)
print("cycles (SCCs > 1):", len(sccs))
