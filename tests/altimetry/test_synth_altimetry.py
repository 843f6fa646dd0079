"""The tiny synthetic mission carries simulated MLA: enough profiles in every tile of its area, shots on
the truth surface within the injected errors, the per-profile orbit errors kept apart in truth/."""

from __future__ import annotations

import numpy as np

from mercury_dem.geometry.tiling import TileGrid


def test_tiny_mission_has_simulated_altimetry(tiny_mission) -> None:
    alt = tiny_mission.altimetry
    assert alt is not None and alt.n_shots > 100_000 and alt.dropped["flagged"] > 0
    grid = TileGrid(alt.tile_size_deg)
    area_tiles = {int(grid.tile_of(la, lo)) for la in (-5, 5, 15) for lo in (-12, -5, 5, 12)}
    assert len(area_tiles) == 12
    for t in area_tiles:
        shots = tiny_mission.read_altimetry(t, ["profile_id", "radius_m"])
        assert shots["profile_id"].nunique() >= 20, t
    # shots lie on the truth surface up to the injected errors (1 m noise, ~3 m radial orbit error,
    # 100-150 m horizontal error times the slopes, 1.5 % wild ranges)
    shots = tiny_mission.read_altimetry(sorted(area_tiles)[4])
    surface = tiny_mission.truth.surface()
    datum = tiny_mission.body.datum_radius_m
    d = shots["radius_m"].to_numpy() - datum - surface.height(shots["lat"].to_numpy(), shots["lon"].to_numpy())
    assert abs(np.median(d)) < 5.0 and np.percentile(np.abs(d), 90) < 60.0
    assert (shots["sigma_m"] == 1.0).all()
    prof = tiny_mission.truth.altimetry_profiles
    assert set(prof["profile_id"]) >= set(shots["profile_id"])
    assert 50 < np.hypot(prof["east_m"], prof["north_m"]).mean() < 400 and prof["up_m"].abs().max() < 15
    assert tiny_mission.meta["altimetry"]["n_shots"] == alt.n_shots
