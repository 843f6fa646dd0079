"""tests/process_guard.py: a test that leaves a process running errors, and the process is killed.

Runs an inner pytest on a small test file (with this suite's hooks) in a subprocess; about 5 s.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import psutil

from tests.process_guard import run_in_own_group

REPO = Path(__file__).resolve().parents[1]

_CONFTEST = """
from tests.process_guard import pytest_configure, pytest_runtest_setup, pytest_runtest_teardown, pytest_sessionfinish
"""

_TESTS = '''
import os, subprocess, sys, pytest
from pathlib import Path
from tests.process_guard import env_for_session_process

OUT = Path(os.environ["GUARD_OUT"])
SLEEP = [sys.executable, "-c", "import time; time.sleep(120)"]

def test_leaks_a_child():
    p = subprocess.Popen(SLEEP)
    (OUT / "child").write_text(str(p.pid))

def test_leaks_a_daemon_outside_its_tree():
    # setsid + the parent exits at once: the sleeper is reparented, found by the environment's token
    subprocess.run(["setsid", "sh", "-c", f"{sys.executable} -c 'import time; time.sleep(120)' & echo $! > {OUT}/daemon"],
                   check=True)

def test_clean():
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    p = subprocess.Popen(SLEEP)
    p.kill(); p.wait()

@pytest.fixture(scope="session")
def forgotten():
    p = subprocess.Popen(SLEEP, env=env_for_session_process())
    (OUT / "session").write_text(str(p.pid))
    yield p   # never stopped: the session-end sweep must find it

def test_uses_a_session_process(forgotten):
    pass

def test_after_it(forgotten):
    pass
'''


def _gone(pid: int, seconds: float = 5) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            if psutil.Process(pid).status() == psutil.STATUS_ZOMBIE:
                return True
        except psutil.NoSuchProcess:
            return True
        time.sleep(0.1)
    return False


def test_a_leaked_process_errors_the_test_and_is_killed(tmp_path: Path) -> None:
    inner = tmp_path / "inner"
    inner.mkdir()
    (inner / "conftest.py").write_text(_CONFTEST)
    (inner / "test_leaky.py").write_text(_TESTS)
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "PYTHONPATH": str(REPO), "GUARD_OUT": str(out), "MERCURY_DEM_TEST_PROCESS_GRACE": "0.5"}
    res = run_in_own_group([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-o", "addopts=",
                            "-c", os.devnull, "--rootdir", str(inner), str(inner)],
                           timeout=120, env=env, cwd=inner)
    text = res.stdout + res.stderr
    assert res.returncode == 1, text
    assert "5 passed, 2 errors" in text, text
    assert "test_leaks_a_child left 1 process(es) running" in text, text
    assert "test_leaks_a_daemon_outside_its_tree left 1 process(es) running" in text, text
    assert "test_clean" not in text.split("short test summary")[-1], text
    assert "process guard: 1 process(es) started by this test session were still running at its end" in text, text
    for name in ("child", "daemon", "session"):
        pid = int((out / name).read_text())
        assert _gone(pid), f"the {name} process {pid} is still running"
