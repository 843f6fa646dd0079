"""Parquet columns as numpy without pandas give what pandas' reader gives (mercury_dem.io.tables)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from mercury_dem.exceptions import StoreError
from mercury_dem.io.tables import column_to_numpy, read_arrow_table, read_table


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if a.dtype.kind in "fc" or b.dtype.kind in "fc":
        return a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True)
    return a.dtype == b.dtype and a.tolist() == b.tolist()


@pytest.mark.parametrize("seed", [3, 11])
def test_columns_equal_pandas_reader(tmp_path: Path, seed: int) -> None:
    """Every column type a store holds, with and without nulls, several row groups and a sliced read."""
    rng = np.random.default_rng(seed)
    n = 257
    holes = rng.random(n) < 0.2
    ints = rng.integers(-10**12, 10**12, n)
    table = pa.table({
        "i64": pa.array(ints, pa.int64()),
        "i64_null": pa.array(ints, pa.int64(), mask=holes),
        "i32": pa.array(ints.astype(np.int32), pa.int32()),
        "u8": pa.array(ints.astype(np.uint8), pa.uint8()),
        "f64": pa.array(rng.normal(size=n)),
        "f64_null": pa.array(rng.normal(size=n), mask=holes),
        "f32": pa.array(rng.normal(size=n).astype(np.float32)),
        "flag": pa.array(rng.random(n) < 0.5),
        "flag_null": pa.array(rng.random(n) < 0.5, mask=holes),
        "text": pa.array([f"id{k}" for k in rng.integers(0, 99, n)], pa.large_string()),
        "text_null": pa.array([f"x{k}" for k in range(n)], pa.string(), mask=holes),
    })
    path = tmp_path / "t.parquet"
    pq.write_table(table, path, row_group_size=100)
    arrow = read_arrow_table(path, "test")
    df = read_table(path, "test")
    for name in table.column_names:
        ours, theirs = column_to_numpy(arrow.column(name)), df[name].to_numpy()
        if theirs.dtype.kind in "OTU":  # pandas' string dtype: NaN where ours has None
            theirs = np.array([None if v is None or v != v else v for v in theirs.tolist()], dtype=object)
        assert _same(ours, theirs), name
    sliced = arrow.slice(37, 150)  # an offset into the chunks' buffers
    for name in ("i64", "f32", "u8"):
        assert _same(column_to_numpy(sliced.column(name)), df[name].to_numpy()[37:187]), name
    chunked = pa.concat_tables([arrow.slice(0, 100), arrow.slice(100, 100), arrow.slice(200)])
    assert chunked.column("f64").num_chunks == 3
    for name in table.column_names:
        assert _same(column_to_numpy(chunked.column(name)), column_to_numpy(arrow.column(name))), name


def test_empty_table_and_damaged_file(tmp_path: Path) -> None:
    path = tmp_path / "e.parquet"
    pq.write_table(pa.table({"a": pa.array([], pa.float64()), "s": pa.array([], pa.string())}), path)
    t = read_arrow_table(path, "test")
    assert column_to_numpy(t.column("a")).shape == (0,) and column_to_numpy(t.column("s")).shape == (0,)
    path.write_bytes(path.read_bytes()[:-9])
    with pytest.raises(StoreError, match="e.parquet"):
        read_arrow_table(path, "test")
