"""Shared pieces of the line-oriented fuzz tests (BAL files, PDS3 labels)."""

from __future__ import annotations

from collections.abc import Callable

from hypothesis import strategies as st

#: Edits every line-oriented text takes; readers add their own (``edit_line`` below).
COMMON_EDITS = ("truncate", "delete", "duplicate")

EditLine = Callable[[st.DrawFn, str, list[str], int], list[str]]


def mutate_lines(draw: st.DrawFn, seed: str, edits: tuple[str, ...], edit_line: EditLine) -> str:
    """1-4 random edits of ``seed``: truncation anywhere, a line deleted or duplicated, or one of the
    reader's own ``edits`` applied by ``edit_line(draw, how, lines, i)`` (which returns the lines)."""
    lines = seed.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        how = draw(st.sampled_from(COMMON_EDITS + edits))
        if not lines:
            break
        i = draw(st.integers(0, len(lines) - 1))
        if how == "truncate":
            text = "\n".join(lines)
            lines = text[: draw(st.integers(0, len(text)))].splitlines()
        elif how == "delete":
            del lines[i]
        elif how == "duplicate":
            lines.insert(i, lines[i])
        else:
            lines = edit_line(draw, how, lines, i)
    return "\n".join(lines)
