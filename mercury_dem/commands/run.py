"""``mercury-dem run MISSION --out RUN``: the whole job, tiles -> regions -> hemispheres -> globe -> DEM."""

from __future__ import annotations

import argparse
import sys

from mercury_dem.compute.security import add_tls_arguments, security_from_args
from mercury_dem.config import Config

NAME = "run"
HELP = "run (or resume) the whole pipeline on a mission: matching, hierarchical adjustment, DEM, products"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("mission", help="mission store (e.g. from 'mercury-dem synth')")
    p.add_argument("--out", required=True, help="run directory (created, or resumed when it exists)")
    p.add_argument("--scheduler", help="'local' (default: LocalCluster), 'sync' (in-process) or tcp://HOST:PORT")
    p.add_argument("--scheduler-file", help="Dask scheduler file of an existing cluster")
    p.add_argument("--workers", type=int, help="LocalCluster workers (default: one per core)")
    p.add_argument("--threads-per-worker", type=int, help="LocalCluster threads per worker")
    add_tls_arguments(p)
    p.add_argument("--force", metavar="STAGE", help="recompute from STAGE on: plan, tile, region, hemisphere, global, dem, dense")
    p.add_argument("--no-dem", action="store_true", help="stop after the global adjustment")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    g = p.add_argument_group("batch system (--cluster): the workers as SLURM/PBS jobs, as 'mercury-dem cluster'")
    g.add_argument("--cluster", choices=("slurm", "pbs"),
                   help="submit the workers as batch jobs of this system and run against them")
    g.add_argument("--dask-dir", help="with --cluster: scheduler file, logs and TLS files (default RUN.dask)")
    from mercury_dem.cluster.jobqueue import add_launcher_arguments

    add_launcher_arguments(g)


def _run_on_batch_cluster(args: argparse.Namespace) -> int:
    """The same run, as the command of ``mercury-dem cluster`` (scheduler here, workers as batch jobs)."""
    from mercury_dem.cluster.jobqueue import check_launcher_arguments, launch
    from mercury_dem.exceptions import ConfigError

    if args.scheduler or args.scheduler_file or args.workers or args.threads_per_worker:
        raise ConfigError("--cluster starts its own scheduler: drop --scheduler, --scheduler-file, --workers and "
                          "--threads-per-worker (the job shape comes from the jobqueue configuration)")
    dask_dir = args.dask_dir or f"{str(args.out).rstrip('/')}.dask"
    command = [sys.executable, "-m", "mercury_dem.cli", "run", str(args.mission), "--out", str(args.out),
               "--scheduler-file", f"{dask_dir}/scheduler.json"]
    for flag, value in (("--config", args.config), ("--force", args.force)):
        if value:
            command += [flag, str(value)]
    command += [flag for flag, on in (("--no-dem", args.no_dem), ("--quiet", args.quiet)) if on]
    launcher = argparse.Namespace(**vars(args))
    launcher.system, launcher.dask_dir, launcher.command, launcher.print_job_script = (
        args.cluster, dask_dir, command, False)
    check_launcher_arguments(argparse.ArgumentParser(prog="mercury-dem run --cluster"), launcher)
    return launch(launcher)


def run(args: argparse.Namespace, config: Config) -> int:
    if args.cluster:
        return _run_on_batch_cluster(args)
    from mercury_dem.pipeline.graph import run_pipeline
    from mercury_dem.pipeline.report import print_report

    report = run_pipeline(
        args.mission, args.out, config,
        scheduler=args.scheduler, scheduler_file=args.scheduler_file,
        workers=args.workers, threads_per_worker=args.threads_per_worker, security=security_from_args(args),
        force=args.force, stream=None if args.quiet else sys.stdout, dem=not args.no_dem,
    )
    print()
    print_report(report, sys.stdout)
    print(f"\noutputs: {args.out}/report.json, {args.out}/global/0/ (adjusted network and pointing)"
          + (f", {args.out}/dem.zarr, {args.out}/products/" if "dem" in report else "")
          + (f", {args.out}/dense.zarr, {args.out}/dem_dense.zarr" if "dem" in report.get("dense", {}) else ""))
    glob = report["levels"]["global"]
    return 0 if glob and glob.get("ok") else 1
