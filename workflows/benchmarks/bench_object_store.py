"""The run store on a disk vs in an S3 bucket (moto's server on 127.0.0.1), side by side in one run.

    python workflows/benchmarks/bench_object_store.py [--mission DIR] [--repeats 1]

Runs the tiny mission (generated when --mission is not given) with ``--scheduler sync`` into a
local directory and into ``s3://bench/run-N`` (the mission read from the bucket too), then resumes
each; prints wall times, the bucket's object count and whether the global solutions are equal.
Needs ``moto[server]`` and ``s3fs`` (``make test`` installs them).
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path


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
        for k in range(args.repeats):
            row = {}
            for name, m, out in (("disk", mission, tmp / f"run-{k}"), ("bucket", "s3://bench/mission", f"s3://bench/run-{k}")):
                for phase in ("run", "resume"):
                    t = time.perf_counter()
                    rep = run_pipeline(m, out, config, scheduler="sync", stream=None)
                    row[f"{name} {phase}"] = time.perf_counter() - t
                    assert rep["levels"]["global"]["ok"]
            a = read_solution(RunStore(tmp / f"run-{k}").solution_path("global", 0))
            b = read_solution(RunStore(f"s3://bench/run-{k}").solution_path("global", 0))
            n = len(RemoteDir(f"s3://bench/run-{k}").fs.find(f"bench/run-{k}"))
            print(" | ".join(f"{key} {v:.1f} s" for key, v in row.items())
                  + f" | bucket/disk {row['bucket run'] / row['disk run']:.2f}x | {n} objects"
                  + f" | global solutions equal: {bool((a[0] == b[0]).all() and np.array_equal(a[1], b[1]))}")
    finally:
        proc.terminate()
        proc.wait(timeout=10)


if __name__ == "__main__":
    main()
