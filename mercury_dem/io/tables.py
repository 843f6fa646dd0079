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

import pandas as pd

from mercury_dem.exceptions import StoreError

#: Field metadata keys by which Arrow marks an extension type (the second holds its serialized parameters).
EXTENSION_KEYS = (b"ARROW:extension:name", b"ARROW:extension:metadata")


def read_table(path: str | Path, what: str) -> pd.DataFrame:
    """The Parquet table at ``path`` as a DataFrame; :class:`StoreError` naming ``what`` and the file
    when it is unreadable or declares an extension type (a pickled Python type, among others).

    ``what`` says whose table it is (e.g. ``"mission m"``), for the message.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
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
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow and pandas raise several types for a damaged file
        raise StoreError(f"{what}: cannot read {path} ({type(exc).__name__}: {exc})") from None


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
