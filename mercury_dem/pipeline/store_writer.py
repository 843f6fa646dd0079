"""Write ``dem.zarr`` from a forked child process while this process starts numba and grids.

Why: a cold ``mercury-dem grid`` spends ~1 s single-threaded before its two-thread gridding
(Python, numpy, numba's import and registries, zarr's import), with the machine's other core
idle. Python imports hold the GIL, so a thread cannot overlap them; a second *process* can.
:class:`ForkedStoreWriter` forks at the command's start, after numpy (both need it) and before numba or zarr
are imported (no Python thread runs; OpenBLAS's pool, started with numpy, has its own fork handlers and the
child calls no BLAS; nothing is shared but the file system and two pipes). The child
imports zarr and the store layout code, creates the store when told its grid, writes each
chunk's layers as the parent sends them, then the final attributes and the completion mark.
The parent never imports zarr; its ``dem.zarr`` writes become sends on a pipe.

What the child writes is exactly what the in-process path writes: the same
:func:`~mercury_dem.pipeline.dem_stage.create_store`, the same region assignments into the
same zarr arrays, the same attribute updates (tests compare both stores file by file).

Protocol (one pipe each way): a message is a JSON header and a byte payload, each preceded
by its 8-byte length; no pickle (the package never unpickles, tests/cluster/test_security_defaults.py).
Parent to child: ``create`` (store path, the grid, the ``dem`` configuration, attributes and body as
plain dicts; the parent checks they rebuild equal objects, else it writes in-process),
``write`` (layer name, region, dtype, shape; payload: the C-order bytes), ``attrs`` and
``complete``. The child answers once: ``ok`` after the completion mark, or ``error`` with the
fault's text at the first fault (then exits). A child that reads end-of-file before
``complete`` (the parent failed or aborted) exits without marking the store complete; the
parent waits for it before the temporary store is removed (:meth:`ForkedStoreWriter.abort`),
so nothing half-written survives.

Only the ``grid`` command's in-process path uses it (``--workers 0``, on a platform with
``os.fork``; ``MERCURY_DEM_GRID_WRITER=inprocess`` turns it off). Why not :mod:`multiprocessing`: its
start methods re-import the package in a new interpreter (``spawn``) or fork from a helper
(``forkserver``), both slower than the imports they would overlap; its connections pickle.
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import sys
from typing import Any

from mercury_dem.exceptions import StoreError

#: Environment variable: ``inprocess`` keeps every write in this process (no fork).
ENV = "MERCURY_DEM_GRID_WRITER"

_LEN = struct.Struct("<Q")


#: Pipe capacity asked for (Linux; the default is 64 KiB): a chunk's layer (~1 MiB at 512 x 512 float32)
#: then goes into the pipe without waiting for the child to finish writing the previous one.
PIPE_BYTES = 1 << 20


def _widen(fd: int) -> None:
    """Ask for a :data:`PIPE_BYTES` pipe (best effort: elsewhere, or above the system's limit, it stays)."""
    with contextlib.suppress(ImportError, AttributeError, OSError):  # no fcntl, no F_SETPIPE_SZ, over the limit
        import fcntl

        fcntl.fcntl(fd, fcntl.F_SETPIPE_SZ, PIPE_BYTES)


def _write_all(fd: int, data: bytes | memoryview) -> None:
    view = memoryview(data).cast("B")
    while view:
        n = os.write(fd, view)
        view = view[n:]


def _read_exact(fd: int, n: int) -> bytes | None:
    """``n`` bytes from ``fd``, or None at end-of-file before them."""
    parts = []
    while n:
        b = os.read(fd, min(n, 1 << 22))
        if not b:
            return None
        parts.append(b)
        n -= len(b)
    return b"".join(parts)


def _send(fd: int, header: dict[str, Any], payload: bytes | memoryview = b"") -> None:
    head = json.dumps(header).encode()
    size = memoryview(payload).nbytes
    _write_all(fd, _LEN.pack(len(head)) + head + _LEN.pack(size))
    if size:
        _write_all(fd, payload)


def _recv(fd: int) -> tuple[dict[str, Any], bytes] | None:
    """The next (header, payload), or None at end-of-file."""
    n = _read_exact(fd, _LEN.size)
    head = None if n is None else _read_exact(fd, _LEN.unpack(n)[0])
    m = None if head is None else _read_exact(fd, _LEN.size)
    if head is None or m is None:
        return None
    size = _LEN.unpack(m)[0]
    payload = _read_exact(fd, size) if size else b""
    return None if payload is None else (json.loads(head), payload)


def _objects(d: dict[str, Any]) -> tuple[Any, Any, Any]:
    """(grid, dem configuration, body) from the plain dicts of a ``create`` message."""
    from mercury_dem.config.base import from_dict
    from mercury_dem.config.dem import DemConfig
    from mercury_dem.dem.grid import GridSpec
    from mercury_dem.geometry.body import Body

    return GridSpec(**d["grid"]), from_dict(DemConfig, d["cfg"], prefix="dem."), Body.from_dict(d["body"])


def _serve(rfd: int, wfd: int) -> int:
    """The child's loop; returns its exit status (0 once the store is marked complete)."""
    try:
        import numpy as np
        import zarr  # noqa: F401  (imported now, while the parent is still starting)

        from mercury_dem.pipeline import dem_stage

        group: Any = None
        layers: dict[str, Any] | None = None
        store: Any = None
        while True:
            msg = _recv(rfd)
            if msg is None:  # the parent failed or aborted: leave the store unmarked
                return 1
            head, payload = msg
            kind = head["kind"]
            if kind == "create":
                store = head["store"]
                grid, cfg, body = _objects(head)
                group, layers = dem_stage.create_store(store, grid, cfg, head["attrs"], body)
            elif kind in ("write", "attrs", "complete") and layers is None:
                raise ValueError(f"message {kind!r} before 'create'")
            elif kind == "write":
                assert layers is not None
                r0, r1, c0, c1 = head["region"]
                arr = np.frombuffer(payload, dtype=np.dtype(head["dtype"])).reshape(head["shape"])
                layers[head["name"]][r0:r1, c0:c1] = arr
            elif kind == "attrs":
                group.attrs.update(head["attrs"])
            elif kind == "complete":
                dem_stage.mark_zarr_complete(store)
                _send(wfd, {"kind": "ok"})
                return 0
            else:
                raise ValueError(f"unknown message {kind!r}")
    except BaseException as exc:  # noqa: BLE001 - reported to the parent, which raises it
        with contextlib.suppress(OSError):
            _send(wfd, {"kind": "error", "text": f"{type(exc).__name__}: {exc}"})
        return 1


class _Layer:
    """Stands for one zarr array of the store: ``layer[r0:r1, c0:c1] = arr`` sends the region."""

    def __init__(self, writer: ForkedStoreWriter, name: str) -> None:
        self._writer, self._name = writer, name

    def __setitem__(self, key: tuple[slice, slice], value: Any) -> None:
        import numpy as np

        rs, cs = key
        arr = np.ascontiguousarray(value)
        self._writer._send({"kind": "write", "name": self._name, "region": [rs.start, rs.stop, cs.start, cs.stop],
                            "dtype": arr.dtype.str, "shape": list(arr.shape)}, arr)


class ForkedStoreWriter:
    """The parent's end of the writer process (see the module docstring).

    Use :meth:`start` (None where it does not apply), then :meth:`create` once, region writes
    through the returned layers, :meth:`update_attrs`, and :meth:`complete` as the store's
    ``mark_complete``; :meth:`abort` on any failure before that. Writes may come from
    several threads (a lock keeps each message whole).
    """

    def __init__(self, pid: int, wfd: int, rfd: int) -> None:
        import threading

        self.pid, self._wfd, self._rfd = pid, wfd, rfd
        self._lock = threading.Lock()
        self._fail_lock = threading.Lock()
        self._store: str | None = None
        self._done = False
        self._error: str | None = None  # the child's fault, once known (every later call repeats it)

    @classmethod
    def start(cls) -> ForkedStoreWriter | None:
        """Fork the writer, or None (then write in this process) where it would not help or be safe.

        None: without ``os.fork``; with ``MERCURY_DEM_GRID_WRITER=inprocess``; when zarr is already
        imported (nothing left to overlap); when another thread runs (a fork copies only the
        calling thread: a lock held elsewhere could never be released in the child, e.g. when
        the command is called inside a test or a notebook). Call it before importing
        numba or zarr and before starting any thread (numpy may be imported: both processes use it).
        """
        import threading

        if (os.environ.get(ENV, "").strip().lower() == "inprocess" or not hasattr(os, "fork")
                or "zarr" in sys.modules or threading.active_count() > 1):
            return None
        to_child_r, to_child_w = os.pipe()
        to_parent_r, to_parent_w = os.pipe()
        _widen(to_child_w)
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the child: never returns into the caller's code
            status = 1
            try:
                os.close(to_child_w)
                os.close(to_parent_r)
                status = _serve(to_child_r, to_parent_w)
            finally:
                os._exit(status)
        os.close(to_child_r)
        os.close(to_parent_w)
        return cls(pid, to_child_w, to_parent_r)

    # -- the parent's side ------------------------------------------------------------------

    def create(self, store: str, grid: Any, cfg: Any, attrs: dict[str, Any] | None, body: Any,
               name: str | None = None) -> dict[str, _Layer] | None:
        """Have the child create the empty store (:func:`~mercury_dem.pipeline.dem_stage.create_store`).

        ``name``: the store as error messages call it (default ``store``; e.g. the final path
        of a store built under a temporary name).

        Returns stand-ins of its map layers for region writes, or None (the child stopped; the
        caller writes in-process) when the grid, configuration, attributes or body do not
        survive the trip as plain dicts unchanged.
        """
        import dataclasses

        from mercury_dem.config.base import to_dict
        from mercury_dem.dem.grid import LAYERS

        head = {"kind": "create", "store": store, "grid": dataclasses.asdict(grid), "cfg": to_dict(cfg),
                "attrs": attrs, "body": body.to_dict()}
        try:
            text = json.dumps(head)
            same = _objects(json.loads(text)) == (grid, cfg, body) and json.loads(json.dumps(attrs)) == attrs
        except (TypeError, ValueError):
            same = False
        if not same:
            self.abort()
            return None
        self._store = name or store
        self._send(head)
        return {name: _Layer(self, name) for name in LAYERS}

    def update_attrs(self, attrs: dict[str, Any]) -> None:
        self._send({"kind": "attrs", "attrs": attrs})

    def complete(self, tmp: Any = None) -> None:
        """Have the child mark the store complete; wait for it. Raises :class:`StoreError` on its fault."""
        self._send({"kind": "complete"})
        with self._fail_lock:
            reply = self._reply()
            self._finish()
            if reply is None or reply.get("kind") != "ok":
                self._record(reply)
        if self._error is not None:
            self._fail()

    def abort(self) -> None:
        """Stop the child without marking the store complete, and wait for it (idempotent)."""
        self._finish()

    def _send(self, header: dict[str, Any], payload: Any = b"") -> None:
        if self._done:
            self._fail()
        try:
            with self._lock:
                _send(self._wfd, header, payload)
        except OSError:  # the child stopped (its reason is on the reply pipe): the first thread to see it reads it
            with self._fail_lock:
                if not self._done:
                    self._record(self._reply())
                    self._finish()
            self._fail()

    def _reply(self) -> dict[str, Any] | None:
        try:
            msg = _recv(self._rfd)
        except (OSError, ValueError):
            return None
        return msg[0] if msg is not None and isinstance(msg[0], dict) else None

    def _finish(self) -> None:
        if self._done:
            return
        self._done = True
        for fd in (self._wfd, self._rfd):
            with contextlib.suppress(OSError):
                os.close(fd)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(self.pid, 0)

    def _where(self) -> str:
        return f"writing {self._store or 'dem.zarr'}"

    def _record(self, reply: dict[str, Any] | None) -> None:
        """Keep the child's reason for stopping (the first one seen)."""
        if self._error is None:
            self._error = (str(reply.get("text")) if reply and reply.get("kind") == "error"
                           else "the writer process stopped without a reason")

    def _fail(self) -> None:
        with self._fail_lock:  # wait for a thread still reading the child's reason
            why = self._error or "the writer process has already stopped"
        raise StoreError(f"{self._where()}: {why}; check the output directory (free space, permissions), "
                         f"or set {ENV}=inprocess to write from the gridding process")

    def __del__(self) -> None:  # a writer never completed nor aborted: do not leave the child waiting
        with contextlib.suppress(Exception):  # at interpreter shutdown anything may fail
            self._finish()
