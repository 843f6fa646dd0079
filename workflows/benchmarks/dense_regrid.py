"""The dense DEM of a finished dense run gridded again with the current code, without matching again (issue 31;
docs/benchmarks/dense.md, session 5): its validation on the pixels the dense points reach.

Copies the run's ``run.json``, ``dem.zarr``, ``dense.zarr`` and (unless ``--adjusted``) ``registered.zarr`` and
``registration/`` into OUT, then ``pipeline.dense_dem.grid_dense_dem`` (with the mission's altimetry, as the stage)
and ``validate_dense_dem``. ``--adjusted``: without the registration, the dense DEM in the adjusted frame (with
``dense.level_to_altimetry=false``: the dense DEM as it was before session 5). ``KEY=VALUE``: a config override
(JSON value), e.g. ``dense.grid_smoothing_passes=0``. ~20 s per run; light, no lock.

    .venv/bin/python workflows/benchmarks/dense_regrid.py RUN OUT [--adjusted] [dense.level_to_altimetry=false]
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path


def main(argv: list[str] | None = None) -> None:
    """One line per run: the dense DEM's and the sparse DEM's RMSE (bias) and the ratio, and the dense value alone."""
    from mercury_dem.config import load_config
    from mercury_dem.io.run_store import DEM_DENSE_FILE, RunStore
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dense_dem import grid_dense_dem, rmse_ratio, validate_dense_dem
    from mercury_dem.progress import Reporter

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("overrides", nargs="*", metavar="SECTION.KEY=VALUE")
    ap.add_argument("--adjusted", action="store_true", help="without the registration (the adjusted frame)")
    args = ap.parse_intermixed_args(argv)
    src, out = args.run, args.out
    names = ["run.json", "report.json", "dem.zarr", "dense.zarr"]
    if not args.adjusted:
        names += ["registered.zarr", "registration"]
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        if (src / name).exists() and not (out / name).exists():
            (shutil.copytree if (src / name).is_dir() else shutil.copy)(src / name, out / name)
    info = json.loads((out / "run.json").read_text())
    over = info["config"]
    for kv in args.overrides:
        k, v = kv.split("=", 1)
        sec, key = k.split(".", 1)
        over.setdefault(sec, {})[key] = json.loads(v)
    config = load_config(overrides=over)
    mission = open_mission(Path(info["mission"]))
    d = json.loads((src / "report.json").read_text())["dense"]["dem"]
    shots = (mission.read_altimetry(columns=["lat", "lon", "radius_m"])
             if mission.altimetry is not None and mission.altimetry.n_shots else None)
    blk = grid_dense_dem(RunStore(out), config, d["pixels_per_degree"], None, mission.body, Reporter(None),
                         d["median_pair_pixel_scale_m"], shots=shots)
    v = validate_dense_dem(out / DEM_DENSE_FILE, mission.need_truth().surface().height)
    a, b, c = v["dense_on_dense_pixels"], v["sparse_on_dense_pixels"], v["dense_alone_on_dense_pixels"]
    print(f"# {src} {' '.join(args.overrides)}: frame {blk['frame']}; level {blk.get('altimetry_level')}")
    print(f"| dense {a['rmse_m']:.0f} ({a['bias_m']:+.0f}) | sparse {b['rmse_m']:.0f} ({b['bias_m']:+.0f}) | ratio "
          f"{rmse_ratio(v):.2f} | alone {c['rmse_m']:.0f} ({c['bias_m']:+.0f}) {c['rmse_m'] / b['rmse_m']:.2f} |")


if __name__ == "__main__":
    main()
