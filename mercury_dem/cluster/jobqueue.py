"""Start a Dask scheduler here, its workers as SLURM or PBS batch jobs, and run a command against it.

    mercury-dem cluster {slurm,pbs} --dask-dir DIR [--jobs N | --adapt MIN:MAX]
        [--tls-dir CERTS | --no-tls] [--scheduler-host HOST] [--dashboard-address 127.0.0.1:8787]
        [--wait-workers K] -- COMMAND ...
    mercury-dem cluster {slurm,pbs} --dask-dir DIR --print-job-script
    mercury-dem run MISSION --out RUN --cluster {slurm,pbs} [--jobs N]   (the same, around the run)

(``cluster/jobqueue_launch.py`` and ``cluster/KIND/launch.sh`` in the source tree call this.)

The workers' shape (cores, memory, processes, walltime, local directory,
interface, the ``adjust_slots`` resource) comes from dask-jobqueue's
configuration. The package's defaults are ``slurm.yaml`` and ``pbs.yaml`` next to this
module; a site overrides any key with its own Dask configuration (a YAML in ``DASK_CONFIG``
or ``~/.config/dask``) or an environment variable such as
``DASK_JOBQUEUE__SLURM__WALLTIME=12:00:00``. The scheduler runs in this process and writes its address
to ``DIR/scheduler.json``; COMMAND (normally ``mercury-dem run MISSION --out RUN
--scheduler-file DIR/scheduler.json``) runs with ``MERCURY_DEM_SCHEDULER_FILE``
set and, with TLS, the ``DASK_DISTRIBUTED__COMM__TLS__*`` variables that let any
Dask client connect. When COMMAND ends (or this process gets SIGTERM/SIGINT)
the jobs are cancelled and the exit code is COMMAND's.

Secure by default: the scheduler listens on one address reachable from the
compute nodes (``--scheduler-host``, the configured interface, or this host's
outward address), every connection is TLS with certificates made in
``DIR/tls`` by ``make-certs.sh`` (next to this module; ``--no-tls`` to opt out), and
the dashboard binds to 127.0.0.1 (tunnel it: ``ssh -L 8787:127.0.0.1:8787 HOST``).
"""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SYSTEMS = {"slurm": "SLURMCluster", "pbs": "PBSCluster"}


def add_launcher_arguments(p: argparse.ArgumentParser) -> None:
    """The launcher's options (shared by ``mercury-dem cluster`` and ``run --cluster``), without the system."""
    p.add_argument("--jobs", type=int, default=2, help="batch jobs to submit (default 2)")
    p.add_argument("--adapt", metavar="MIN:MAX", help="scale between MIN and MAX jobs with the load instead of --jobs")
    p.add_argument("--scheduler-host", help="address the scheduler listens on (default: the configured "
                                            "interface's, else this host's outward address)")
    p.add_argument("--dashboard-address", help="scheduler dashboard (default from the YAML: 127.0.0.1:8787)")
    tls = p.add_mutually_exclusive_group()
    tls.add_argument("--tls-dir", help="ca.pem/cert.pem/key.pem to use (made there when absent; default DIR/tls)")
    tls.add_argument("--no-tls", action="store_true", help="plain TCP (only on a network you trust)")
    p.add_argument("--wait-workers", type=int, default=None,
                   help="wait for this many workers before COMMAND (default: 1 when jobs are submitted at once, "
                        "so 'mercury-dem run' sees the adjust_slots resource; a timeout is then only a warning)")
    p.add_argument("--timeout", type=float, default=3600.0, help="seconds to wait for --wait-workers")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The launcher's command line (``python -m mercury_dem.cluster.jobqueue``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    command: list[str] = []
    if "--" in argv:
        i = argv.index("--")
        argv, command = argv[:i], argv[i + 1:]
    p = argparse.ArgumentParser(prog="mercury-dem cluster", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("system", choices=sorted(SYSTEMS), help="batch system")
    p.add_argument("--dask-dir", required=True, help="directory for scheduler.json, logs/ and tls/")
    add_launcher_arguments(p)
    p.add_argument("--print-job-script", action="store_true", help="print one job's script and exit")
    args = p.parse_args(argv)
    args.command = command
    check_launcher_arguments(p, args)
    return args


def check_launcher_arguments(p: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse inconsistent launcher options (``p.error``); fill ``args.wait_workers`` and ``args.adapt``."""
    if not getattr(args, "print_job_script", False) and not args.command:
        p.error("give the command to run after '--' (e.g. -- mercury-dem run MISSION --out RUN --scheduler-file ...)")
    if args.jobs < 0:
        p.error("--jobs must be >= 0")
    if args.adapt:
        try:
            lo, hi = (int(v) for v in args.adapt.split(":"))
        except ValueError:
            p.error(f"--adapt takes MIN:MAX job counts, got {args.adapt!r}")
        if not 0 <= lo <= hi:
            p.error(f"--adapt needs 0 <= MIN <= MAX, got {args.adapt!r}")
        args.adapt = (lo, hi)
    args.wait_explicit = args.wait_workers is not None
    if args.wait_workers is None:
        args.wait_workers = default_wait_workers(args.jobs, args.adapt)


def default_wait_workers(jobs: int, adapt: tuple[int, int] | None) -> int:
    """Workers to wait for before COMMAND when ``--wait-workers`` is not given.

    ``mercury-dem run`` (``execution.adjust_resource: auto``) limits the memory-heavy
    adjustments to one per worker when the workers it sees at start advertise the
    ``adjust_slots`` resource, so it should start after the first worker has joined;
    with ``--adapt 0:N`` no worker comes before there is work: set
    ``execution: {adjust_resource: "on"}`` in the run's configuration instead.
    """
    if adapt is not None:
        return 1 if adapt[0] > 0 else 0
    return 1 if jobs > 0 else 0


def make_certificates(directory: Path, hosts: list[str]) -> Path:
    """ca.pem, cert.pem and key.pem in ``directory`` (kept when they exist)."""
    if not (directory / "key.pem").exists():
        subprocess.run(["bash", str(HERE / "make-certs.sh"), str(directory), "--hosts", ",".join(hosts)],
                       check=True, stdout=subprocess.DEVNULL)
    return directory


def load_defaults(system: str) -> None:
    """The package's ``SYSTEM.yaml`` as Dask configuration defaults: keys a site set keep its value."""
    import dask
    import dask_jobqueue  # noqa: F401 - its own defaults first, so ours replace its nulls
    import yaml

    dask.config.update_defaults(yaml.safe_load((HERE / f"{system}.yaml").read_text()))


def build_cluster(args: argparse.Namespace, dask_dir: Path):  # -> dask_jobqueue.JobQueueCluster
    """The SLURMCluster/PBSCluster of the configuration, with this run's scheduler file, logs and TLS."""
    import dask
    import dask_jobqueue
    from distributed.utils import get_ip, get_ip_interface

    load_defaults(args.system)
    key = f"jobqueue.{args.system}"
    if dask.config.get(f"{key}.cores", None) is None or dask.config.get(f"{key}.memory", None) is None:
        raise SystemExit(f"mercury-dem cluster: no cores/memory in the Dask configuration '{key}' (a site "
                         f"configuration set them to null?); set DASK_JOBQUEUE__{args.system.upper()}__CORES and "
                         f"__MEMORY or fix the YAML in DASK_CONFIG ({os.environ.get('DASK_CONFIG')!r})")
    options = dict(dask.config.get(f"{key}.scheduler-options", None) or {})
    options["scheduler_file"] = str(dask_dir / "scheduler.json")
    if args.dashboard_address:
        options["dashboard_address"] = args.dashboard_address
    options.setdefault("dashboard_address", "127.0.0.1:8787")
    interface = dask.config.get(f"{key}.interface", None)
    host = args.scheduler_host or (get_ip_interface(interface) if interface else get_ip())
    options["host"] = host
    options.pop("interface", None)

    security = None
    if not args.no_tls:
        from mercury_dem.compute.security import TlsFiles, tls_security

        tls_dir = Path(args.tls_dir) if args.tls_dir else dask_dir / "tls"
        hosts = sorted({host, "127.0.0.1", "localhost", socket.gethostname()})
        files = TlsFiles.in_directory(make_certificates(tls_dir, hosts))
        security = tls_security(files)
        args.tls_files = files
    cls = getattr(dask_jobqueue, SYSTEMS[args.system])
    return cls(
        scheduler_options=options,
        log_directory=str(dask_dir / "logs"),
        security=security,
    )


def main(argv: list[str] | None = None) -> int:
    """Run the launcher from a command line; its exit code."""
    return launch(parse_args(argv))


def launch(args: argparse.Namespace) -> int:
    """Start the cluster of ``args`` (from :func:`parse_args`), run ``args.command``, cancel the jobs."""
    dask_dir = Path(args.dask_dir).resolve()
    (dask_dir / "logs").mkdir(parents=True, exist_ok=True)
    os.chmod(dask_dir, 0o700)
    (dask_dir / "scheduler.json").unlink(missing_ok=True)
    args.tls_files = None

    cluster = build_cluster(args, dask_dir)

    def _stop(signum: int, _frame: object) -> None:
        raise SystemExit(128 + signum)

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    try:
        if args.print_job_script:
            print(cluster.job_script())
            return 0
        (dask_dir / "launcher.pid").write_text(str(os.getpid()))
        print(f"scheduler {cluster.scheduler_address}  file {dask_dir / 'scheduler.json'}", flush=True)
        print(f"dashboard {cluster.dashboard_link} (bound to this host; tunnel it with ssh -L)", flush=True)
        if args.adapt:
            cluster.adapt(minimum_jobs=args.adapt[0], maximum_jobs=args.adapt[1])
            print(f"adaptive: {args.adapt[0]}..{args.adapt[1]} jobs", flush=True)
        else:
            cluster.scale(jobs=args.jobs)
            print(f"submitted {args.jobs} jobs", flush=True)
        env = dict(os.environ, MERCURY_DEM_SCHEDULER_FILE=str(dask_dir / "scheduler.json"))
        if args.tls_files is not None:
            from mercury_dem.compute.security import tls_environment

            env.update(tls_environment(args.tls_files))
        if args.wait_workers:
            from distributed import Client

            with Client(cluster, timeout=60) as client:
                t0 = time.monotonic()
                try:
                    client.wait_for_workers(args.wait_workers, timeout=args.timeout)
                except TimeoutError:
                    if args.wait_explicit:
                        raise
                    print(f"no worker joined within {args.timeout:.0f} s; running anyway (the adjustments are "
                          "limited to one per worker only with execution.adjust_resource: on)", flush=True)
                else:
                    print(f"{args.wait_workers} workers joined in {time.monotonic() - t0:.0f} s", flush=True)
        elif args.adapt:
            print("no worker is waited for (--adapt 0:N): set execution.adjust_resource: on in the run's "
                  "configuration so the adjustments stay one per worker", flush=True)
        print("running:", " ".join(args.command), flush=True)
        return subprocess.run(args.command, env=env).returncode
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        signal.signal(signal.SIGINT, signal.SIG_DFL)
        cluster.close()
        (dask_dir / "launcher.pid").unlink(missing_ok=True)


if __name__ == "__main__":
    sys.exit(main())
