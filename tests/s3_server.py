"""A real S3 API on 127.0.0.1 for the object-store tests: ``moto_server`` started in a subprocess.

The fixture ``s3_endpoint`` starts moto's server on a free port, points fsspec (in this
process, through ``fsspec.config.conf``; in child processes, through
``FSSPEC_S3_ENDPOINT_URL``) and the AWS credentials at it, gives the run caches a fresh
``MERCURY_DEM_CACHE``, and stops the server at the end. It skips, saying why, only
when moto's server or s3fs is not installed (``pip install 'moto[server]' s3fs``, as
``make test`` does).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="session")
def s3_endpoint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """The endpoint URL of a moto S3 server on 127.0.0.1 (session-wide)."""
    pytest.importorskip("s3fs", reason="s3fs is not installed: pip install s3fs (make test installs it)")
    pytest.importorskip("moto.server", reason="moto's server is not installed: pip install 'moto[server]'")
    import fsspec.config

    exe = Path(sys.executable).parent / "moto_server"
    cmd = [str(exe)] if exe.exists() else [shutil.which("moto_server") or "moto_server"]
    port = _free_port()
    log = tmp_path_factory.mktemp("moto") / "moto.log"
    with open(log, "wb") as fh:
        proc = subprocess.Popen([*cmd, "-H", "127.0.0.1", "-p", str(port)], stdout=fh, stderr=subprocess.STDOUT)
    endpoint = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while True:
        try:
            urllib.request.urlopen(endpoint + "/moto-api/", timeout=1).close()
            break
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                proc.kill()
                raise RuntimeError(f"moto_server did not start on {endpoint}: {log.read_text()[-2000:]}") from None
            time.sleep(0.2)
    env = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
           "FSSPEC_S3_ENDPOINT_URL": endpoint, "MERCURY_DEM_CACHE": str(tmp_path_factory.mktemp("cache"))}
    saved_env = {k: os.environ.get(k) for k in env}
    saved_conf = fsspec.config.conf.get("s3")
    os.environ.update(env)
    fsspec.config.conf["s3"] = {**(saved_conf or {}), "endpoint_url": endpoint}
    try:
        yield endpoint
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        for k, v in saved_env.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        if saved_conf is None:
            fsspec.config.conf.pop("s3", None)
        else:
            fsspec.config.conf["s3"] = saved_conf


def make_bucket(name: str) -> None:
    """Create a bucket on the fixture's server (no error when it exists)."""
    import fsspec

    fs = fsspec.filesystem("s3", use_listings_cache=False)
    if not fs.exists(name):
        fs.mkdir(name)
