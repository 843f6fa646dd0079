"""``mercury-dem cluster {slurm,pbs} --dask-dir DIR [...] -- COMMAND``: Dask workers as batch jobs around a command."""

from __future__ import annotations

import argparse

from mercury_dem.config import Config

NAME = "cluster"
#: The command to run comes after '--' (``args.passthrough``, split off by the CLI).
PASSTHROUGH = True
HELP = "start a Dask scheduler here and its workers as SLURM/PBS jobs, run COMMAND against it, cancel the jobs"
DESCRIPTION = (
    "Start a Dask scheduler in this process and its workers as SLURM or PBS batch jobs (dask-jobqueue; the "
    "job shape from the package's slurm.yaml/pbs.yaml, overridable by Dask configuration or "
    "DASK_JOBQUEUE__SLURM__* variables), run COMMAND with MERCURY_DEM_SCHEDULER_FILE set, then cancel the "
    "jobs. TLS between all of them by default. Example: mercury-dem cluster slurm --dask-dir RUN.dask "
    "--jobs 4 -- mercury-dem run MISSION --out RUN --scheduler-file RUN.dask/scheduler.json "
    "(or simply: mercury-dem run MISSION --out RUN --cluster slurm --jobs 4)."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    from mercury_dem.cluster.jobqueue import SYSTEMS, add_launcher_arguments

    p.add_argument("system", choices=sorted(SYSTEMS), help="batch system")
    p.add_argument("--dask-dir", required=True, help="directory for scheduler.json, logs/ and tls/")
    add_launcher_arguments(p)
    p.add_argument("--print-job-script", action="store_true", help="print one job's script and exit")
    p.epilog = "-- COMMAND ...   the command to run against the cluster (required unless --print-job-script)"


def run(args: argparse.Namespace, config: Config) -> int:
    from mercury_dem.cluster.jobqueue import check_launcher_arguments, launch

    args.command = list(args.passthrough)
    check_launcher_arguments(argparse.ArgumentParser(prog="mercury-dem cluster"), args)
    return launch(args)
