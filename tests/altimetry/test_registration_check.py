"""Seed 004's before/after check of a registration (mercury_dem.validate.registration.profile_check)."""

from __future__ import annotations

from mercury_dem.validate.registration import CHECK_KEYS, profile_check


def _tile(tid: int, ok: bool, n: int, before: float, after: float) -> dict[str, object]:
    return {"tile_id": tid, "ok": ok, "n_profiles": n, "rms_before_m": before, "rms_registered_m": before / 2,
            "rms_after_m": after, "model": "affine"}


def test_counts_only_registered_tiles_with_enough_profiles():
    tiles = [_tile(1, True, 25, 40.0, 10.0), _tile(2, True, 20, 40.0, 50.0), _tile(3, False, 90, 40.0, 1.0),
             _tile(4, True, 19, 40.0, 1.0), _tile(5, True, 30, 30.0, 30.0)]
    records, share = profile_check(tiles, 20)
    assert [r["tile_id"] for r in records] == [1, 2, 5]  # not the failed tile 3, not tile 4 with 19 profiles
    assert all(tuple(r) == CHECK_KEYS for r in records)
    assert share == 1 / 3  # tile 1 improved; tile 2 got worse; tile 5 equal is not an improvement
    assert profile_check(tiles, 26) == ([{k: tiles[4][k] for k in CHECK_KEYS}], 0.0)


def test_no_tile_with_enough_profiles_gives_no_share():
    assert profile_check([_tile(1, True, 5, 40.0, 10.0)], 20) == ([], None)
    assert profile_check([], 20) == ([], None)
