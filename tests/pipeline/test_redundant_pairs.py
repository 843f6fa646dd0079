"""A tile counts the wide pairs it did not try (a narrower route joins their images) apart from its failures."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from mercury_dem.io.run_store import PAIRS_FILE, RunStore
from mercury_dem.match.selection import REDUNDANT_REASON
from mercury_dem.pipeline.results import TileSummary, read_summary

pytestmark = pytest.mark.integration


def test_tiles_count_redundant_pairs_apart_from_failures(sync_run: tuple[Path, dict[str, Any]]) -> None:
    """Each tile's ``pairs_redundant`` is the number of its pair rows skipped as redundant, and none of them
    is among its pair failures.
    """
    run, _ = sync_run
    store = RunStore(run)
    images, _, _ = store.read_plan()
    tiles = sorted(set(images.loc[images["excluded_reason"] == "", "tile_id"].astype(int)))
    counted = listed = 0
    for t in tiles:
        s = read_summary(store, "tile", t)
        assert isinstance(s, TileSummary)
        if s.counts is None:
            continue
        p = store.unit_file("tile", t, PAIRS_FILE)
        rows = pd.read_parquet(p) if p.is_file() else pd.DataFrame()
        if "reason" not in rows.columns:  # a tile without pairs writes a table without columns
            rows = pd.DataFrame({"status": pd.Series([], dtype=str), "reason": pd.Series([], dtype=str)})
        skipped = rows["reason"].astype(str).str.startswith(REDUNDANT_REASON)
        assert s.counts.pairs_redundant == int(skipped.sum()), t
        assert (rows.loc[skipped, "status"] == "skipped").all()
        assert not any(k.startswith(REDUNDANT_REASON) for k in s.counts.pair_failures), s.counts.pair_failures
        counted += s.counts.pairs_redundant
        listed += int(skipped.sum())
    # the tiny mission has wide pairs with narrower routes (a mission without any would not test the count)
    assert counted == listed and counted > 0
