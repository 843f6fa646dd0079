"""The live dashboard inside a Jupyter notebook: an iframe onto a dashboard server in a thread.

``embed(run)`` starts the dashboard's Bokeh server (the same app as ``mercury-dem
dashboard``) on 127.0.0.1 and a free port, in a daemon thread of the kernel with its
own event loop, and returns a handle that displays as an ``<iframe>`` onto it.

Why a thread and an iframe rather than ``bokeh.io.show(app)``: ``show`` runs the app
on the kernel's own event loop, which is blocked while a cell runs, so the page would
freeze exactly while ``run_pipeline`` (a blocking call) is running: the moment one wants
to watch it. A server on its own loop keeps pushing updates while the kernel is busy.
An iframe is plain HTML, rendered the same by JupyterLab, Jupyter Notebook (classic or
7) and VS Code, with no notebook extension (``jupyter_bokeh``) and no comms; the page
inside is the dashboard's own, so its websocket origin is the server itself. The
browser must reach 127.0.0.1:PORT of the kernel's machine: true for a local Jupyter;
for a remote one, use an SSH tunnel or jupyter-server-proxy (``url="/proxy/{port}/"``
and ``origins=["jupyter.example.org"]``).

Stop the server with ``handle.stop()`` (also a context manager); a kernel restart
stops it too (the thread is a daemon).
"""

from __future__ import annotations

import asyncio
import html
import socket
import threading
from pathlib import Path
from typing import Any

from mercury_dem.dashboard.app import dashboard_app, free_port


def _check_free(host: str, port: int, run: Path) -> None:
    """Refuse a port in use with a clear error, before Bokeh/tornado tries it.

    (tornado's ``bind_sockets`` leaves its socket open when the bind fails, which is
    a ResourceWarning in the caller's process.)
    """
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as tornado binds
        try:
            s.bind((host, port))
        except OSError as exc:
            raise RuntimeError(f"the dashboard server for {run} failed to start on {host}:{port}: {exc.strerror}; "
                               "give another port (port=0 picks a free one)") from None


class EmbeddedDashboard:
    """A dashboard server running in a background thread, shown as an iframe in a notebook.

    Attributes
    ----------
    run : the run directory shown.
    host, port : where the server listens (127.0.0.1 and a free port by default).
    url : the address the iframe loads (``http://host:port/`` unless a proxy URL was given).
    """

    def __init__(self, run: str | Path, *, port: int = 0, host: str = "127.0.0.1", interval_ms: int = 1000,
                 dask_link: str | None = None, url: str | None = None, origins: list[str] | None = None,
                 width: int = 1200, height: int = 760, start_timeout_s: float = 30.0):
        self.run = Path(run)
        self.host = host
        self.port = port or free_port(host)
        _check_free(host, self.port, self.run)
        self.url = (url or "http://{host}:{port}/").format(host=host, port=self.port)
        self.width, self.height = width, height
        self._origins = [f"{host}:{self.port}", f"localhost:{self.port}", *(origins or [])]
        self._app = dashboard_app(self.run, interval_ms, dask_link)
        self._server: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._error: BaseException | None = None
        self._ready = threading.Event()
        self._thread = threading.Thread(target=self._main, name=f"mercury-dem-dashboard-{self.port}", daemon=True)
        self._thread.start()
        if not self._ready.wait(start_timeout_s):
            raise TimeoutError(f"the dashboard server for {self.run} did not start within {start_timeout_s} s")
        if self._error is not None:
            raise RuntimeError(f"the dashboard server for {self.run} failed to start on "
                               f"{host}:{self.port}: {self._error}") from self._error

    def _main(self) -> None:
        from bokeh.application import Application
        from bokeh.application.handlers.function import FunctionHandler
        from bokeh.server.server import Server
        from tornado.ioloop import IOLoop

        loop = asyncio.new_event_loop()
        asyncio.set_event_loop(loop)
        io_loop = IOLoop.current()  # tornado's wrapper of this thread's asyncio loop
        self._loop = loop
        try:
            self._server = Server({"/": Application(FunctionHandler(self._app))}, io_loop=io_loop,
                                  port=self.port, address=self.host, allow_websocket_origin=self._origins)
            self._server.start()
        except BaseException as exc:  # reported by __init__ in the caller's thread
            self._error = exc
            self._ready.set()
            io_loop.close(all_fds=True)
            return
        self._ready.set()
        try:
            loop.run_forever()
        finally:
            loop.run_until_complete(loop.shutdown_asyncgens())
            io_loop.close(all_fds=True)  # closes the asyncio loop too

    @property
    def running(self) -> bool:
        """True while the server thread is alive."""
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 10.0) -> None:
        """Stop the server and its thread (idempotent)."""
        loop = self._loop
        if loop is None or not self._thread.is_alive():
            return

        def _shutdown() -> None:
            try:
                self._server.stop()
            finally:
                loop.stop()

        loop.call_soon_threadsafe(_shutdown)
        self._thread.join(timeout_s)
        if self._thread.is_alive():
            raise TimeoutError(f"the dashboard server on {self.host}:{self.port} did not stop within {timeout_s} s")

    def __enter__(self) -> EmbeddedDashboard:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _repr_html_(self) -> str:
        if not self.running:
            return f"<p>mercury-dem dashboard of {html.escape(str(self.run))}: stopped</p>"
        u = html.escape(self.url, quote=True)
        return (f"<iframe class='mercury-dem-dashboard' src='{u}' width='{self.width}' height='{self.height}' "
                f"style='border:1px solid #ccc' title='mercury-dem dashboard'></iframe>"
                f"<div><a href='{u}' target='_blank'>open the dashboard of {html.escape(str(self.run))} "
                f"in its own tab</a></div>")

    def __repr__(self) -> str:
        state = "running" if self.running else "stopped"
        return f"mercury-dem dashboard of {self.run}: {self.url} ({state})"


def embed(run: str | Path, **kwargs: Any) -> EmbeddedDashboard:
    """Start the live dashboard of ``run`` for a notebook; display the result to show it.

    Parameters
    ----------
    run : run directory (it may not exist yet: the page waits for the plan).
    **kwargs : :class:`EmbeddedDashboard` options: ``port`` (0: a free one), ``host``
        (127.0.0.1), ``interval_ms`` (store polling, 1000), ``dask_link``, ``url``
        (iframe address, ``{host}``/``{port}`` filled in, e.g. ``"/proxy/{port}/"``),
        ``origins`` (extra websocket origins for a proxy), ``width``, ``height``.

    Returns
    -------
    EmbeddedDashboard
        Its HTML representation is the iframe; call ``.stop()`` when done.

    Examples
    --------
    >>> dash = embed("tiny_run")   # doctest: +SKIP
    >>> dash                       # the last expression of a cell: the live page  # doctest: +SKIP
    """
    return EmbeddedDashboard(run, **kwargs)


__all__ = ["EmbeddedDashboard", "embed"]
