"""Where the dense values' bias comes from (issue 31 done-when 1; docs/benchmarks/dense.md, session 6).

Reads a finished dense run (its ``dense.zarr``, ``dem.zarr``, ``registered.zarr``, ``registration/transform.json``)
and its mission's truth, writes nothing. Prints the cloud's error against the truth at its points in the adjusted
frame, moved by the registration's transform (``altimetry.merge.register_points``) without and with the mean
level, the sparse DEMs at the same points, the shots against the truth, and per stereo pair the cloud against the
truth and against the sparse DEM (a pair's own offset: what ``dense.level_pairs_on_sparse`` removes).

    PYTHONPATH=. .venv/bin/python workflows/benchmarks/diag_dense_bias.py RUN
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np


def _row(name: str, e: Any) -> str:
    e = np.asarray(e, np.float64)
    e = e[np.isfinite(e)]
    return (f"{name:44s} n {e.size:8d}  mean {e.mean():8.1f}  median {np.median(e):8.1f}  "
            f"rms {np.sqrt(np.mean(e * e)):8.1f}")


def main(argv: list[str] | None = None) -> None:
    """Print the decomposition."""
    import zarr

    from mercury_dem.altimetry.merge import blended_scalar, register_points
    from mercury_dem.geometry.body import latlon_to_xyz
    from mercury_dem.geometry.tiling import TileGrid
    from mercury_dem.io.dense_store import read_cloud
    from mercury_dem.io.run_store import read_registration_transform
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dem_stage import open_dem
    from mercury_dem.reference.sampling import sample_grid

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    run = ap.parse_args(argv).run
    mission = open_mission(json.loads((run / "run.json").read_text())["mission"])
    radius = mission.body.datum_radius_m
    truth = mission.need_truth().surface().height
    c = read_cloud(run / "dense.zarr")
    t_adj = truth(c["lat"], c["lon"])

    def dem_at(name: str, lat: Any, lon: Any) -> Any:
        d = open_dem(run / name)
        return sample_grid(d["elevation"].transpose("lat", "lon").values.astype(np.float64), d["lat"].values,
                           d["lon"].values, lat, lon)

    print(_row("cloud, adjusted frame - truth", c["height"] - t_adj))
    print(_row("dem.zarr at the points - truth", dem_at("dem.zarr", c["lat"], c["lon"]) - t_adj))
    t = read_registration_transform(run / "registration")
    if t is not None:
        tiles = TileGrid(float(t["tile_size_deg"]))
        xyz = latlon_to_xyz(c["lat"], c["lon"], height_m=c["height"], datum_radius_m=radius)
        la, lo, h = register_points(xyz, c["lat"], c["lon"], radius, t["table"], tiles, None)
        t_reg = truth(la, lo)
        level = (blended_scalar(np.asarray(t["level_offset_m"], np.float64), tiles, la, lo)
                 if t.get("level_offset_m") is not None else np.zeros_like(h))
        print(_row("transform's vertical move at the points", h - c["height"]))
        print(_row("registration's mean level at the points", level))
        print(_row("cloud moved + level - truth", h + level - t_reg))
        print(_row("registered.zarr at the points - truth", dem_at("registered.zarr", la, lo) - t_reg))
        own = np.asarray(t["own"], bool)
        tid = tiles.tile_of(c["lat"], c["lon"])
        print(f"tiles of the points: {np.unique(tid).size}, with their own transform {int(own[np.unique(tid)].sum())}")
    shots = mission.read_altimetry(columns=["lat", "lon", "radius_m"]) if mission.altimetry is not None else None
    if shots is not None and len(shots):
        sl, so = shots["lat"].to_numpy(), shots["lon"].to_numpy()
        print(_row("shots - truth", shots["radius_m"].to_numpy() - radius - truth(sl, so)))
    pairs = zarr.open_group(str(run / "dense.zarr"), mode="r").attrs.get("pairs") or []
    sparse = dem_at("dem.zarr", c["lat"], c["lon"])
    for p in np.unique(c["pair"]):
        m = c["pair"] == p
        rec = pairs[int(p)] if int(p) < len(pairs) else {}
        print(f"pair {int(p)} {rec.get('left', '')}/{rec.get('right', '')} incidences "
              f"{rec.get('incidence_left_deg', float('nan')):.0f}/{rec.get('incidence_right_deg', float('nan')):.0f} deg: "
              f"{int(m.sum())} points, cloud - truth mean {np.nanmean((c['height'] - t_adj)[m]):7.1f}, "
              f"cloud - dem.zarr mean {np.nanmean((c['height'] - sparse)[m]):7.1f}")


if __name__ == "__main__":
    main()
