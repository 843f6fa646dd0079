"""The levelling decision (adjust.datum.levelling_decision) of a finished run's global network and its mission.

The network's a-priori points on the datum, and the mission's altimetry counted as the run would
(radius_priors_within at the largest search radius); prints the decision and the time of the count.

    PYTHONPATH=. python workflows/benchmarks/levelling_decision.py RUN MISSION
"""

from __future__ import annotations

import sys
import time

import numpy as np

from mercury_dem.adjust.datum import levelling_decision, on_datum
from mercury_dem.altimetry.constraints import radius_priors_within
from mercury_dem.config.adjust import AdjustConfig
from mercury_dem.io.network_store import read_network
from mercury_dem.mission import open_mission


def main(run: str, mission_path: str) -> None:
    net = read_network(f"{run}/global/0/network.zarr")
    mission = open_mission(mission_path)
    xyz = np.asarray(net.apriori_xyz, np.float64)
    xyz = on_datum(xyz[np.all(np.isfinite(xyz), axis=1)], mission.body.datum_radius_m)
    cfg = AdjustConfig()
    t = time.perf_counter()
    constrained = None
    if mission.altimetry is not None:
        shots = mission.read_altimetry()
        constrained = radius_priors_within(
            xyz, shots["lat"].to_numpy(), shots["lon"].to_numpy(), shots["radius_m"].to_numpy(),
            search_radius_m=max(cfg.altimetry_search_m), min_shots=cfg.altimetry_min_shots,
        ).constrained
    decision = levelling_decision(xyz, constrained, min_extent_deg=cfg.point_prior_recentre_min_extent_deg,
                                  max_altimetry_share=cfg.point_prior_recentre_max_altimetry_share)
    print(f"{len(xyz)} points: {decision.summary()} ({time.perf_counter() - t:.1f} s)")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
