"""The run store on a disk vs in an S3 bucket (moto's server on 127.0.0.1), side by side in one run.

    python workflows/benchmarks/bench_object_store.py [--mission DIR] [--repeats 1]

Runs the tiny mission (generated when --mission is not given) with ``--scheduler sync`` into a
local directory and into ``s3://bench/run-N`` (the mission read from the bucket too), then resumes
each; the four runs of a round (disk run, disk resume, bucket run, bucket resume) alternate over the rounds
(``harness.interleave``), each in a child of its own (``harness.measure``: wall, CPU, peak). Prints each round
(wall times, the bucket's object count, whether the global solutions are equal) and appends the record (medians,
bucket/disk ratio of the run medians) to ``records/object_store.jsonl`` (``harness.append_record``).
Needs ``moto[server]`` and ``s3fs`` (``make test`` installs them).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

from harness import append_record, interleave, measure, ratio_of_medians


def _moto(tmp: Path) -> tuple[subprocess.Popen[bytes], str]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    exe = Path(sys.executable).parent / "moto_server"
    proc = subprocess.Popen([str(exe), "-H", "127.0.0.1", "-p", str(port)], stdout=open(tmp / "moto.log", "wb"),
                            stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    for _ in range(150):
        try:
            urllib.request.urlopen(url + "/moto-api/", timeout=1).close()
            return proc, url
        except OSError:
            time.sleep(0.2)
    proc.kill()
    raise RuntimeError(f"moto_server did not start: {(tmp / 'moto.log').read_text()[-1000:]}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mission", type=Path)
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-objstore-"))
    proc, endpoint = _moto(tmp)
    os.environ.update({"AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench", "AWS_DEFAULT_REGION": "us-east-1",
                       "FSSPEC_S3_ENDPOINT_URL": endpoint, "MERCURY_DEM_CACHE": str(tmp / "cache")})
    import fsspec.config

    fsspec.config.conf["s3"] = {"endpoint_url": endpoint}
    try:
        import numpy as np

        from mercury_dem.config import load_config
        from mercury_dem.io.remote import RemoteDir
        from mercury_dem.io.run_store import RunStore, read_solution
        from mercury_dem.pipeline.graph import run_pipeline

        mission = args.mission
        if mission is None:
            from mercury_dem.config.synth import SynthConfig
            from mercury_dem.synth.generate import generate_mission

            mission = tmp / "tiny"
            generate_mission(mission, SynthConfig(preset="tiny", seed=42))
        config = load_config(overrides={
            "dem": {"pixels_per_degree": 4.0, "lat_min": -20.0, "lat_max": 30.0, "lon_min": -25.0, "lon_max": 25.0,
                    "chunk_size": 64, "browse_width": 256, "stats_pixel_km": 20.0, "coverage_pixel_km": 20.0}})
        remote = RemoteDir("s3://bench/mission")
        remote.fs.mkdir("bench")
        files = [p for p in sorted(mission.rglob("*")) if p.is_file()]
        t = time.perf_counter()
        remote.fs.put([str(p) for p in files], [remote.key(p.relative_to(mission).as_posix()) for p in files])
        print(f"mission upload: {len(files)} objects in {time.perf_counter() - t:.1f} s")
        rounds: list[int] = []

        def phase(name: str, what: str) -> Any:
            def run() -> Any:
                if (name, what) == ("disk", "run"):
                    rounds.append(len(rounds))  # a new round: new run directories
                k = rounds[-1]
                m, out = (mission, tmp / f"run-{k}") if name == "disk" else ("s3://bench/mission", f"s3://bench/run-{k}")
                return measure(lambda: bool(run_pipeline(m, out, config, scheduler="sync", stream=None)
                                            ["levels"]["global"]["ok"]), label=f"{name} {what}")
            return run

        ms = interleave({f"{n} {w}": phase(n, w) for n in ("disk", "bucket") for w in ("run", "resume")}, args.repeats)
        assert all(m.value for v in ms.values() for m in v), "a global adjustment failed"
        rows = []
        for k in rounds:
            a = read_solution(RunStore(tmp / f"run-{k}").solution_path("global", 0))
            b = read_solution(RunStore(f"s3://bench/run-{k}").solution_path("global", 0))
            n = len(RemoteDir(f"s3://bench/run-{k}").fs.find(f"bench/run-{k}"))
            row = {key: v[k].wall_s for key, v in ms.items()}
            equal = bool((a[0] == b[0]).all() and np.array_equal(a[1], b[1]))
            rows.append({"wall_s": row, "objects": n, "global_solutions_equal": equal})
            print(" | ".join(f"{key} {v:.1f} s" for key, v in row.items())
                  + f" | bucket/disk {row['bucket run'] / row['disk run']:.2f}x | {n} objects"
                  + f" | global solutions equal: {equal}")
        values = {"median_wall_s": {k: round(float(np.median([m.wall_s for m in v])), 2) for k, v in ms.items()},
                  "median_cpu_s": {k: round(float(np.median([m.cpu_s for m in v])), 2) for k, v in ms.items()},
                  "peak_rss_median_bytes": {k: int(np.median([m.peak_rss_bytes for m in v])) for k, v in ms.items()},
                  "bucket_over_disk_run": round(ratio_of_medians(ms["bucket run"], ms["disk run"]), 3),  # median bucket / disk
                  "rounds": rows}
        rec = append_record("object_store", {"mission": str(args.mission) if args.mission else "tiny (generated)",
                                             "repeats": args.repeats}, values)
        print(json.dumps(rec["values"], indent=2))
    finally:
        proc.terminate()
        proc.wait(timeout=10)


if __name__ == "__main__":
    main()
