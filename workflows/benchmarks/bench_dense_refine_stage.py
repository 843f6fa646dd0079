"""The dense stage on the tiny mission with each sub-pixel refinement (``dense.refine_method``; issue 31 done-when 3).

The tiny mission (seed 42) is run once without the dense stage (the configuration of the pipeline tests,
``workflows/tiny.yaml``); each method then resumes a copy with ``dense.enabled`` and ``--force dense``, as
``tests/pipeline/test_dense_stage.py`` does. Per method: the stage's seconds, the points, the dense DEM's RMSE
and bias against the truth on the dense pixels (fused with the sparse DEM, and alone), the sparse DEM's there,
and the points' true RMS / stated RMS and share beyond 3 stated sigma. Prints one JSON line per method.

Run (heavy, ~100 s + ~60-100 s per method; take the lock), from the repository root:
    flock /tmp/mercury_bench.lock nice -n 10 .venv/bin/python workflows/benchmarks/bench_dense_refine_stage.py \
        --workdir /tmp/dense_refine window_fit dense_lk:2 dense_lk:3
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]


def main(argv: list[str] | None = None) -> None:
    """Run the base mission once, then the dense stage per ``method[:iterations]``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workdir", type=Path, required=True)
    ap.add_argument("--seed", type=int, default=42)
    ap.add_argument("methods", nargs="+", help="window_fit, dense_lk or dense_lk:<iterations>")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from mercury_dem.config import load_config
    from mercury_dem.config.synth import SynthConfig
    from mercury_dem.mission import open_mission
    from mercury_dem.pipeline.dense_stage import read_cloud
    from mercury_dem.pipeline.graph import run_pipeline
    from mercury_dem.synth.generate import generate_mission
    from tests.pipeline.conftest import tiny_config
    from tests.viz.runs import TINY_CONFIG

    root = args.workdir
    root.mkdir(parents=True, exist_ok=True)
    mission, base = root / "mission", root / "run0"
    if not mission.exists():
        generate_mission(mission, SynthConfig(preset="tiny", seed=args.seed))
    if not (base / "report.json").is_file():
        t = time.perf_counter()
        run_pipeline(mission, base, load_config(overrides=TINY_CONFIG), scheduler="sync", stream=None)
        print(json.dumps({"base_run_s": round(time.perf_counter() - t, 1)}), flush=True)
    truth = open_mission(mission).need_truth().surface()
    for spec in args.methods:
        name, _, iterations = spec.partition(":")
        out = root / f"run_{name}{iterations}"
        shutil.rmtree(out, ignore_errors=True)
        shutil.copytree(base, out)
        dense: dict[str, object] = {"enabled": True, "refine_method": name}
        if iterations:
            dense["refine_iterations"] = int(iterations)
        t = time.perf_counter()
        rep = run_pipeline(mission, out, tiny_config(dense=dense), scheduler="sync", stream=None, force="dense")
        sec = time.perf_counter() - t
        val = rep["validation"]["dem"]
        cloud = read_cloud(out / "dense.zarr")
        err = cloud["height"] - truth.height(cloud["lat"], cloud["lon"])
        sig = cloud["sigma_h_m"].astype(np.float64)
        alone, sparse = val["dense_alone_on_dense_pixels"], val["sparse_on_dense_pixels"]
        print(json.dumps({
            "method": spec, "stage_s": round(sec, 1), "points": len(err),
            "ratio_fused": rep["dense"]["dem"]["rmse_ratio_dense_over_sparse"],
            "dense_rmse_m": val["dense_on_dense_pixels"]["rmse_m"], "dense_bias_m": val["dense_on_dense_pixels"]["bias_m"],
            "alone_rmse_m": alone["rmse_m"], "sparse_rmse_m": sparse["rmse_m"],
            "ratio_alone": alone["rmse_m"] / sparse["rmse_m"],
            "points_rms_m": float(np.sqrt(np.mean(err**2))),
            "true_over_stated": float(np.sqrt(np.mean(err**2) / np.mean(sig**2))),
            "beyond_3sigma": float(np.mean(np.abs(err) > 3 * sig))}), flush=True)


if __name__ == "__main__":
    main()
