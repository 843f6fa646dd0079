"""The Kubernetes deployment with the run store in a bucket (cluster/kubernetes/bucket/): no shared volume.

Checked statically, as tests/cluster/test_kubernetes.py checks the volume-based manifests.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

BUCKET = Path(__file__).resolve().parents[2] / "cluster" / "kubernetes" / "bucket"


def _docs(name: str) -> list[dict[str, Any]]:
    return [d for d in yaml.safe_load_all((BUCKET / name).read_text()) if d]


def _pods(job: dict[str, Any]) -> dict[str, dict[str, Any]]:
    spec = job["spec"]
    return {"runner": spec["job"]["spec"], "worker": spec["cluster"]["spec"]["worker"]["spec"],
            "scheduler": spec["cluster"]["spec"]["scheduler"]["spec"]}


def test_the_bucket_daskjob_needs_no_shared_volume_and_runs_on_urls() -> None:
    pytest.importorskip("s3fs", reason="s3fs is not installed: pip install s3fs (make test installs it)")
    from mercury_dem.cli import build_parser
    from mercury_dem.io.location import is_remote, resolve_location

    text = (BUCKET / "daskjob.yaml").read_text()
    assert "persistentVolumeClaim:" not in text and "PersistentVolumeClaim" not in text
    (job,) = [d for d in _docs("daskjob.yaml") if d["kind"] == "DaskJob"]
    (runner,) = _pods(job)["runner"]["containers"]
    args = [a.replace("$(DASK_SCHEDULER_ADDRESS)", "tcp://mercury-dem-bucket-scheduler:8786") for a in runner["args"]]
    ns = build_parser().parse_args(args)
    assert ns.command == "run" and is_remote(ns.mission) and is_remote(ns.out)
    assert isinstance(resolve_location(ns.out), str) and isinstance(resolve_location(ns.mission), str)


def test_every_pod_that_opens_the_store_has_credentials_and_a_writable_cache() -> None:
    (job,) = [d for d in _docs("daskjob.yaml") if d["kind"] == "DaskJob"]
    (secret,) = _docs("credentials.yaml")
    assert secret["kind"] == "Secret"
    assert {"AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "FSSPEC_S3_ENDPOINT_URL"} <= set(secret["stringData"])
    for role in ("runner", "worker"):
        pod = _pods(job)[role]
        (c,) = pod["containers"]
        assert {"secretRef": {"name": secret["metadata"]["name"]}} in c["envFrom"], role
        cache = {e["name"]: e.get("value") for e in c["env"]}["MERCURY_DEM_CACHE"]
        # the root file system is read-only: the cache must sit on a mounted emptyDir
        assert c["securityContext"]["readOnlyRootFilesystem"] is True
        mounts = {m["mountPath"]: m["name"] for m in c["volumeMounts"]}
        (mount,) = [p for p in mounts if cache.startswith(p.rstrip("/") + "/")]
        vols = {v["name"]: v for v in pod["volumes"]}
        assert "emptyDir" in vols[mounts[mount]], role
    # the image and its user as in the volume-based DaskJob
    (main_job,) = [d for d in yaml.safe_load_all((BUCKET.parent / "daskjob.yaml").read_text()) if d and d["kind"] == "DaskJob"]
    for role, pod in _pods(job).items():
        (c,) = pod["containers"]
        (m,) = _pods(main_job)[role]["containers"]
        assert c["image"] == m["image"] and c["command"] == m["command"], role
        assert pod["securityContext"]["runAsNonRoot"] is True
