"""Dense DEM against the sparse one on the tiny mission (issue 31, 'Done when' 1 and 2).

For each seed: the ``tiny`` mission generated and run in-process with the pipeline tests' configuration
(``workflows/tiny.yaml``; or an existing run given with ``--run``, copied first), then resumed with
``dense.enabled`` and ``--force dense``. Prints per seed the issue's ratio (the dense DEM's RMSE over the sparse
DEM's on the pixels the dense points reach), both biases, and the precision figures of the points against the
truth: true RMS / stated RMS and the share beyond 3 stated sigma.

Run (heavy: a whole tiny run per seed, ~5 min, plus the dense stage, 1-2 min; take the lock):
    flock /tmp/mercury_bench.lock nice -n 10 .venv/bin/python workflows/benchmarks/bench_dense_dem.py
        --workdir /tmp/dense_dem --seeds 42 7 [--run 42=/path/to/run] [--dense refine_window=7]
        [--render-grid-px 0.5]   (one command line)
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

TINY_CONFIG = Path(__file__).resolve().parents[1] / "tiny.yaml"


def tiny_config(**sections: dict) -> object:
    """The tests' tiny-mission configuration (``workflows/tiny.yaml``) with some sections updated."""
    import yaml

    from mercury_dem.config import load_config

    base = yaml.safe_load(TINY_CONFIG.read_text())
    for k, v in sections.items():
        base.setdefault(k, {}).update(v)
    return load_config(overrides=base)


def main(argv: list[str] | None = None) -> None:
    """Run the seeds and print one table row each."""
    from mercury_dem.config.synth import SynthConfig
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dense_stage import read_cloud
    from mercury_dem.pipeline.graph import run_pipeline
    from mercury_dem.synth.generate import generate_mission

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", type=Path, required=True)
    ap.add_argument("--seeds", type=int, nargs="+", default=[42, 7])
    ap.add_argument("--run", action="append", default=[], help="SEED=RUN: an existing tiny run of that seed")
    ap.add_argument("--dense", action="append", default=[], metavar="KEY=VALUE",
                    help="a dense.* key for the dense run (YAML value), e.g. refine_window=7; repeatable")
    ap.add_argument("--force", default="dense", choices=("dem", "dense"),
                    help="the stage the dense run recomputes from: dense (default), or dem (the DEM and its "
                         "registration too: a run registered before registration/transform.json was stored)")
    ap.add_argument("--render-grid-px", type=float, default=0.0,
                    help="the missions' renderer grid in ground pixels (synth.render_grid_px; 0: the preset's)")
    args = ap.parse_args(argv)
    import yaml

    dense_keys = {k: yaml.safe_load(v) for k, v in (d.split("=", 1) for d in args.dense)}
    given = {int(k): Path(v) for k, v in (r.split("=", 1) for r in args.run)}
    print(f"# bench_dense_dem {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} dense: {dense_keys}")
    print("| seed | points | parts / chips | dense RMSE (bias) m | sparse RMSE (bias) m | ratio | true/stated | > 3 sigma "
          "| stage s | dense alone RMSE (ratio) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        root = args.workdir / f"seed{seed}"
        run = root / "dense_run"
        shutil.rmtree(run, ignore_errors=True)
        if seed in given:
            shutil.copytree(given[seed], run)
            mission = Path(json.loads((run / "run.json").read_text())["mission"])
        else:
            mission = root / "mission"
            if not (mission / "catalog.parquet").exists():
                generate_mission(mission, SynthConfig(preset="tiny", seed=seed, render_grid_px=args.render_grid_px))
            run_pipeline(mission, run, tiny_config(), scheduler="sync", stream=None)
        rep = run_pipeline(mission, run, tiny_config(dense={"enabled": True, **dense_keys}), scheduler="sync", stream=None,
                           force=args.force)
        d, v = rep["dense"], rep["validation"]["dem"]
        a, b = v["dense_on_dense_pixels"], v["sparse_on_dense_pixels"]
        cloud = read_cloud(run / "dense.zarr")
        err = cloud["height"] - open_mission(mission).need_truth().surface().height(cloud["lat"], cloud["lon"])
        sig = cloud["sigma_h_m"].astype(np.float64)
        ratio = float(np.sqrt(np.mean(err**2) / np.mean(sig**2)))
        beyond = float(np.mean(np.abs(err) > 3 * sig))
        c = v.get("dense_alone_on_dense_pixels")  # before the fusion with the sparse DEM (dense.sparse_sigma_m)
        alone = f"{c['rmse_m']:.0f} ({c['rmse_m'] / b['rmse_m']:.2f})" if c else "-"
        print(f"# seed {seed}: dense DEM frame {d['dem'].get('frame', 'adjusted')}, sparse DEM "
              f"{d['dem'].get('sparse_dem', 'dem.zarr')}", flush=True)
        print(f"| {seed} | {d['points']} | {d.get('chip_parts')} / {d['chips']} | {a['rmse_m']:.0f} ({a['bias_m']:+.0f}) "
              f"| {b['rmse_m']:.0f} ({b['bias_m']:+.0f}) | {d['dem']['rmse_ratio_dense_over_sparse']:.2f} | {ratio:.2f} "
              f"| {100 * beyond:.2f} % | {rep['timings']['dense']:.0f} | {alone} |", flush=True)


if __name__ == "__main__":
    main()
