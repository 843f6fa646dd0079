"""``measure``: wall, CPU and peak memory of one callable or command, run in a child process.

A callable runs in a forked child (so its peak memory is its own, and a crash or a leak stays there); its return
value comes back pickled. A command runs as a child process. Either way the parent reaps the child with
``os.wait4``, whose resource usage covers the child and every descendant it waited for: CPU is user + system of
all of them, the peak is the largest resident size among them. A forked child starts with its parent's pages
resident, so for a callable the peak is also read inside the child after resetting ``VmHWM`` at the call
(``start_rss_bytes`` is what it held when the call began; ``extra_rss_bytes`` the difference).

A command's peak has a floor: Linux carries the high-water mark of the process image a child replaced at
``exec`` (the fork of this process) into its ``ru_maxrss``, so a command spawned by a benchmark holding 500 MB
reports at least ~500 MB whatever it used (measured: ``true`` 30 MB from a bare interpreter, 510 MB from one
holding a 480 MB array). ``extra["parent_rss_bytes"]`` records this process's resident size at the spawn: a
command's peak near it says only "at most this"; measure a small command from a small process.

``interleave`` runs several such measurements alternately (A B A B ...), so that load on a shared machine falls
on ours and on the reference alike; a ratio is taken between medians of the same run.
"""

from __future__ import annotations

import os
import pickle
import signal
import statistics
import subprocess
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from harness.memory import peak_rss_bytes, reset_peak, rss_bytes


@dataclass
class Measurement:
    """One run: seconds of wall and of CPU (user + system, children included), peak resident bytes."""

    label: str
    wall_s: float
    cpu_s: float
    peak_rss_bytes: int
    start_rss_bytes: int = 0
    returncode: int = 0
    value: Any = None
    stdout: str = ""
    stderr: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def extra_rss_bytes(self) -> int:
        return max(self.peak_rss_bytes - self.start_rss_bytes, 0)

    def as_record(self) -> dict[str, Any]:
        """The figures of this run, JSON-able (no value, no output)."""
        return {"label": self.label, "wall_s": round(self.wall_s, 4), "cpu_s": round(self.cpu_s, 4),
                "peak_rss_bytes": self.peak_rss_bytes, "start_rss_bytes": self.start_rss_bytes,
                "returncode": self.returncode, **self.extra}


def _rusage_figures(ru: Any) -> tuple[float, int]:
    return float(ru.ru_utime + ru.ru_stime), int(ru.ru_maxrss) * 1024


def _run_command(cmd: Sequence[str], label: str, env: Mapping[str, str] | None, cwd: str | os.PathLike[str] | None,
                 check: bool, timeout: float | None, log: str | os.PathLike[str] | None) -> Measurement:
    with tempfile.TemporaryFile("w+") as out, tempfile.TemporaryFile("w+") as err, \
            open(log if log is not None else os.devnull, "w") as log_fh:
        parent_rss = rss_bytes()  # the floor of the command's ru_maxrss (module docstring)
        t0 = time.perf_counter()
        # a session of its own: on a timeout its whole process group (and nothing else) is stopped
        proc = subprocess.Popen(list(cmd), stdout=log_fh if log is not None else out,
                                stderr=subprocess.STDOUT if log is not None else err,
                                env=dict(env) if env is not None else None, cwd=cwd, text=True, start_new_session=True)
        timed_out = False
        while True:
            pid, status, ru = os.wait4(proc.pid, os.WNOHANG if timeout is not None else 0)
            if pid:
                break
            if timeout is not None and time.perf_counter() - t0 > timeout:
                timed_out = True
                os.killpg(proc.pid, signal.SIGKILL)
                _, status, ru = os.wait4(proc.pid, 0)
                break
            time.sleep(0.05)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: tell Popen, so it does not wait again
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read(), err.read()
    cpu, peak = _rusage_figures(ru)
    m = Measurement(label, wall, cpu, peak, returncode=proc.returncode, stdout=stdout, stderr=stderr,
                    extra={"parent_rss_bytes": parent_rss, **({"timed_out": True} if timed_out else {})})
    if check and (proc.returncode != 0 or timed_out):
        raise RuntimeError(f"{label}: {' '.join(cmd)} exited {proc.returncode}: {stderr[-2000:]}")
    return m


def _run_callable(fn: Callable[..., Any], args: tuple[Any, ...], kwargs: Mapping[str, Any], label: str) -> Measurement:
    read_fd, write_fd = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: run, send back (ok, value, wall, start rss, peak rss), leave without cleanup
        code = 0
        try:
            os.close(read_fd)
            reset_peak()
            start = rss_bytes()
            t0 = time.perf_counter()
            try:
                value, ok = fn(*args, **kwargs), True
            except BaseException:  # noqa: BLE001 - reported to the parent, which raises
                value, ok = traceback.format_exc(), False
            wall = time.perf_counter() - t0
            payload = pickle.dumps((ok, value, wall, start, peak_rss_bytes()))
            with os.fdopen(write_fd, "wb") as fh:
                fh.write(payload)
        except BaseException:  # noqa: BLE001
            code = 1
        finally:
            for stream in (sys.stdout, sys.stderr):  # os._exit skips the interpreter's flush of what it printed
                try:
                    stream.flush()
                except Exception:  # noqa: BLE001
                    pass
            os._exit(code)
    os.close(write_fd)
    with os.fdopen(read_fd, "rb") as fh:
        payload = fh.read()
    _, status, ru = os.wait4(pid, 0)
    cpu, peak_waited = _rusage_figures(ru)
    if not payload:
        raise RuntimeError(f"{label}: the child died without a result (exit status {os.waitstatus_to_exitcode(status)})")
    ok, value, wall, start, peak_in_call = pickle.loads(payload)
    if not ok:
        raise RuntimeError(f"{label}: {getattr(fn, '__name__', fn)} raised in the child:\n{value}")
    # the call's own peak where VmHWM could be reset; else the child's, which includes the inherited pages
    peak = peak_in_call if peak_in_call else peak_waited
    return Measurement(label, wall, cpu, peak, start_rss_bytes=start, value=value)


def measure(target: Callable[..., Any] | Sequence[str], *args: Any, label: str = "",
            env: Mapping[str, str] | None = None, cwd: str | os.PathLike[str] | None = None, check: bool = True,
            timeout: float | None = None, log: str | os.PathLike[str] | None = None, **kwargs: Any) -> Measurement:
    """Run ``target(*args, **kwargs)`` in a forked child, or the command ``target`` (a list of strings), once.

    ``env``, ``cwd``, ``check`` (raise when it exits non-zero or times out), ``timeout`` (seconds, then its
    process group is killed: ``extra["timed_out"]``) and ``log`` (a file for its stdout and stderr, instead of
    ``Measurement.stdout``/``stderr``) apply to commands; other keyword arguments go to the callable."""
    if callable(target):
        return _run_callable(target, args, kwargs, label or getattr(target, "__name__", "callable"))
    if isinstance(target, (str, bytes)):
        raise TypeError("a command is a list of strings, not one string")
    return _run_command(list(target), label or os.path.basename(str(target[0])), env, cwd, check, timeout, log)


def measure_here(fn: Callable[..., Any], *args: Any, label: str = "", **kwargs: Any) -> Measurement:
    """Run ``fn(*args, **kwargs)`` once in this process (warm: its caches, loaded kernels and threads), for the
    benchmarks that time a warm in-process call: wall (``perf_counter``), CPU of this process (``process_time``,
    all its threads) and this process's peak resident size so far (not reset: an upper bound); the return value in
    ``value``."""
    c0, t0 = time.process_time(), time.perf_counter()
    value = fn(*args, **kwargs)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return Measurement(label or getattr(fn, "__name__", "callable"), wall, cpu, peak_rss_bytes(), value=value)


def interleave(runs: Mapping[str, Callable[[], Measurement]], repeats: int) -> dict[str, list[Measurement]]:
    """Call each of ``runs`` (label -> a function returning a :class:`Measurement`) in turn, ``repeats`` rounds:
    A B A B ... The lists keep the order of the rounds."""
    out: dict[str, list[Measurement]] = {k: [] for k in runs}
    for _ in range(repeats):
        for label, run in runs.items():
            out[label].append(run())
    return out


def median(ms: Sequence[Measurement], figure: str = "wall_s") -> float:
    return float(statistics.median(float(getattr(m, figure)) for m in ms))


def ratio_of_medians(reference: Sequence[Measurement], ours: Sequence[Measurement], figure: str = "wall_s") -> float:
    """median(reference) / median(ours): above 1 when ours is faster (or smaller)."""
    return median(reference, figure) / median(ours, figure)
