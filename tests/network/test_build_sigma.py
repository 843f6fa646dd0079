"""Convergent pairs' measures get a larger sigma (issue 21): the factor and how build_network gives it."""

from __future__ import annotations

import numpy as np
import pytest
from network_world import make_world

from mercury_dem.exceptions import NetworkError
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.network import PairMatches, build_network
from mercury_dem.network.build import convergence_sigma_factor


def test_factor_follows_tan_and_is_bounded():
    c = np.array([0.0, 30.0, 45.0, 60.0, 70.0, 89.99, 90.0, 135.0, np.nan])
    f = convergence_sigma_factor(c, 45.0, 10.0)
    assert np.allclose(f[:3], 1.0)
    assert f[3] == pytest.approx(np.tan(np.radians(60.0)))
    assert f[4] == pytest.approx(np.tan(np.radians(70.0)))
    assert np.allclose(f[5:8], 10.0)
    assert f[8] == 1.0
    assert np.all(np.diff(f[:8]) >= 0)
    assert np.allclose(convergence_sigma_factor(c, 180.0, 10.0), 1.0)  # off


def _matches(w, pairs):
    """Matches of each pair: the first image's side a keypoint (id = truth point), the second measured (-1)."""
    rows = []
    for k, (a, b) in enumerate(pairs):
        n = np.flatnonzero(w.visible[a] & w.visible[b])
        rows.append((np.full(n.size, a), np.full(n.size, b), n, np.full(n.size, k)))
    ia, ib, pt, pair = (np.concatenate([r[j] for r in rows]).astype(np.int64) for j in range(4))
    m = PairMatches(ia, ib, w.observed[ia, pt, 0], w.observed[ia, pt, 1], w.observed[ib, pt, 0], w.observed[ib, pt, 1],
                    pt, np.full(pt.size, -1))
    return m, pair


def test_measured_side_gets_the_factor_and_merged_measures_the_rms():
    w = make_world(0.0, 0.0, seed=1)
    pairs = [(0, 1), (2, 1), (0, 3)]
    m, pair = _matches(w, pairs)
    factor = np.array([3.0, 1.0, 2.0])[pair]
    net, _ = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, sigma_px=0.5, sigma_factor=factor, datum_radius_m=DATUM_RADIUS_M)
    plain, _ = build_network(w.image_ids, m, w.camera, w.positions, w.rotations, sigma_px=0.5, datum_radius_m=DATUM_RADIUS_M)
    assert net.n_measures == plain.n_measures and np.array_equal(net.measure_image, plain.measure_image)
    assert np.allclose(plain.sigma, 0.5)
    s = net.sigma[:, 0]
    assert np.array_equal(net.sigma[:, 0], net.sigma[:, 1])
    img = net.measure_image
    # keypoint sides (images 0 and 2) keep the plain sigma
    assert np.allclose(s[(img == 0) | (img == 2)], 0.5)
    assert np.allclose(s[img == 3], 1.0)  # only pair (0, 3): factor 2
    # image 1: every one of its points is seen by 0, 1 and 2 in this world, so its measure merges the
    # observations of (0, 1) (factor 3) and (2, 1) (factor 1): the RMS, sqrt(5)
    assert (w.visible[1] <= (w.visible[0] & w.visible[2])).all()
    assert np.allclose(s[img == 1], np.sqrt(5.0) * 0.5)


def test_bad_factors_are_refused():
    w = make_world(0.0, 0.0, seed=1)
    m, pair = _matches(w, [(0, 1)])
    with pytest.raises(NetworkError, match="sigma_factor"):
        build_network(w.image_ids, m, w.camera, w.positions, w.rotations, sigma_factor=np.ones(pair.size + 1), datum_radius_m=DATUM_RADIUS_M)
    with pytest.raises(NetworkError, match="sigma_factor"):
        build_network(w.image_ids, m, w.camera, w.positions, w.rotations, sigma_factor=np.zeros(pair.size), datum_radius_m=DATUM_RADIUS_M)
