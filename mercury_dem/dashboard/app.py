"""The live run dashboard: a Bokeh server app that polls a run store.

``dashboard_app(run)`` returns the function that builds a page for a Bokeh
Document; :func:`serve` serves it on 127.0.0.1 (``mercury-dem dashboard RUN``),
and in Jupyter :func:`mercury_dem.dashboard.embed` shows it in an iframe onto a
server in a thread of the kernel (it keeps updating while a cell runs the pipeline).

The page reads only the store (see :mod:`mercury_dem.viz.status` for how states are
inferred), so it works for a run in progress, a finished run, or a run written by
a cluster to a shared file system. Bokeh was chosen over Panel because it is
already a dependency (Dask's own dashboard uses it) and the app needs nothing more.
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from pathlib import Path
from typing import Any

from mercury_dem.dashboard.data import dashboard_data
from mercury_dem.io.run_store import RunStore
from mercury_dem.plan.tree import LEVELS
from mercury_dem.viz.status import STATE_COLOURS, STATES


def _legend_below(fig: Any, font_size: str) -> None:
    """Move the figure's legend below the plot area, so it never hides data (e.g. a tile near a pole)."""
    legend = fig.legend[0]
    fig.center.remove(legend)
    legend.orientation = "horizontal"
    legend.location = "center"
    legend.label_text_font_size = font_size
    fig.add_layout(legend, "below")


def _figures(data: dict[str, Any]) -> tuple[Any, dict[str, Any]]:
    from bokeh.layouts import column, row
    from bokeh.models import ColumnDataSource, Div, FactorRange, HoverTool
    from bokeh.plotting import figure

    tiles = ColumnDataSource(data["tiles"], name="tiles")
    prog = ColumnDataSource(data["progress"], name="progress")
    sig = ColumnDataSource(data["sigma0"], name="sigma0")

    fmap = figure(title="tiles (colour: state; hover for the reason)", width=720, height=380,
                  x_axis_label="east longitude (deg)", y_axis_label="latitude (deg)", match_aspect=True,
                  tools="pan,wheel_zoom,box_zoom,reset,save", name="tile_map")
    fmap.quad(left="left", right="right", bottom="bottom", top="top", source=tiles, fill_color="colour",
              line_color="black", fill_alpha=0.9, name="tile_quads", legend_field="state")
    fmap.text(x="left", y="bottom", text="tile", source=tiles, x_offset=2, y_offset=-2, text_font_size="8pt")
    fmap.add_tools(HoverTool(renderers=[fmap.renderers[0]], tooltips=[
        ("tile", "@tile"), ("state", "@state"), ("images", "@images"), ("points", "@points"),
        ("seconds", "@seconds"), ("reason", "@error")]))
    _legend_below(fmap, "9pt")

    fprog = figure(title="progress per level (units)", y_range=FactorRange(*reversed(LEVELS)), width=420,
                   height=250, tools="", toolbar_location=None, name="progress_bars")
    fprog.hbar_stack(["done", "failed", "running", "pending"], y="level", height=0.7, source=prog,
                     color=[STATE_COLOURS[s] for s in ("done", "failed", "running", "pending")],
                     legend_label=["done", "failed", "running", "pending"])
    _legend_below(fprog, "8pt")

    fsig = figure(title="adjustment convergence (σ0 per iteration)", width=420, height=260, y_axis_type="log",
                  x_axis_label="iteration", y_axis_label="σ0", tools="pan,wheel_zoom,reset", name="sigma0_plot")
    fsig.multi_line(xs="xs", ys="ys", line_color="colour", source=sig, line_width=2)
    fsig.add_tools(HoverTool(tooltips=[("unit", "@name")]))

    info = Div(text=data["info"], width=720, name="info")
    tiles_div = Div(text=data["tiles_html"], width=720, name="tile_states")
    layout = column(info, row(fmap, column(fprog, fsig)), tiles_div, name="dashboard")
    return layout, {"tiles": tiles, "progress": prog, "sigma0": sig, "info": info, "tiles_html": tiles_div}


def dashboard_app(run: str | Path, interval_ms: int = 1000, dask_link: str | None = None) -> Callable[[Any], None]:
    """A Bokeh app function ``doc -> None`` showing ``run`` and refreshing every ``interval_ms``.

    Parameters
    ----------
    run : run directory (it may not exist yet: the page waits for the plan).
    interval_ms : polling period of the store, milliseconds.
    dask_link : the Dask dashboard URL, when run.json/report.json do not record one.
    """
    store = RunStore(run)

    def build(doc: Any) -> None:
        data = dashboard_data(store, dask_link)
        layout, models = _figures(data)
        last = dict(data)

        def update() -> None:
            new = dashboard_data(store, dask_link)
            for key in ("tiles", "progress", "sigma0"):
                if new[key] != last[key]:
                    models[key].data = new[key]
            for key in ("info", "tiles_html"):
                if new[key] != last[key]:
                    models[key].text = new[key]
            last.update(new)

        doc.add_root(layout)
        doc.title = f"mercury-dem: {store.root.name}"
        doc.add_periodic_callback(update, interval_ms)

    return build


def free_port(host: str = "127.0.0.1") -> int:
    """A port free on ``host`` right now (the OS picks it)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def serve(run: str | Path, port: int = 5006, host: str = "127.0.0.1", interval_ms: int = 1000,
          dask_link: str | None = None) -> Any:
    """Start (not run) a Bokeh server for the dashboard; returns the ``bokeh.server.server.Server``.

    Binds ``host`` (127.0.0.1 by default: only this machine; use an SSH tunnel to
    look from elsewhere). ``port=0`` picks a free port (``server.port``). Run it with
    ``server.io_loop.start()``; stop with ``server.stop()``.
    """
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    port = port or free_port(host)
    origins = [f"{host}:{port}"] + ([f"localhost:{port}"] if host in ("127.0.0.1", "localhost") else [])
    server = Server({"/": Application(FunctionHandler(dashboard_app(run, interval_ms, dask_link)))},
                    port=port, address=host, allow_websocket_origin=origins)
    server.start()
    return server


__all__ = ["STATES", "dashboard_app", "free_port", "serve"]
