"""No body by default below the mission: a guard that reads the package's source (AST), no import.

A default of Mercury deep in ``dem/`` once turned a Moon DEM's heights into "radius minus Mercury's
datum" on the LocalCluster path only. Every function and dataclass below the mission takes the body
(or its datum) from its caller; Mercury stays the default only of the synthetic presets and the command
line (``mission/``, ``synth/``, ``commands/``, ``config/``, ``cli.py``).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mercury_dem"
#: Where Mercury may be the default: the mission layer, the synthetic presets, the command line, configuration.
ALLOWED = ("mission", "synth", "commands", "config")
#: Names that are Mercury's (geometry/body.py's constants).
MERCURY_NAMES = {"MERCURY", "DATUM_RADIUS_M", "IAU_SPHERE_RADIUS_M", "CRS_GEOGRAPHIC", "CRS_EQUIRECTANGULAR",
                 "CRS_EQUIRECTANGULAR_180", "CRS_NORTH_POLAR_STEREOGRAPHIC", "CRS_SOUTH_POLAR_STEREOGRAPHIC",
                 "CRS_DATUM_GEOGRAPHIC", "MERCURY_GM", "MERCURY_ROTATION_S"}
#: Mercury's radii as literals (datum, IAU sphere), metres and km.
MERCURY_NUMBERS = {2_439_400.0, 2_440_530.0, 2439.4, 2440.53}
#: Modules below the mission that build scenes of their own on Mercury on purpose (not defaults: their
#: functions that measure take the datum). Each is debt to pay when a second body needs them.
SCENES = {"network/synthetic.py", "validate/synthetic_network.py", "validate/matching.py"}


def _mercury(expr: ast.AST | None) -> bool:
    """True when an expression names Mercury: a constant, a literal radius, ``get_body("mercury")``."""
    if expr is None:
        return False
    for n in ast.walk(expr):
        if isinstance(n, ast.Name) and n.id in MERCURY_NAMES:
            return True
        if isinstance(n, ast.Attribute) and n.attr in MERCURY_NAMES:
            return True
        if isinstance(n, ast.Constant) and isinstance(n.value, (int, float)) and float(n.value) in MERCURY_NUMBERS:
            return True
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value.lower() == "mercury":
            return True
    return False


def _is_dataclass(node: ast.ClassDef) -> bool:
    return any("dataclass" in ast.unparse(d) for d in node.decorator_list)


def offenders(root: Path = PACKAGE) -> list[str]:
    """``path:line what`` for every Mercury default below the mission."""
    out = []
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.split("/")[0] in ALLOWED or rel == "cli.py":
            continue
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                a = node.args
                for d in [*a.defaults, *a.kw_defaults]:
                    if _mercury(d):
                        out.append(f"{rel}:{d.lineno} default {ast.unparse(d)!r} of {getattr(node, 'name', 'lambda')}")
            elif isinstance(node, ast.ClassDef) and _is_dataclass(node):
                for st in node.body:
                    if isinstance(st, ast.AnnAssign) and _mercury(st.value):
                        out.append(f"{rel}:{st.lineno} field default {ast.unparse(st)!r} of {node.name}")
            elif isinstance(node, ast.BoolOp) and isinstance(node.op, ast.Or) and any(_mercury(v) for v in node.values[1:]):
                out.append(f"{rel}:{node.lineno} fallback {ast.unparse(node)!r}")
            elif (isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and rel not in SCENES
                  and rel != "geometry/body.py"):
                # a body-less function that reaches for Mercury itself (``body = MERCURY`` in its body)
                for n in ast.walk(node):
                    if isinstance(n, ast.Name) and n.id in MERCURY_NAMES and isinstance(n.ctx, ast.Load):
                        out.append(f"{rel}:{n.lineno} {n.id} used in {node.name}")
    return sorted(set(out))


def test_nothing_below_the_mission_defaults_to_mercury() -> None:
    found = offenders()
    assert not found, "Mercury defaults below the mission (take the body from the caller):\n" + "\n".join(found)


def test_the_guard_sees_each_form(tmp_path: Path) -> None:
    pkg = tmp_path / "pkg" / "dem"
    pkg.mkdir(parents=True)
    (pkg / "bad.py").write_text(
        "from dataclasses import dataclass\n"
        "def f(x, datum_radius_m=DATUM_RADIUS_M): ...\n"
        "def g(x, *, body=MERCURY): ...\n"
        "def h(x, r=2439400.0): ...\n"
        "def k(body=None):\n    body = body or MERCURY\n"
        "def m(name='mercury'): ...\n"
        "@dataclass(frozen=True)\nclass G:\n    radius_m: float = DATUM_RADIUS_M\n"
    )
    (tmp_path / "pkg" / "synth").mkdir()
    (tmp_path / "pkg" / "synth" / "ok.py").write_text("def f(body=MERCURY): ...\n")
    found = offenders(tmp_path / "pkg")
    assert len([f for f in found if f.startswith("dem/bad.py")]) >= 6, found
    assert not [f for f in found if f.startswith("synth/")]
