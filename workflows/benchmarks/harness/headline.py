"""The headline table of ``docs/benchmarks.md``, written from the records (between two marker lines).

Each record may carry ``headline``: ``area``, ``command``, ``text`` (ours vs the reference, same run), ``goal``,
``status`` and, once per area, ``row`` (its place in the table). The newest record of an area (by date, then by
file and line order) gives that area's row. Rows that predate the harness were imported once from the
hand-copied table into ``records/headline_before_harness.jsonl`` (commit null, ``source`` saying so); a new
run that records a headline for the same area replaces its row.

``cd workflows/benchmarks && python -m harness headline`` rewrites the table; ``--check`` only compares
(exit 1 when the page differs from what the records give).
"""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from harness.records import RECORDS, REPO, read_records

DOC = REPO / "docs" / "benchmarks.md"
BEGIN = ("<!-- headline table: generated from workflows/benchmarks/records by "
         "`cd workflows/benchmarks && python -m harness headline`; record a run, do not edit here -->")
END = "<!-- end of the generated headline table -->"
COLUMNS = ("area", "command", "text", "goal", "status")
HEADER = ("| area | command | headline (ours vs reference, same run) | goal | status |\n"
          "|---|---|---|---|---|")


def _cell(value: Any) -> str:
    """A table cell: one line, every bare ``|`` escaped (cells already escaped stay as they are)."""
    return re.sub(r"(?<!\\)\|", r"\\|", str(value).replace("\n", " "))


def headline_rows(records: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The newest headline of each area, in table order (``row``, first given; areas without one last)."""
    latest: dict[str, tuple[str, int, Mapping[str, Any]]] = {}
    position: dict[str, float] = {}
    for i, rec in enumerate(records):
        h = rec.get("headline")
        if not h:
            continue
        area = h["area"]
        if "row" in h and area not in position:
            position[area] = float(h["row"])
        key = (str(rec.get("date", "")), i)
        if area not in latest or key >= latest[area][:2]:
            latest[area] = (key[0], key[1], h)
    areas = sorted(latest, key=lambda a: (position.get(a, float("inf")), a))
    return [dict(latest[a][2]) for a in areas]


def table(records: Iterable[Mapping[str, Any]]) -> str:
    lines = [HEADER]
    for h in headline_rows(records):
        lines.append("| " + " | ".join(_cell(h.get(c, "")) for c in COLUMNS) + " |")
    return "\n".join(lines)


def render(page: str, records: Iterable[Mapping[str, Any]]) -> str:
    """``page`` with the text between the markers replaced by the generated table."""
    if BEGIN not in page or END not in page:
        raise ValueError(f"the page has no headline markers ({BEGIN!r} ... {END!r})")
    head, rest = page.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    return f"{head}{BEGIN}\n{table(records)}\n{END}{tail}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m harness headline", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="compare only; exit 1 when the page differs")
    ap.add_argument("--doc", type=Path, default=DOC)
    ap.add_argument("--records", type=Path, default=RECORDS)
    args = ap.parse_args(argv)
    page = args.doc.read_text()
    new = render(page, read_records(args.records))
    if args.check:
        if new != page:
            print(f"{args.doc}: the headline table differs from the records; run `python -m harness headline`",
                  file=sys.stderr)
            return 1
        print(f"{args.doc}: the headline table is the records'")
        return 0
    if new != page:
        args.doc.write_text(new)
        print(f"{args.doc}: headline table rewritten from {args.records}")
    else:
        print(f"{args.doc}: unchanged")
    return 0
