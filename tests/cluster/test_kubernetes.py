"""cluster/kubernetes: the manifests parse, name the image the Dockerfile builds and its entry point,
and pass arguments the real CLIs (mercury-dem run, dask scheduler/worker) accept.

No Docker daemon or Kubernetes cluster is needed (nor used): the image is not built here.
"""

from __future__ import annotations

import json
import re
import shutil
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

from tests.cluster.conftest import CLUSTER, REPO

K8S = CLUSTER / "kubernetes"
MANIFESTS = sorted(K8S.glob("*.yaml"))


def _dockerfile() -> dict[str, object]:
    text = (K8S / "Dockerfile").read_text()
    lines = [ln for ln in re.sub(r"\\\n\s*", " ", text).splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    out: dict[str, object] = {"COPY": [], "LABEL": {}}
    for ln in lines:
        instr, _, rest = ln.strip().partition(" ")
        if instr == "COPY":
            out["COPY"].append(rest.split()[:-1])  # type: ignore[union-attr]
        elif instr == "LABEL":
            out["LABEL"].update(dict(re.findall(r'(\S+?)="([^"]*)"', rest)))  # type: ignore[union-attr]
        else:
            out[instr] = rest.strip()
    return out


def _docs() -> list[tuple[str, dict]]:
    docs = []
    for path in MANIFESTS:
        for doc in yaml.safe_load_all(path.read_text()):
            if doc is not None:
                docs.append((path.name, doc))
    return docs


def _containers(node: object, where: str = "") -> list[tuple[str, dict]]:
    """Every container spec anywhere in a manifest, with its path."""
    found: list[tuple[str, dict]] = []
    if isinstance(node, dict):
        for k, v in node.items():
            if k == "containers" and isinstance(v, list):
                found += [(f"{where}/{c['name']}", c) for c in v]
            else:
                found += _containers(v, f"{where}/{k}")
    elif isinstance(node, list):
        for v in node:
            found += _containers(v, where)
    return found


def _image_name() -> str:
    m = re.search(r'IMAGE="\$\{1:-([^}]+)\}"', (K8S / "build-image.sh").read_text())
    assert m, "build-image.sh must define IMAGE=\"${1:-NAME:TAG}\""
    return m.group(1)


def _version() -> str:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["version"]


def test_manifests_parse_with_safe_load() -> None:
    docs = _docs()
    kinds = {(name, d["kind"]) for name, d in docs}
    assert ("daskcluster.yaml", "DaskCluster") in kinds
    assert ("daskjob.yaml", "DaskJob") in kinds
    for name, d in docs:
        assert {"apiVersion", "kind", "metadata"} <= set(d), name
        assert re.fullmatch(r"[a-z0-9]([-a-z0-9]*[a-z0-9])?", d["metadata"]["name"]), name


def test_dockerfile_installs_the_project_as_a_non_root_user() -> None:
    df = _dockerfile()
    assert str(df["FROM"]).startswith("python:3.11")  # the Python the project is tested on
    assert json.loads(str(df["ENTRYPOINT"])) == ["mercury-dem"]
    user = str(df["USER"]).split(":")[0]
    assert user not in ("0", "root") and int(user) > 0
    assert "pip install ." in str(df["RUN"]) or any("pip install ." in str(v) for v in df.values())
    assert df["LABEL"]["org.opencontainers.image.version"] == _version()  # type: ignore[index]
    # What the build copies exists, and is what pip needs (the readme pyproject names, the package).
    copied = {src for srcs in df["COPY"] for src in srcs}  # type: ignore[union-attr]
    for src in copied:
        assert (REPO / src).exists(), src
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    assert {"pyproject.toml", project["readme"], "mercury_dem"} <= copied
    assert project["scripts"]["mercury-dem"] == "mercury_dem.cli:main"
    # The build context filter lets exactly those through.
    ignore = (K8S / "Dockerfile.dockerignore").read_text().split()
    assert "*" in ignore and {"!pyproject.toml", f"!{project['readme']}", "!mercury_dem/"} <= set(ignore)


def test_dockerfile_order_installs_as_root_then_runs_as_the_created_user() -> None:
    """Static checks of the build order (the image is never built here: no Docker engine on this machine)."""
    text = re.sub(r"\\\n\s*", " ", (K8S / "Dockerfile").read_text())
    steps = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    instr = [ln.split()[0] for ln in steps]
    assert instr[0] == "FROM" and instr.count("FROM") == 1
    users = [i for i, k in enumerate(instr) if k == "USER"]
    assert len(users) == 1, "one USER switch, to the unprivileged user, and none back"
    install = [i for i, ln in enumerate(steps) if ln.startswith("RUN") and "pip install ." in ln]
    copies = [i for i, k in enumerate(instr) if k == "COPY"]
    assert install and copies and max(copies) < install[0] < users[0], "copy, install (as root), then USER"
    assert instr.index("ENTRYPOINT") > users[0]
    uid, _, gid = steps[users[0]].split()[1].partition(":")
    created = next(ln for ln in steps if "useradd" in ln)
    assert f"--uid {uid}" in created and (not gid or f"--gid {gid}" in created)
    # the install step checks the entry point answers, so a broken console script fails the build
    assert "mercury-dem --help" in steps[install[0]]


def test_every_container_runs_the_dockerfile_image_and_entry_point() -> None:
    image = _image_name()
    assert image.endswith(f":{_version()}")
    entry = json.loads(str(_dockerfile()["ENTRYPOINT"]))
    roles = set()
    for name, doc in _docs():
        for where, c in _containers(doc):
            assert c["image"] == image, f"{name}{where}"
            cmd = c["command"]
            assert cmd in (entry, ["dask"]), f"{name}{where}: {cmd}"
            roles.add(c["args"][0])
    assert {"scheduler", "worker", "run"} <= roles
    # 'dask' comes with the project's own dependencies (distributed's console script).
    assert shutil.which("dask", path=str(Path(sys.executable).parent)), "dask console script missing"


def _job_and_cluster() -> tuple[dict, dict]:
    (job,) = [d for n, d in _docs() if d["kind"] == "DaskJob"]
    return job, job["spec"]["cluster"]["spec"]


def test_daskjob_runs_mercury_dem_run_with_arguments_the_cli_accepts() -> None:
    from mercury_dem.cli import build_parser

    job, _ = _job_and_cluster()
    (runner,) = job["spec"]["job"]["spec"]["containers"]
    args = [a.replace("$(DASK_SCHEDULER_ADDRESS)", "tcp://mercury-dem-large-scheduler:8786") for a in runner["args"]]
    ns = build_parser().parse_args(args)
    assert ns.command == "run" and ns.scheduler.startswith("tcp://") and ns.out.startswith("/data/")
    assert "$(DASK_SCHEDULER_ADDRESS)" in runner["args"]  # injected by the operator, expanded by Kubernetes
    mounts = {m["mountPath"] for m in runner["volumeMounts"]}
    assert ns.mission.startswith("/data/") and "/data" in mounts


def test_daskjob_runner_keeps_adjustments_one_per_worker() -> None:
    """The runner may start before any worker joins, so its configuration turns the adjust resource on."""
    from mercury_dem.cli import build_parser
    from mercury_dem.config import load_config

    job, _ = _job_and_cluster()
    (runner,) = job["spec"]["job"]["spec"]["containers"]
    ns = build_parser().parse_args([a.replace("$(DASK_SCHEDULER_ADDRESS)", "tcp://x:8786") for a in runner["args"]])
    config_path = Path(ns.config)
    (mount,) = [m for m in runner["volumeMounts"] if Path(m["mountPath"]) == config_path.parent]
    (volume,) = [v for v in job["spec"]["job"]["spec"]["volumes"] if v["name"] == mount["name"]]
    (cm,) = [d for n, d in _docs() if d["kind"] == "ConfigMap" and d["metadata"]["name"] == volume["configMap"]["name"]]
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        f = Path(tmp) / config_path.name
        f.write_text(cm["data"][config_path.name])
        assert load_config(f).execution.adjust_resource == "on"


@pytest.mark.parametrize("kind", ["DaskCluster", "DaskJob"])
def test_workers_and_scheduler_arguments_parse_with_dask_cli(kind: str) -> None:
    from distributed.cli.dask_scheduler import main as scheduler_cli
    from distributed.cli.dask_worker import main as worker_cli

    from mercury_dem.compute import ADJUST_RESOURCE

    (doc,) = [d for n, d in _docs() if d["kind"] == kind]
    spec = doc["spec"] if kind == "DaskCluster" else doc["spec"]["cluster"]["spec"]
    (worker,) = spec["worker"]["spec"]["containers"]
    (sched,) = spec["scheduler"]["spec"]["containers"]
    wctx = worker_cli.make_context("worker", list(worker["args"][1:]))
    sctx = scheduler_cli.make_context("scheduler", list(sched["args"][1:]))
    # One adjustment at a time per worker; threads = the cores the pod is given.
    assert wctx.params["resources"] == f"{ADJUST_RESOURCE}=1"
    assert wctx.params["nthreads"] == int(worker["resources"]["limits"]["cpu"])
    # Dask's memory limit sits below the pod's, so Dask spills/pauses before the OOM killer acts.
    dask_limit = _bytes(wctx.params["memory_limit"])
    pod_limit = _bytes(worker["resources"]["limits"]["memory"])
    assert 0.85 * pod_limit <= dask_limit < pod_limit
    assert worker["resources"]["requests"]["memory"] == worker["resources"]["limits"]["memory"]
    # Worker dashboards stay on the pod's loopback; the scheduler's is reached by port-forward only.
    assert wctx.params["dashboard_address"].startswith("127.0.0.1:")
    assert spec["scheduler"]["service"]["type"] == "ClusterIP"
    assert int(sctx.params["port"]) == 8786
    # Same worker size as the HPC configurations (one worker = cores/processes, memory/processes).
    slurm = yaml.safe_load((REPO / "mercury_dem" / "cluster" / "slurm.yaml").read_text())["jobqueue"]["slurm"]
    assert wctx.params["nthreads"] == slurm["cores"] // slurm["processes"]
    assert pod_limit == _bytes(slurm["memory"]) // slurm["processes"]


def test_pods_run_unprivileged_as_the_image_user() -> None:
    uid = int(str(_dockerfile()["USER"]).split(":")[0])
    for name, doc in _docs():
        for where, pod in _pod_specs(doc):
            sc = pod["securityContext"]
            assert sc["runAsNonRoot"] is True and sc["runAsUser"] == uid, f"{name}{where}"
            for c in pod["containers"]:
                csc = c["securityContext"]
                assert csc["allowPrivilegeEscalation"] is False and csc["capabilities"]["drop"] == ["ALL"]
                if csc.get("readOnlyRootFilesystem"):
                    assert "/tmp" in {m["mountPath"] for m in c["volumeMounts"]}, f"{name}{where}: /tmp not writable"


def test_network_policies_select_their_own_cluster() -> None:
    docs = _docs()
    for name, doc in docs:
        if doc["kind"] not in ("DaskCluster", "DaskJob"):
            continue
        cluster = doc["metadata"]["name"]  # a DaskJob's cluster is named after the job
        (policy,) = [d for n, d in docs if n == name and d["kind"] == "NetworkPolicy"]
        assert policy["spec"]["podSelector"]["matchLabels"] == {"dask.org/cluster-name": cluster}
        peers = policy["spec"]["ingress"][0]["from"][0]["podSelector"]["matchLabels"]
        assert peers == {"dask.org/cluster-name": cluster}
        spec = doc["spec"] if doc["kind"] == "DaskCluster" else doc["spec"]["cluster"]["spec"]
        assert spec["scheduler"]["service"]["selector"]["dask.org/cluster-name"] == cluster


def _pod_specs(node: object, where: str = "") -> list[tuple[str, dict]]:
    found: list[tuple[str, dict]] = []
    if isinstance(node, dict):
        if "containers" in node:
            found.append((where, node))
        for k, v in node.items():
            if k != "containers":
                found += _pod_specs(v, f"{where}/{k}")
    elif isinstance(node, list):
        for v in node:
            found += _pod_specs(v, where)
    return found


def _bytes(text: str) -> int:
    from dask.utils import parse_bytes

    # Kubernetes writes binary units without the B ("32Gi"); Dask wants "32GiB".
    return int(parse_bytes(text + "B" if text.endswith("i") else text))


def test_synth_job_arguments_parse_when_the_synth_command_exists() -> None:
    from mercury_dem.cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._subparsers._group_actions if a.dest == "command")  # type: ignore[union-attr]
    if "synth" not in sub.choices:
        pytest.skip("mercury-dem synth is not there yet (the synth helper's command lands it)")
    (job,) = [d for n, d in _docs() if n == "synth-job.yaml"]
    (c,) = job["spec"]["template"]["spec"]["containers"]
    ns = parser.parse_args(c["args"])
    assert ns.command == "synth"
