"""Compare the outputs of two run directories: every Zarr array bit for bit, every parquet table and JSON file
value for value (timings and the run directories' own paths left out).

Made to show that a refactor leaves a run's outputs identical (issue 32): run the same mission before and after,
then

    python workflows/dev/compare_runs.py RUN_BEFORE RUN_AFTER [--only dem.zarr registered.zarr ...]

Prints one line per difference and the counts ("N/N arrays identical"); exits 1 when anything differs.
Zarr stores are found anywhere under the run (a directory whose name ends in ``.zarr``); their arrays are
compared on their bytes (NaN equal to NaN of the same bit pattern) with dtype and shape, their attributes as
values. JSON keys that hold a duration or a moment (``seconds``, ``timings``, ``time``, ``elapsed``, ``started``,
``finished``, ``date``, ``created``, ``host``, ``pid``, ``token``) are dropped, as are parquet columns named so.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

VOLATILE = re.compile(r"seconds|timing|time|elapsed|started|finished|date|created|host|pid|token|duration|wall|cpu|rss|peak")


def _clean(value: Any, roots: tuple[str, str]) -> Any:
    """``value`` without volatile keys, the run directory's path replaced by ``RUN``."""
    if isinstance(value, dict):
        return {k: _clean(v, roots) for k, v in value.items() if not VOLATILE.search(str(k))}
    if isinstance(value, list):
        return [_clean(v, roots) for v in value]
    if isinstance(value, str):
        for r in roots:
            value = value.replace(r, "RUN")
        return value
    return value


def _stores(root: Path) -> list[Path]:
    out = []
    for p in sorted(root.rglob("*.zarr")):
        if p.is_dir() and not any(part.endswith(".zarr") for part in p.relative_to(root).parts[:-1]):
            out.append(p.relative_to(root))
    return out


def compare_zarr(a: Path, b: Path, roots: tuple[str, str]) -> tuple[int, int, list[str]]:
    """(arrays identical, arrays, differences) of two stores."""
    import zarr

    ga, gb = zarr.open_group(str(a), mode="r"), zarr.open_group(str(b), mode="r")
    diffs = []
    if _clean(dict(ga.attrs), roots) != _clean(dict(gb.attrs), roots):
        keys = {k for k in set(ga.attrs) | set(gb.attrs)
                if _clean({k: ga.attrs.get(k)}, roots) != _clean({k: gb.attrs.get(k)}, roots)}
        diffs.append(f"{a.name}: root attributes differ: {sorted(keys)}")
    names_a = {k for k, _ in ga.arrays()}
    names_b = {k for k, _ in gb.arrays()}
    if names_a != names_b:
        diffs.append(f"{a.name}: arrays {sorted(names_a ^ names_b)} in one store only")
    same = 0
    for name in sorted(names_a & names_b):
        xa, xb = np.asarray(ga[name][...]), np.asarray(gb[name][...])
        if xa.dtype == xb.dtype and xa.shape == xb.shape and xa.tobytes() == xb.tobytes() \
                and _clean(dict(ga[name].attrs), roots) == _clean(dict(gb[name].attrs), roots):
            same += 1
        else:
            diffs.append(f"{a.name}/{name}: differs ({xa.dtype}{xa.shape} vs {xb.dtype}{xb.shape})")
    return same, len(names_a | names_b), diffs


def compare_tables(a: Path, b: Path) -> str | None:
    import pandas as pd

    ta, tb = pd.read_parquet(a), pd.read_parquet(b)
    ta = ta[[c for c in ta.columns if not VOLATILE.search(c)]]
    tb = tb[[c for c in tb.columns if not VOLATILE.search(c)]]
    return None if ta.equals(tb) else f"{a.name}: tables differ"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--only", nargs="*", default=None, help="relative paths (stores, files, directories) to compare")
    args = ap.parse_args(argv)
    roots = (str(args.before.resolve()), str(args.after.resolve()))
    diffs: list[str] = []
    n_same = n_arrays = 0
    stores = [s for s in _stores(args.before) if args.only is None or any(str(s).startswith(o) for o in args.only)]
    for s in stores:
        if not (args.after / s).exists():
            diffs.append(f"{s}: missing after")
            continue
        same, n, d = compare_zarr(args.before / s, args.after / s, roots)
        n_same, n_arrays, diffs = n_same + same, n_arrays + n, diffs + [f"{s.parent}/{x}" for x in d]
    files = {"parquet": [0, 0], "json": [0, 0]}
    for ext, counts in files.items():
        for f in sorted(args.before.rglob(f"*.{ext}")):
            rel = f.relative_to(args.before)
            if ".zarr" in str(rel) or (args.only is not None and not any(str(rel).startswith(o) for o in args.only)):
                continue
            counts[1] += 1
            g = args.after / rel
            if not g.exists():
                diffs.append(f"{rel}: missing after")
                continue
            if ext == "parquet":
                d = compare_tables(f, g)
            else:
                d = None if _clean(json.loads(f.read_text()), roots) == _clean(json.loads(g.read_text()), roots) \
                    else f"{rel}: values differ"
            if d is None:
                counts[0] += 1
            else:
                diffs.append(d if ext == "json" else f"{rel}: {d}")
    for d in diffs:
        print("DIFF", d)
    print(f"{n_same}/{n_arrays} arrays identical in {len(stores)} Zarr stores; "
          f"{files['parquet'][0]}/{files['parquet'][1]} parquet tables and {files['json'][0]}/{files['json'][1]} "
          f"JSON files equal (timings left out)")
    return 1 if diffs else 0


if __name__ == "__main__":
    sys.exit(main())
