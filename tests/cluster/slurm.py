"""A real one-node SLURM on this machine, started and stopped by a test (as root, Debian's slurm-wlm).

The daemons (munged, slurmctld, slurmd) run from a scratch directory with their own configuration,
munge key and socket, on free ports: nothing under /etc or /run is touched, and everything started
is stopped by pid at the end. Facts used are in ../shared/ECOSYSTEM-NOTES.md ("a real SLURM").
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

DAEMONS = ("munged", "slurmctld", "slurmd", "sbatch", "squeue", "scancel", "sinfo")


def missing() -> str | None:
    """Why a real SLURM cannot start here, or None."""
    if os.geteuid() != 0:
        return "a one-node SLURM needs root (slurmd runs jobs as their user)"
    absent = [d for d in DAEMONS if shutil.which(d) is None and not Path(f"/usr/sbin/{d}").exists()]
    if absent:
        return f"{', '.join(absent)} not installed (Debian: apt-get install slurm-wlm munge; 'make test' does it)"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _exe(name: str) -> str:
    return shutil.which(name) or f"/usr/sbin/{name}"


@dataclass
class Slurm:
    """A running one-node SLURM: the environment its client commands need, and its directory."""

    root: Path
    env: dict[str, str]
    pids: dict[str, Path] = field(default_factory=dict)

    def run(self, *cmd: str, timeout: float = 60) -> subprocess.CompletedProcess[str]:
        return subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout, env={**os.environ, **self.env})

    def log(self, name: str) -> str:
        path = self.root / f"{name}.log"
        return path.read_text(errors="replace")[-3000:] if path.exists() else ""


def _conf(root: Path, host: str, munge_socket: Path) -> str:
    return f"""ClusterName=mercurytest
SlurmctldHost={host}
SlurmUser=root
SlurmctldPort={_free_port()}
SlurmdPort={_free_port()}
AuthType=auth/munge
AuthInfo=socket={munge_socket}
CredType=cred/munge
StateSaveLocation={root}/state
SlurmdSpoolDir={root}/spool
SlurmctldPidFile={root}/slurmctld.pid
SlurmdPidFile={root}/slurmd.pid
SlurmctldLogFile={root}/slurmctld.log
SlurmdLogFile={root}/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
MpiDefault=none
ReturnToService=2
SelectType=select/cons_tres
SelectTypeParameters=CR_Core_Memory
SchedulerType=sched/backfill
NodeName={host} CPUs={os.cpu_count() or 2} RealMemory=8000 State=UNKNOWN
PartitionName=main Nodes={host} Default=YES MaxTime=INFINITE State=UP OverSubscribe=YES
"""


def _wait(cond, timeout: float, what: str, slurm: Slurm) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return
        time.sleep(0.5)
    raise RuntimeError(f"one-node SLURM: {what} within {timeout:.0f} s\nslurmctld: {slurm.log('slurmctld')}\n"
                       f"slurmd: {slurm.log('slurmd')}\nmunged: {slurm.log('munged')}")


@contextmanager
def one_node_slurm(root: Path) -> Iterator[Slurm]:
    """Start munged, slurmctld and slurmd under ``root``; yield; stop all three (by their pid files)."""
    for d in ("state", "spool", "munge"):
        (root / d).mkdir(parents=True, exist_ok=True)
    os.chmod(root / "munge", 0o700)
    key, sock = root / "munge" / "munge.key", root / "munge" / "munge.socket"
    key.write_bytes(os.urandom(1024))
    os.chmod(key, 0o600)
    host = socket.gethostname()
    conf = root / "slurm.conf"
    conf.write_text(_conf(root, host, sock))
    slurm = Slurm(root=root, env={"SLURM_CONF": str(conf)})
    slurm.pids = {"munged": root / "munged.pid", "slurmctld": root / "slurmctld.pid", "slurmd": root / "slurmd.pid"}
    try:
        subprocess.run([_exe("munged"), "--force", f"--key-file={key}", f"--socket={sock}",
                        f"--pid-file={slurm.pids['munged']}", f"--log-file={root / 'munged.log'}",
                        f"--seed-file={root / 'munge' / 'munge.seed'}"], check=True, capture_output=True, timeout=30)
        env = {**os.environ, **slurm.env}
        subprocess.run([_exe("slurmctld"), "-f", str(conf)], check=True, capture_output=True, timeout=30, env=env)
        subprocess.run([_exe("slurmd"), "-f", str(conf)], check=True, capture_output=True, timeout=30, env=env)
        _wait(lambda: "idle" in slurm.run("sinfo", "-h", "-o", "%T").stdout, 60, "the node did not become idle",
              slurm)
        yield slurm
    finally:
        for name in ("slurmd", "slurmctld", "munged"):
            pid_file = slurm.pids[name]
            try:
                pid = int(pid_file.read_text().split()[0])
                os.kill(pid, signal.SIGTERM)
            except (OSError, ValueError, IndexError):
                continue
            deadline = time.monotonic() + 15
            while time.monotonic() < deadline:
                try:
                    os.kill(pid, 0)
                except OSError:
                    break
                time.sleep(0.2)
            else:
                os.kill(pid, signal.SIGKILL)
