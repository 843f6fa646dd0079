"""Tests of the benchmark helpers in ``workflows/benchmarks`` (not part of the package)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

BENCHMARKS = Path(__file__).resolve().parents[2] / "workflows" / "benchmarks"


def load_benchmark(name: str) -> ModuleType:
    """Import ``workflows/benchmarks/<name>.py`` (as the scripts there import it: by its bare name)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    assert spec is not None and spec.loader is not None, f"no {name}.py in {BENCHMARKS}"
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up here
    spec.loader.exec_module(module)
    return module


def load_harness() -> ModuleType:
    """Import the package ``workflows/benchmarks/harness`` (as the scripts there import it: ``import harness``)."""
    if "harness" in sys.modules:
        return sys.modules["harness"]
    spec = importlib.util.spec_from_file_location("harness", BENCHMARKS / "harness" / "__init__.py",
                                                  submodule_search_locations=[str(BENCHMARKS / "harness")])
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["harness"] = module
    spec.loader.exec_module(module)
    return module
