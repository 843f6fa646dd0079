"""A real S3 API on 127.0.0.1 for the object-store tests: ``moto_server`` started in a subprocess.

The fixture ``s3_endpoint`` starts moto's server on a free port, points fsspec (in this
process, through ``fsspec.config.conf``; in child processes, through
``FSSPEC_S3_ENDPOINT_URL``) and the AWS credentials at it, gives the run caches a fresh
``MERCURY_DEM_CACHE``, and stops the server at the end. It skips, saying why, only
when moto's server or s3fs is not installed (``pip install 'moto[server]' s3fs``, as
``make test`` does).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.process_guard import env_for_session_process


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM the server's process group, SIGKILL after 10 s; reap it."""
    for sig, wait in ((signal.SIGTERM, 10), (signal.SIGKILL, 10)):
        with contextlib.suppress(OSError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(timeout=wait)
            break
        except subprocess.TimeoutExpired:
            continue
    with contextlib.suppress(OSError):
        os.killpg(proc.pid, signal.SIGKILL)  # anything the server itself started


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
        # its own process group, so the teardown ends anything it started; marked as a session fixture's
        # process for tests/process_guard.py (checked at the session's end, not after the test that started it)
        proc = subprocess.Popen([*cmd, "-H", "127.0.0.1", "-p", str(port)], stdout=fh, stderr=subprocess.STDOUT,
                                env=env_for_session_process(), start_new_session=True)
    endpoint = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while True:
        try:
            urllib.request.urlopen(endpoint + "/moto-api/", timeout=1).close()
            break
        except OSError:
            if proc.poll() is not None or time.monotonic() > deadline:
                _stop(proc)
                raise RuntimeError(f"moto_server did not start on {endpoint}: {log.read_text()[-2000:]}") from None
            time.sleep(0.2)
        except BaseException:  # interrupted (KeyboardInterrupt, a timeout): no server left behind
            _stop(proc)
            raise
    env = {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
           "FSSPEC_S3_ENDPOINT_URL": endpoint, "MERCURY_DEM_CACHE": str(tmp_path_factory.mktemp("cache"))}
    saved_env = {k: os.environ.get(k) for k in env}
    saved_conf = fsspec.config.conf.get("s3")
    os.environ.update(env)
    fsspec.config.conf["s3"] = {**(saved_conf or {}), "endpoint_url": endpoint}
    try:
        yield endpoint
    finally:
        _stop(proc)
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
