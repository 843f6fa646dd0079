"""cluster/slurm and cluster/pbs: job scripts rendered by dask-jobqueue from the repo's YAML, and a
whole launch.sh run (each system's wrapper of cluster/common/launch_jobqueue.sh) against stand-in
batch commands that run the job scripts on this machine."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from mercury_dem.cluster import jobqueue
from mercury_dem.compute import ADJUST_RESOURCE
from tests.cluster.conftest import CLUSTER, script_env

pytest.importorskip("dask_jobqueue", reason="dask-jobqueue is not installed (pip install -e '.[test]')")

LAUNCHER = CLUSTER / "jobqueue_launch.py"
#: The job shapes ship inside the package (the wheel has no cluster/ directory).
PACKAGE_CLUSTER = Path(jobqueue.__file__).parent


def _yaml(system: str) -> dict:
    return yaml.safe_load((PACKAGE_CLUSTER / f"{system}.yaml").read_text())["jobqueue"][system]


def render(system: str, tmp_path: Path, *extra: str, env: dict[str, str] | None = None) -> str:
    """The job script, from ``mercury-dem cluster`` with no site configuration."""
    res = subprocess.run(
        [sys.executable, "-m", "mercury_dem.cli", "cluster", system, "--dask-dir", str(tmp_path / "dask"),
         "--print-job-script", "--scheduler-host", "127.0.0.1", *extra],
        capture_output=True, text=True, timeout=120, env=env or script_env(),
    )
    assert res.returncode == 0, res.stderr
    return res.stdout


def _worker_line(script: str) -> str:
    (line,) = [ln for ln in script.splitlines() if "distributed.cli.dask_worker" in ln]
    return line


def _common_worker_checks(line: str, conf: dict, scheme: str) -> None:
    cores, processes = conf["cores"], conf["processes"]
    assert line.startswith(sys.executable + " -m distributed.cli.dask_worker ")
    assert re.search(rf"dask_worker {scheme}://127\.0\.0\.1:\d+ ", line), line
    assert f"--nworkers {processes}" in line
    assert f"--nthreads {cores // processes}" in line
    assert f"--resources {ADJUST_RESOURCE}=1" in line  # the resource the pipeline asks for
    assert "--local-directory ${TMPDIR:-/tmp}" in line
    assert "--dashboard-address 127.0.0.1:0" in line
    assert f"--death-timeout {conf['death-timeout']}" in line


def test_slurm_job_script_from_the_repo_yaml(tmp_path: Path) -> None:
    conf = _yaml("slurm")
    script = render("slurm", tmp_path)
    assert script.startswith("#!/usr/bin/env bash")
    assert f"#SBATCH -J {conf['name']}" in script
    assert f"#SBATCH --cpus-per-task={conf['cores']}" in script
    mem_gib = int(conf["memory"].removesuffix("GiB"))
    assert f"#SBATCH --mem={mem_gib}G" in script
    assert f"#SBATCH -t {conf['walltime']}" in script
    assert f"#SBATCH -e {tmp_path / 'dask' / 'logs'}/" in script
    line = _worker_line(script)
    _common_worker_checks(line, conf, "tls")
    assert f"--memory-limit {mem_gib / conf['processes']:.2f}GiB" in line
    # TLS by default: the workers get the certificates made in DIR/tls.
    tls = tmp_path / "dask" / "tls"
    for flag, name in (("--tls-ca-file", "ca.pem"), ("--tls-cert", "cert.pem"), ("--tls-key", "key.pem")):
        assert f"{flag} {tls / name}" in line
    assert oct((tls / "key.pem").stat().st_mode & 0o777) == "0o600"


def test_pbs_job_script_from_the_repo_yaml(tmp_path: Path) -> None:
    conf = _yaml("pbs")
    # The resource request and the worker shape say the same thing.
    m = re.fullmatch(r"select=1:ncpus=(\d+):mem=(\d+)GB", conf["resource-spec"])
    assert m and int(m.group(1)) == conf["cores"] and f"{m.group(2)}GB" == conf["memory"]
    script = render("pbs", tmp_path, "--no-tls")
    assert f"#PBS -N {conf['name']}" in script
    assert f"#PBS -l {conf['resource-spec']}" in script
    assert f"#PBS -l walltime={conf['walltime']}" in script
    line = _worker_line(script)
    _common_worker_checks(line, conf, "tcp")
    mem_per_worker = int(conf["memory"].removesuffix("GB")) * 1e9 / conf["processes"] / 2**30
    assert f"--memory-limit {mem_per_worker:.2f}GiB" in line
    assert "--tls-" not in line


def test_launcher_waits_for_a_first_worker_by_default() -> None:
    """'mercury-dem run' turns the adjust resource on when the workers it sees advertise it: let one join first."""
    mod = jobqueue
    base = ["slurm", "--dask-dir", "d", "--", "mercury-dem", "run"]
    assert mod.parse_args(base).wait_workers == 1  # --jobs 2 by default
    assert mod.parse_args(base[:3] + ["--jobs", "0"] + base[3:]).wait_workers == 0
    assert mod.parse_args(base[:3] + ["--adapt", "2:8"] + base[3:]).wait_workers == 1
    assert mod.parse_args(base[:3] + ["--adapt", "0:8"] + base[3:]).wait_workers == 0
    explicit = mod.parse_args(base[:3] + ["--wait-workers", "3"] + base[3:])
    assert explicit.wait_workers == 3 and explicit.wait_explicit
    assert not mod.parse_args(base).wait_explicit


def test_a_site_configuration_overrides_the_package_shape(tmp_path: Path) -> None:
    """The package's slurm.yaml is only the default: a site YAML in DASK_CONFIG and variables win."""
    site = tmp_path / "site"
    site.mkdir()
    (site / "jobqueue.yaml").write_text("jobqueue:\n  slurm:\n    walltime: '12:00:00'\n    queue: long\n")
    script = render("slurm", tmp_path, "--no-tls",
                    env=script_env(DASK_CONFIG=str(site), DASK_JOBQUEUE__SLURM__CORES="4"))
    assert "#SBATCH -t 12:00:00" in script and "#SBATCH -p long" in script
    assert "#SBATCH --cpus-per-task=4" in script
    assert f"#SBATCH -J {_yaml('slurm')['name']}" in script  # the rest from the package


# --- a whole launch.sh run, the batch system stood in for by scripts that run the job on this machine ---

#: system -> (submit command, cancel command, job-script directive, memory unit of the YAML)
BATCH = {"slurm": ("sbatch", "scancel", "#SBATCH --cpus-per-task=2", "GiB"),
         "pbs": ("qsub", "qdel", "#PBS -N mercury-dem-worker", "GB")}

FAKE_SUBMIT = """#!/usr/bin/env bash
# stand-in for sbatch/qsub: keep a copy of the job script and run it in its own process group
set -e
n=$(ls "$FAKE_BATCH_DIR"/job-*.sh 2>/dev/null | wc -l)
cp "$1" "$FAKE_BATCH_DIR/job-$n.sh"
setsid bash "$FAKE_BATCH_DIR/job-$n.sh" > "$FAKE_BATCH_DIR/job-$n.log" 2>&1 < /dev/null &
echo $! >> "$FAKE_BATCH_DIR/jobids"
echo "Submitted batch job $!"
"""
FAKE_CANCEL = """#!/usr/bin/env bash
# stand-in for scancel/qdel: end the job's process group
for id in "$@"; do echo "$id" >> "$FAKE_BATCH_DIR/cancelled"; kill -TERM -- "-$id" 2>/dev/null || true; done
"""
# Stands in for mercury-dem: records its arguments, then works through the scheduler file it is given,
# connecting with nothing but the environment the launcher set (TLS included).
FAKE_MERCURY_DEM = """#!{python}
import json, os, sys
from distributed import Client
args = sys.argv[1:]
sched = args[args.index("--scheduler-file") + 1]
assert sched == os.environ["MERCURY_DEM_SCHEDULER_FILE"]
with Client(scheduler_file=sched, timeout=30) as c:
    workers = c.scheduler_info(n_workers=-1)["workers"]
    total = c.submit(sum, range(10), resources={{"{resource}": 1}}).result()
    out = {{"argv": args, "address": c.scheduler.address, "total": total,
           "resources": [w["resources"] for w in workers.values()], "nthreads": [w["nthreads"] for w in workers.values()]}}
open(os.environ["FAKE_BATCH_DIR"] + "/mercury-dem.json", "w").write(json.dumps(out))
"""


# PBS end to end takes another ~16 s: slow; by default PBS is covered by its rendered job script and the
# wrapper test below (both systems run the same cluster/common/launch_jobqueue.sh).
@pytest.mark.parametrize("system", ["slurm", pytest.param("pbs", marks=pytest.mark.slow)])
def test_launch_runs_the_command_on_batch_workers_and_cancels_them(system: str, tmp_path: Path) -> None:
    import json

    import psutil

    bin_dir, batch = tmp_path / "bin", tmp_path / "batch"
    bin_dir.mkdir()
    batch.mkdir()
    submit, cancel, directive, unit = BATCH[system]
    for name, text in ((submit, FAKE_SUBMIT), (cancel, FAKE_CANCEL),
                       ("mercury-dem", FAKE_MERCURY_DEM.format(python=sys.executable, resource=ADJUST_RESOURCE))):
        (bin_dir / name).write_text(text)
        (bin_dir / name).chmod(0o755)
    mission, run = tmp_path / "mission", tmp_path / "run"
    mission.mkdir()
    env = script_env(
        FAKE_BATCH_DIR=str(batch),
        # A small job for this 2-core machine: one job of 2 single-threaded workers.
        **{f"DASK_JOBQUEUE__{system.upper()}__CORES": "2", f"DASK_JOBQUEUE__{system.upper()}__MEMORY": f"2{unit}",
           f"DASK_JOBQUEUE__{system.upper()}__LOCAL_DIRECTORY": str(tmp_path / "scratch")},
    )
    env["PATH"] = f"{bin_dir}{os.pathsep}{env['PATH']}"
    t0 = time.monotonic()
    res = subprocess.run(
        [str(CLUSTER / system / "launch.sh"), str(mission), str(run), "--jobs", "1", "--wait-workers", "2",
         "--timeout", "120", "--", "--quiet"],
        capture_output=True, text=True, timeout=300, env=env,
    )
    elapsed = time.monotonic() - t0
    assert res.returncode == 0, f"{res.stdout}\n{res.stderr}"
    out = json.loads((batch / "mercury-dem.json").read_text())
    assert out["argv"] == ["run", str(mission), "--out", str(run), "--scheduler-file",
                           f"{run}.dask/scheduler.json", "--quiet"]
    assert out["address"].startswith("tls://")
    assert out["total"] == 45
    assert out["resources"] == [{ADJUST_RESOURCE: 1}] * 2 and out["nthreads"] == [1, 1]
    # The job script that was submitted names the scheduler and the TLS files.
    (job,) = sorted(batch.glob("job-*.sh"))
    text = job.read_text()
    assert directive in text and "--tls-cert" in text and f"--resources {ADJUST_RESOURCE}=1" in text
    # Every job was cancelled and its processes are gone; the scheduler file was removed.
    jobids = [int(i) for i in (batch / "jobids").read_text().split()]
    assert sorted(int(i) for i in (batch / "cancelled").read_text().split()) == sorted(jobids)
    deadline = time.monotonic() + 15
    left = []
    while time.monotonic() < deadline:
        left = [p.pid for p in psutil.process_iter() if _pgid(p.pid) in jobids]
        if not left:
            break
        time.sleep(0.2)
    assert left == [], f"job processes still running: {left}"
    assert not (tmp_path / "run.dask" / "scheduler.json").exists()
    print(f"{system} launch.sh round trip: {elapsed:.1f} s")


def _pgid(pid: int) -> int:
    try:
        return os.getpgid(pid)
    except (ProcessLookupError, PermissionError):
        return -1


@pytest.mark.parametrize("system", ["slurm", "pbs"])
def test_launch_scripts_share_one_launcher(system: str, tmp_path: Path) -> None:
    """Each launch.sh only hands its system to cluster/common/launch_jobqueue.sh, which checks its batch command."""
    text = (CLUSTER / system / "launch.sh").read_text()
    (call,) = [ln for ln in text.splitlines() if ln.startswith("exec ")]
    assert call.endswith(f'/../common/launch_jobqueue.sh" {system} "$@"')
    submit = BATCH[system][0]
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "mercury-dem").symlink_to("/bin/true")
    # Only the tools the script needs: no sbatch/qsub on this PATH (make test installs a real SLURM).
    for tool in ("bash", "dirname", "sed", "cat"):
        (bin_dir / tool).symlink_to(shutil.which(tool))
    env = script_env()
    env["PATH"] = str(bin_dir)
    res = subprocess.run([str(CLUSTER / system / "launch.sh"), str(tmp_path), str(tmp_path / "run")],
                         capture_output=True, text=True, timeout=60, env=env)
    assert res.returncode == 1 and f"{submit} not found: is this a {system.upper()} login node?" in res.stderr
    res = subprocess.run([str(CLUSTER / "common" / "launch_jobqueue.sh"), "lsf", "m", "r"],
                         capture_output=True, text=True, timeout=60, env=env)
    assert res.returncode == 2 and "slurm or pbs" in res.stderr
