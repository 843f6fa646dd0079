"""The pair state between the tile's phases (mercury_dem.match.pair.PairState): frozen, each step a new state."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from mercury_dem.config.match import MatchConfig
from mercury_dem.match.pair import PairState, WarpedPartner
from mercury_dem.match.propagation import anchors_of, priorities, thin


class _Image:
    """Only what thin() and the tile's anchor bookkeeping read of an ImageFeatures."""

    def __init__(self, shape: tuple[int, int]) -> None:
        self.image = np.zeros(shape, np.float32)
        self.described = True


def _state(n: int, rng: np.random.Generator, swap: bool = False, **kw: Any) -> PairState:
    base: Any = _Image((100, 100))
    return PairState(
        swap=swap, pg=None, base=base, other=base, other_geom=None,  # type: ignore[arg-type]
        feat_base=np.arange(n, dtype=np.int64), feat_other=np.full(n, -1, np.int64),
        pa=rng.uniform(0, 100, (n, 2)), pb=rng.uniform(0, 100, (n, 2)), score=rng.uniform(0.5, 1.0, n), **kw,
    )


def test_take_returns_a_new_state_and_leaves_the_old_one() -> None:
    st = _state(6, np.random.default_rng(3), other_exact=np.arange(12.0).reshape(6, 2))
    keep = np.array([True, False, True, True, False, False])
    out = st.take(keep)
    assert out is not st and st.pa.shape == (6, 2) and st.kind is None  # the old state is untouched
    assert out.feat_base.tolist() == [0, 2, 3]
    np.testing.assert_array_equal(out.pa, st.pa[keep])
    np.testing.assert_array_equal(out.other_exact, st.other_exact[keep])
    assert out.kind is not None and out.kind.dtype == np.int8 and out.kind.tolist() == [0, 0, 0]
    with pytest.raises(dataclasses.FrozenInstanceError):
        out.pa = st.pa  # type: ignore[misc]


def test_warped_partner_is_typed_and_frozen() -> None:
    w = WarpedPartner(np.zeros((4, 4), np.float32), np.ones((4, 4), bool), None, None)
    st = _state(3, np.random.default_rng(5), warped=w)
    assert st.warped is w and dataclasses.replace(st, warped=None).warped is None and st.warped is w
    with pytest.raises(dataclasses.FrozenInstanceError):
        w.pattern = w.image  # type: ignore[misc]


def test_thin_prefers_anchors_matched_in_more_pairs() -> None:
    """Three pairs of one base image: keypoints 0-9 are in all three, 10-39 in one; thinning pair 0
    to 10 matches keeps exactly the ten shared ones although they have the lowest scores (all in one
    cell of the spreading grid, so only the priority decides), and leaves the state it got."""
    rng = np.random.default_rng(11)
    pairs = [("A", "B"), ("A", "C"), ("A", "D")]
    score = np.concatenate([rng.uniform(0.5, 0.6, 10), rng.uniform(0.9, 1.0, 30)])
    big = dataclasses.replace(_state(40, rng), pa=rng.uniform(0, 40, (40, 2)), score=score)
    small = [dataclasses.replace(_state(10, rng), feat_base=np.arange(10, dtype=np.int64)) for _ in range(2)]
    states: list[Any] = [big, *small]
    index = {k: i for i, k in enumerate("ABCD")}
    anchors = anchors_of(pairs, states)
    assert anchors["A"][0].tolist() == list(range(40)) and anchors["A"][1][:10].tolist() == [3] * 10
    prio = priorities(pairs, states, index)
    assert prio[0][:10].tolist() == [3] * 10 and prio[0][10:].tolist() == [1] * 30
    out = thin(big, prio[0], MatchConfig(max_matches=10))
    assert sorted(out.feat_base.tolist()) == list(range(10))
    assert big.pa.shape[0] == 40
