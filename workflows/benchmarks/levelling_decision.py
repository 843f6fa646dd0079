"""The levelling decision (adjust.datum.levelling_decision) of a finished run's global network and its mission.

The network's a-priori points on the datum, and the mission's altimetry counted as the run would
(radius_priors_within at the largest search radius); prints the decision and the time of the count.

    PYTHONPATH=. python workflows/benchmarks/levelling_decision.py RUN MISSION
"""
import sys, time, numpy as np
from mercury_dem.mission import open_mission
from mercury_dem.network.store import read_network
from mercury_dem.adjust.datum import levelling_decision
from mercury_dem.altimetry.constraints import radius_priors_within
from mercury_dem.pipeline.adjust_adapter import on_datum
from mercury_dem.config.adjust import AdjustConfig
run, mission = sys.argv[1], sys.argv[2]
net = read_network(f"{run}/global/0/network.zarr")
m = open_mission(mission)
xyz = np.asarray(net.apriori_xyz, float)
xyz = on_datum(xyz[np.all(np.isfinite(xyz), axis=1)], m.body.datum_radius_m)
cfg = AdjustConfig()
t = time.perf_counter()
c = None
if m.altimetry is not None:
    sh = m.read_altimetry()
    c = radius_priors_within(xyz, sh["lat"].to_numpy(), sh["lon"].to_numpy(), sh["radius_m"].to_numpy(),
                             search_radius_m=max(cfg.altimetry_search_m), min_shots=cfg.altimetry_min_shots).constrained
d = levelling_decision(xyz, c)
print(len(xyz), d, f"{time.perf_counter() - t:.1f} s")
