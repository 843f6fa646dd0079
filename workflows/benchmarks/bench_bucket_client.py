"""The client process's peak memory in a bucket run (issue 33 item 3, done-when 3).

    python workflows/benchmarks/bench_bucket_client.py [--mission DIR | --preset tiny] [--config YAML]
        [--workers 2] [--json] [--dir DIR]

Starts moto's S3 server on 127.0.0.1, uploads the mission (``--mission``, or one generated with
``--preset``) to ``s3://bench/mission`` and runs ``mercury-dem run`` into ``s3://bench/run`` on a
LocalCluster of ``--workers`` single-threaded worker processes, as a command under the harness's
``measure()`` (wall). The harness's command peak is the largest process of the tree (a worker's, as
well as the client's), so the client reports its own peak (``harness.peak_rss_bytes``: ``VmHWM`` of its own process, the
scheduler's thread included) on its last line; that is the figure. The units' ``summary.json`` are copied to
``DIR/run`` (for ``bench_cascade_merge.py``). Needs ``moto[server]`` and ``s3fs``.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_object_store import _moto  # noqa: E402  (beside this script)
from harness import append_record, measure, peak_rss_bytes  # noqa: E402


def client(mission: str, out: str, config: str | None, workers: int) -> None:
    """The run's client (this process): run the pipeline, print its own peak RSS as JSON."""
    from mercury_dem.config import load_config
    from mercury_dem.pipeline.graph import run_pipeline

    cfg = load_config(config) if config else load_config()
    rep = run_pipeline(mission, out, cfg, workers=workers, threads_per_worker=1, stream=None)
    peak = peak_rss_bytes()  # this process's own VmHWM (harness.memory)
    print(json.dumps({"client_peak_rss_bytes": peak, "global_ok": bool(rep["levels"]["global"]["ok"]),
                      "dem": sorted(rep.get("dem", {}))}))


def main() -> int:
    """Start moto, upload the mission, measure the bucket run (``--client`` is the measured child)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mission", type=Path)
    ap.add_argument("--preset", default="tiny")
    ap.add_argument("--config", type=Path)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--dir", type=Path)
    ap.add_argument("--label", default="", help="which code ran (recorded: the harness's commit is the script's)")
    ap.add_argument("--json", action="store_true", help="append the record to records/bucket_client.jsonl")
    ap.add_argument("--client", nargs=4, metavar=("MISSION", "OUT", "CONFIG", "WORKERS"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.client:
        m, o, c, w = args.client
        client(m, o, c or None, int(w))
        return 0
    tmp = args.dir or Path(tempfile.mkdtemp(prefix="bench-bucket-client-"))
    tmp.mkdir(parents=True, exist_ok=True)
    proc, endpoint = _moto(tmp)
    env = {**os.environ, "AWS_ACCESS_KEY_ID": "bench", "AWS_SECRET_ACCESS_KEY": "bench",
           "AWS_DEFAULT_REGION": "us-east-1", "FSSPEC_S3_ENDPOINT_URL": endpoint,
           "MERCURY_DEM_CACHE": str(tmp / "cache")}
    os.environ.update(env)
    import fsspec.config

    fsspec.config.conf["s3"] = {"endpoint_url": endpoint}
    try:
        from mercury_dem.io.remote import RemoteDir

        mission = args.mission
        if mission is None:
            from mercury_dem.config.synth import SynthConfig
            from mercury_dem.synth.generate import generate_mission

            mission = tmp / args.preset
            generate_mission(mission, SynthConfig(preset=args.preset, seed=42))
        remote = RemoteDir("s3://bench/mission")
        remote.fs.mkdir("bench")
        files = [p for p in sorted(mission.rglob("*")) if p.is_file()]
        remote.fs.put([str(p) for p in files], [remote.key(p.relative_to(mission).as_posix()) for p in files])
        cmd = [sys.executable, str(Path(__file__).resolve()), "--client", "s3://bench/mission", "s3://bench/run",
               str(args.config.resolve()) if args.config else "", str(args.workers)]
        t = time.strftime("%H:%M:%S")
        m = measure(cmd, label="bucket run", env=env, log=tmp / "client.log")
        last = [ln for ln in (tmp / "client.log").read_text().splitlines() if ln.startswith("{")][-1]
        values = {"wall_s": m.wall_s, "tree_peak_rss_bytes": m.peak_rss_bytes, **json.loads(last),
                  "started": t, "mission": str(mission)}
        print(json.dumps(values))
        run = RemoteDir("s3://bench/run")  # the units' summaries, for bench_cascade*.py (read_unit_timings)
        keys = [k for k in run.fs.find(run.key("")) if k.endswith("/summary.json")]
        run.fs.get(keys, [str(tmp / "run" / k[len(run.key("")):].lstrip("/")) for k in keys])
        if args.json:
            append_record("bucket_client", {"label": args.label, "preset": args.preset if args.mission is None else None, "workers": args.workers,
                                            "config": str(args.config) if args.config else None}, values)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
