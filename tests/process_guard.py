"""No test may leave a process running: a per-test check and a session-end sweep (hooks used by tests/conftest.py).

Which processes are the suite's: at configure time the pytest process puts a token in ``os.environ``
(:data:`TOKEN_VAR`), which every process it starts inherits -- also the ones that leave its process tree:
``start.sh``'s ``setsid`` schedulers and workers, SLURM's daemons, anything double-forked. A forked child
without ``exec`` keeps the environment of pytest's own start (``/proc/PID/environ`` is the memory of the
last ``exec``), so a descendant of this process counts too.

- **After each test's teardown** (its function-scoped fixtures have run their finalizers): a process of the
  suite that appeared during the test and is still running after a grace of :data:`GRACE_S` s is killed
  (with its process group when it leads one) and the test's teardown errors, naming it. Cost when nothing
  new appeared: one listing of ``/proc`` before and after the test (well under a millisecond).
- **At session end**, after every fixture's teardown (``pytest_sessionfinish``, last): every process of the
  suite still running is killed and reported, and the run's exit status becomes "tests failed".

Not counted: zombies (exited, not yet reaped), multiprocessing's resource tracker and fork server (one per
pytest process, they end with it), and during the session, processes a session- or module-scoped fixture
starts on purpose with ``SCOPE_VAR=session`` in their environment (``tests/s3_server.py``'s moto server);
those must be gone at session end like every other.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
import uuid
from dataclasses import dataclass

import pytest

#: Environment variable every process started by this pytest session inherits.
TOKEN_VAR = "MERCURY_DEM_TEST_SESSION"
#: ``SCOPE_VAR=session`` in a process's environment: started by a session/module fixture, checked at the end only.
SCOPE_VAR = "MERCURY_DEM_TEST_PROCESS_SCOPE"
#: Seconds a test's leftover processes get to exit by themselves (a closing nanny, a worker after its scheduler).
GRACE_S = float(os.environ.get("MERCURY_DEM_TEST_PROCESS_GRACE", "5"))
#: Command-line fragments of processes that live as long as the pytest process by design.
_LIFELONG = ("multiprocessing.resource_tracker", "multiprocessing.forkserver")

_PROC = "/proc"
_token: str | None = None
_saved_token: str | None = None
_before: dict[str, set[int]] = {}


def env_for_session_process(env: dict[str, str] | None = None) -> dict[str, str]:
    """The environment for a process a session-scoped fixture starts (and stops in its own teardown)."""
    return {**(os.environ if env is None else env), SCOPE_VAR: "session"}


def run_in_own_group(cmd: list[str], timeout: float, **kwargs: object) -> subprocess.CompletedProcess[str]:
    """``subprocess.run(cmd, capture_output=True, text=True)`` in a new session; on a timeout or any
    interruption the whole process group is killed (``subprocess.run`` kills only the direct child, so a
    script's helpers would live on), then the error is raised."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, **kwargs)  # type: ignore[call-overload]
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        with contextlib.suppress(OSError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


@dataclass
class _Proc:
    pid: int
    ppid: int
    pgid: int
    start: int  # clock ticks after boot: with the PID, the identity of a process (PIDs are reused)
    cmdline: str
    env: bytes

    def describe(self) -> str:
        return f"PID {self.pid} (ppid {self.ppid}, pgid {self.pgid}): {self.cmdline[:300]}"


def _pids() -> set[int]:
    try:
        return {int(name) for name in os.listdir(_PROC) if name.isdigit()}
    except OSError:  # no /proc (not Linux): the guard is off
        return set()


def _read(pid: int) -> _Proc | None:
    """The process ``pid``, or None when it is gone, a zombie or unreadable."""
    try:
        with open(f"{_PROC}/{pid}/stat", "rb") as f:
            stat = f.read()
        with open(f"{_PROC}/{pid}/cmdline", "rb") as f:
            cmdline = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
        with open(f"{_PROC}/{pid}/environ", "rb") as f:
            env = f.read()
    except OSError:
        return None
    # pid (comm) state ppid pgrp ...: comm may hold spaces and parentheses, so split after its last ")".
    fields = stat[stat.rfind(b")") + 2:].split()
    if not fields or fields[0] in (b"Z", b"X"):
        return None
    return _Proc(pid, int(fields[1]), int(fields[2]), int(fields[19]), cmdline, env)


def _ours(pids: set[int], *, include_session: bool) -> list[_Proc]:
    """The processes of ``pids`` that this session started: with the token, or descendants of this process."""
    if _token is None:
        return []
    me = os.getpid()
    mark = f"{TOKEN_VAR}={_token}".encode()
    session_mark = f"{SCOPE_VAR}=session".encode()
    parents: dict[int, int] = {}
    procs: dict[int, _Proc] = {}
    for pid in pids:
        if pid == me:
            continue
        p = _read(pid)
        if p is not None:
            procs[pid] = p
            parents[pid] = p.ppid

    def descends(pid: int) -> bool:
        seen = 0
        while pid > 1 and seen < 64:
            if pid == me:
                return True
            if pid not in parents:
                q = _read(pid)
                parents[pid] = q.ppid if q is not None else 0
            pid = parents[pid]
            seen += 1
        return False

    out = []
    for p in procs.values():
        env = p.env.split(b"\0")
        if not (mark in env or descends(p.ppid)):
            continue
        if any(name in p.cmdline for name in _LIFELONG):
            continue
        if not include_session and session_mark in env:
            continue
        out.append(p)
    return sorted(out, key=lambda p: p.pid)


def _still_running(procs: list[_Proc]) -> list[_Proc]:
    # (not the command line: a process read between its fork and its exec changes it)
    return [p for p in procs if (q := _read(p.pid)) is not None and q.start == p.start]


def _kill(procs: list[_Proc]) -> None:
    """SIGKILL each process, and its whole process group when it leads one (not pytest's own group)."""
    own_group = os.getpgrp()
    for p in procs:
        with contextlib.suppress(OSError):
            if p.pgid == p.pid and p.pgid != own_group:
                os.killpg(p.pgid, signal.SIGKILL)
            else:
                os.kill(p.pid, signal.SIGKILL)


def _leftovers(before: set[int], *, include_session: bool, grace: float) -> list[_Proc]:
    """Processes of this session among the PIDs not in ``before``, still running after ``grace`` s."""
    new = _pids() - before
    if not new:
        return []
    found = _ours(new, include_session=include_session)
    deadline = time.monotonic() + grace
    while found and time.monotonic() < deadline:
        time.sleep(0.1)
        found = _still_running(found)
    if not found:
        return []
    # Judge the survivors on a fresh read: one first read between its fork and its exec showed its parent's
    # environment (no session marker) and an empty command line, which made a session fixture's process,
    # started an instant before a fast test's teardown on a loaded machine, look like a leak (seen once in CI).
    start = {p.pid: p.start for p in found}
    again = _ours(set(start), include_session=include_session)
    return [p for p in again if start.get(p.pid) == p.start]


def pytest_configure(config: pytest.Config) -> None:
    global _token, _saved_token
    if not os.path.isdir(_PROC):
        return
    _saved_token = os.environ.get(TOKEN_VAR)
    _token = f"{os.getpid()}-{uuid.uuid4().hex[:12]}"
    os.environ[TOKEN_VAR] = _token


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item: pytest.Item) -> None:
    if _token is not None:
        _before[item.nodeid] = _pids()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_teardown(item: pytest.Item, nextitem: pytest.Item | None):  # noqa: ANN201 - a hook wrapper
    result = yield
    before = _before.pop(item.nodeid, None)
    if before is None:
        return result
    # After the last test, the session fixtures have been torn down here too: count their processes then.
    left = _leftovers(before, include_session=nextitem is None, grace=GRACE_S)
    if left:
        _kill(left)
        raise AssertionError(
            f"{item.nodeid} left {len(left)} process(es) running {GRACE_S:g} s after its teardown (now killed):\n  "
            + "\n  ".join(p.describe() for p in left)
            + "\nStop what a test starts in a fixture's finally/addfinalizer (see tests/process_guard.py).")
    return result


@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Every fixture has been torn down (the runner's sessionfinish ran first): nothing of ours may remain."""
    global _token
    if _token is None:
        return
    left = _ours(_pids(), include_session=True)
    deadline = time.monotonic() + GRACE_S
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = _still_running(left)
    if left:
        _kill(left)
        lines = [f"process guard: {len(left)} process(es) started by this test session were still running at "
                 "its end; killed them:", *(f"  {p.describe()}" for p in left)]
        reporter = session.config.pluginmanager.get_plugin("terminalreporter")
        for line in lines:
            if reporter is not None:
                reporter.write_line(line, red=True, bold=True)
            else:
                print(line)
        if session.exitstatus == pytest.ExitCode.OK:
            session.exitstatus = pytest.ExitCode.TESTS_FAILED
    if _saved_token is None:
        os.environ.pop(TOKEN_VAR, None)
    else:
        os.environ[TOKEN_VAR] = _saved_token
    _token = None
