"""Bundle Adjustment in the Large (BAL) text files: read one (the problem itself is :mod:`mercury_dem.adjust.bal`)."""

from __future__ import annotations

from pathlib import Path

from mercury_dem.adjust.bal import BalProblem, parse_bal
from mercury_dem.exceptions import AdjustmentError


def read_bal(path: str | Path) -> BalProblem:
    """Read a BAL text file; :class:`AdjustmentError` naming the file when unreadable or malformed."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise AdjustmentError(f"cannot read BAL file {path}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise AdjustmentError(f"BAL file {path} is not text: {exc.reason} at byte {exc.start}") from None
    return parse_bal(text, path)
