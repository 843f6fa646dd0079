"""Reading Parquet tables of a store without ever constructing Python objects from them.

A Parquet file may carry Arrow *extension types* in its schema (``ARROW:extension:name``
field metadata). The Python one, ``arrow.py_extension_type``, stored a pickle of the type,
and pyarrow before 14.0.1 unpickled it on read (CVE-2023-47248); a user-registered extension
type can run code of its own on read. The stores of this package hold only plain columns
(numbers, strings, booleans), so any extension type in a store's table is refused before
pandas or pyarrow build the table. The check reads the schema only (pyarrow's own footer
parser, which does not deserialize extension types); why not just ``pd.read_parquet``: with
today's pyarrow the pickle is ignored and the column silently comes back as its storage
type, which hides a file that is not what the store wrote.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import TYPE_CHECKING

from mercury_dem.exceptions import StoreError

if TYPE_CHECKING:
    from typing import Any

    import pandas as pd
    import pyarrow as pa
    from numpy.typing import NDArray

#: Field metadata keys by which Arrow marks an extension type (the second holds its serialized parameters).
EXTENSION_KEYS = (b"ARROW:extension:name", b"ARROW:extension:metadata")


def read_table(path: str | Path, what: str) -> pd.DataFrame:
    """The Parquet table at ``path`` as a DataFrame; :class:`StoreError` naming ``what`` and the file
    when it is unreadable or declares an extension type (a pickled Python type, among others).

    ``what`` says whose table it is (e.g. ``"mission m"``), for the message.
    """
    import pandas as pd

    path = Path(path)
    _check_schema(path, what)
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow and pandas raise several types for a damaged file
        raise StoreError(f"{what}: cannot read {path} ({type(exc).__name__}: {exc})") from None


def read_arrow_table(path: str | Path, what: str) -> pa.Table:
    """The Parquet table at ``path`` as a :class:`pyarrow.Table`, checked as :func:`read_table` checks it.

    For readers that need a few columns as numpy arrays and not pandas (whose import alone costs
    ~0.3 s CPU: ``mercury-dem info`` reads the mission catalog this way).
    """
    import pyarrow.parquet as pq

    path = Path(path)
    _check_schema(path, what)
    try:
        # ParquetFile.read, not pq.read_table: the latter imports pyarrow.dataset, which imports pandas
        with pq.ParquetFile(path) as f:
            table = f.read(use_pandas_metadata=True)
        # full validation: a flipped byte in a string column reads without error and fails only when a value
        # is decoded (UnicodeDecodeError in to_pylist, found by tests/mission/test_fuzz_store.py)
        table.validate(full=True)
        return table
    except Exception as exc:  # pyarrow raises several types for a damaged file
        raise StoreError(f"{what}: cannot read {path} ({type(exc).__name__}: {exc})") from None


def column_to_numpy(column: pa.ChunkedArray) -> NDArray[Any]:
    """One Arrow column as numpy, with the values pandas' conversion gives, without importing pandas.

    Integers and floats without nulls come zero-copy from their data buffer (read-only); with nulls,
    as float64 with NaN (pandas' rule for integers); booleans as bool (object with None when some are
    missing); strings and any other type as an object array of Python values (None for a null).

    Why by hand: pyarrow's own ``to_numpy``/``__array__`` go through its pandas conversion code, which
    imports pandas (~0.3 s CPU) even for a float column; ``mercury-dem info`` needs a few columns only.
    """
    import numpy as np
    import pyarrow as pa

    t = column.type
    chunks = column.chunks
    if (pa.types.is_integer(t) or pa.types.is_floating(t)) and t.bit_width in (8, 16, 32, 64) \
            and not pa.types.is_float16(t):
        kind = "f" if pa.types.is_floating(t) else "i" if pa.types.is_signed_integer(t) else "u"
        dtype = np.dtype(f"{kind}{t.bit_width // 8}")
        if column.null_count:
            return np.array([np.nan if v is None else v for v in column.to_pylist()], dtype=np.float64)
        parts = [np.frombuffer(c.buffers()[1], dtype=dtype, count=len(c), offset=c.offset * dtype.itemsize)
                 for c in chunks if len(c)]
        out = parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.zeros(0, dtype)
        return out
    values = column.to_pylist()
    if pa.types.is_boolean(t) and not column.null_count:
        return np.array(values, dtype=bool).reshape(-1)
    out = np.empty(len(values), dtype=object)
    out[:] = values
    return out


def _check_schema(path: Path, what: str) -> None:
    """StoreError when the file's schema is unreadable or declares an Arrow extension type."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        schema = pq.read_schema(path)
    except (OSError, pa.ArrowException, ValueError) as exc:
        raise StoreError(f"{what}: cannot read {path} ({type(exc).__name__}: {exc})") from None
    for field in _fields(schema):
        meta = field.metadata or {}
        if any(k in meta for k in EXTENSION_KEYS) or isinstance(field.type, pa.ExtensionType):
            name = meta.get(EXTENSION_KEYS[0], str(field.type).encode()).decode("utf-8", "replace")
            raise StoreError(
                f"{what}: {path} column '{field.name}' declares the Arrow extension type '{name}' (e.g. a pickled "
                "Python object); stores of this package hold plain columns only and nothing in them is unpickled: "
                "regenerate the file with mercury-dem"
            )


def _fields(schema):  # type: ignore[no-untyped-def]
    """Every field of ``schema``, nested ones (struct/list children) included."""
    stack = list(schema)
    while stack:
        f = stack.pop()
        yield f
        t = f.type
        # struct/list/map types have child fields; primitive types have none (or no field())
        with contextlib.suppress(AttributeError, TypeError, IndexError):
            stack.extend(t.field(i) for i in range(t.num_fields))
