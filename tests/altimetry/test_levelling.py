"""The levelling decision of a block (altimetry.levelling): the points near shots counted, the re-centring gate."""

from __future__ import annotations

import dataclasses

import numpy as np

from mercury_dem.adjust.datum import LevellingDecision, on_datum
from mercury_dem.altimetry.constraints import AltimetryShotsArrays
from mercury_dem.altimetry.levelling import levelling_for, recentres
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.geometry.body import DATUM_RADIUS_M
from mercury_dem.validate.synthetic_network import make_synthetic_network


def test_levelling_for_counts_the_points_near_shots() -> None:
    net = make_synthetic_network(800, rng=np.random.default_rng(31), relief_m=1000.0, min_views=2, max_views=3,
                                 outlier_fraction=0.0)
    problem = dataclasses.replace(net.problem, points=on_datum(net.problem.points, datum_radius_m=DATUM_RADIUS_M))
    cfg = AdjustConfig()
    u = problem.points / np.linalg.norm(problem.points, axis=1, keepdims=True)
    lat, lon = np.degrees(np.arcsin(u[:, 2])), np.degrees(np.arctan2(u[:, 1], u[:, 0])) % 360.0
    # shots (20 scattered within ~2 km) around the northern half of the points only
    north = lat > np.median(lat)
    rng = np.random.default_rng(1)
    k = np.repeat(np.flatnonzero(north), 20)
    jit = rng.normal(0.0, 1000.0 / (DATUM_RADIUS_M * np.pi / 180.0), (k.size, 2))
    shots = AltimetryShotsArrays(lat[k] + jit[:, 0], (lon[k] + jit[:, 1]) % 360.0,
                                 np.full(k.size, DATUM_RADIUS_M), 1.0)
    d = levelling_for(problem.points, cfg, shots)
    # the points with >= 6 shots within the largest search radius (10 km; a plane), or >= 3 (a profile fit may
    # take them), counted by brute force
    su = np.stack([np.cos(np.radians(shots.lat_deg)) * np.cos(np.radians(shots.lon_deg)),
                   np.cos(np.radians(shots.lat_deg)) * np.sin(np.radians(shots.lon_deg)),
                   np.sin(np.radians(shots.lat_deg))], axis=1)
    count = (np.arccos(np.clip(u @ su.T, -1, 1)) * DATUM_RADIUS_M <= 10_000.0).sum(axis=1)
    assert 0.5 < (count >= 6).mean() <= d.altimetry_share <= (count >= 3).mean() < 1.0
    assert d.level_to_mean is (d.altimetry_share <= 0.5)
    assert levelling_for(problem.points, cfg, None).altimetry_share == 0.0


def test_recentres_only_when_decided_and_there_is_a_radius_constraint() -> None:
    def decision(recentre: bool) -> LevellingDecision:
        return LevellingDecision(recentre=recentre, level_to_mean=recentre, extent_deg=20.0, altimetry_share=0.0,
                                 reason="test")

    with_radius = AdjustConfig(radius_sigma_m=10_000.0)
    assert recentres(decision(True), with_radius)
    assert not recentres(decision(False), with_radius)
    assert not recentres(decision(True), AdjustConfig(radius_sigma_m=None))  # nothing to centre
