"""near_pairs and form_tracks on small exact cases."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from mercury_dem.network.tracks import form_tracks, near_pairs


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(0, 300), tol=st.sampled_from([0.5, 1.0, 3.0]))
def test_near_pairs_equals_brute_force(seed, n, tol):
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 4, n)
    s = rng.uniform(-5, 60, n)
    l = rng.uniform(-5, 60, n)
    s[rng.random(n) < 0.05] = np.nan
    got = {tuple(sorted(p)) for p in near_pairs(image, s, l, tol).tolist()}
    d = np.hypot(s[:, None] - s[None, :], l[:, None] - l[None, :])
    same = (image[:, None] == image[None, :]) & (d <= tol)
    want = {(i, j) for i, j in zip(*np.nonzero(np.triu(same, 1)))}
    assert got == want


def test_form_tracks_groups_and_order():
    # observations: 0-1 matched (images 0, 1), 2-3 matched (images 1, 2) and 1~2 the same pixel;
    # 4-5 a separate track with a lower rank
    image = np.array([0, 1, 1, 2, 3, 4])
    s = np.array([10.0, 20.0, 20.2, 30.0, 5.0, 6.0])
    l = np.array([10.0, 20.0, 20.0, 30.0, 5.0, 6.0])
    rank = np.array([5, 5, 6, 6, 0, 0])
    edges = np.array([[0, 1], [2, 3], [1, 2], [4, 5]])
    t = form_tracks(6, edges, image, s, l, rank, tolerance_px=1.0)
    assert t.n_tracks == 2 and t.n_conflicts == 0
    assert t.group_track.tolist() == [0, 0, 1, 1, 1]  # the low-rank track first
    assert t.group_image.tolist() == [3, 4, 0, 1, 2]
    np.testing.assert_allclose(t.sample, [5.0, 6.0, 10.0, 20.1, 30.0])
    assert t.group_size.tolist() == [1, 1, 1, 2, 1]
    assert t.obs_group.tolist() == [2, 3, 3, 4, 0, 1]
