"""Fingerprints of a run's results, to prove a refactoring changed no output.

``python workflows/dev/run_fingerprint.py RUN [RUN2]`` prints one SHA-256 per result of the run: every array
of every Zarr store (the units' control networks, ``dem.zarr``) and every Parquet table (the solutions, the
plan), by content (values, dtype, shape), not by file bytes, which also hold times and library versions.
With two runs it prints only the results that differ and exits 1 if any does. Summaries and reports (JSON)
are left out: they hold wall-clock times, and so are the tables' time columns (:data:`TIME_COLUMNS`,
e.g. ``pairs.parquet``'s ``seconds`` per pair).

Written here rather than with a library: ``zarr``/``pandas`` read the stores; what "the same result" means
(content, not metadata) is this project's own choice.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np

#: Columns of a run's tables that hold wall-clock times, not results.
TIME_COLUMNS = frozenset({"seconds", "started_at", "finished_at"})


def _hash_array(a: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(f"{a.dtype.str}{a.shape}".encode())
    if a.dtype.kind == "O" or a.dtype.kind in "US":
        h.update(repr(a.tolist()).encode())
    else:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:16]


def fingerprint(run: Path) -> dict[str, str]:
    """SHA-256 (16 hex digits) of every Zarr array and Parquet table under ``run``, keyed by relative path."""
    import warnings

    import pandas as pd
    import zarr

    warnings.filterwarnings("ignore", message="Object at .complete is not recognized")

    out: dict[str, str] = {}
    for store in sorted(p for p in run.rglob("*.zarr") if p.is_dir() and ".zarr" not in str(p.parent)):
        root = zarr.open_group(str(store), mode="r")
        for name, arr in sorted(root.arrays(), key=lambda kv: kv[0]):
            out[f"{store.relative_to(run)}/{name}"] = _hash_array(np.asarray(arr[...]))
        for gname, group in sorted(root.groups(), key=lambda kv: kv[0]):
            for name, arr in sorted(group.arrays(), key=lambda kv: kv[0]):
                out[f"{store.relative_to(run)}/{gname}/{name}"] = _hash_array(np.asarray(arr[...]))
    for table in sorted(run.rglob("*.parquet")):
        df = pd.read_parquet(table)
        h = hashlib.sha256()
        for col in df.columns:
            if col in TIME_COLUMNS:
                continue
            h.update(str(col).encode())
            h.update(_hash_array(df[col].to_numpy()).encode())
        out[str(table.relative_to(run))] = h.hexdigest()[:16]
    return out


def main(argv: list[str]) -> int:
    """Print the fingerprints of one run, or the differences between two."""
    if len(argv) == 1:
        for k, v in fingerprint(Path(argv[0])).items():
            print(v, k)
        return 0
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    a, b = fingerprint(Path(argv[0])), fingerprint(Path(argv[1]))
    diff = sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))
    for k in diff:
        print(f"{a.get(k, 'missing')} {b.get(k, 'missing')} {k}")
    print(f"{len(a)} results in {argv[0]}, {len(b)} in {argv[1]}, {len(diff)} differ")
    return 1 if diff else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
