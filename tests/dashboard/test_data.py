"""The dashboard's data and server, without a browser."""

from __future__ import annotations

import json
import threading
import urllib.request
from pathlib import Path

import pytest

from mercury_dem.dashboard import dashboard_app, dashboard_data, serve
from mercury_dem.viz import STATE_COLOURS, tile_status


def test_data_of_a_finished_run(tiny_run: Path) -> None:
    d = dashboard_data(tiny_run)
    tiles = tile_status(tiny_run)
    assert d["tiles"]["tile"] == tiles["tile"].tolist()
    assert d["tiles"]["colour"] == [STATE_COLOURS[s] for s in tiles["state"]]
    widths = [r - left for left, r in zip(d["tiles"]["left"], d["tiles"]["right"])]
    assert all(w == pytest.approx(10.0) for w in widths)
    assert all(-180 <= x < 180 for x in d["tiles"]["left"])
    report = json.loads((tiny_run / "report.json").read_text())
    failed = dict(zip(d["tiles"]["tile"], d["tiles"]["error"]))
    for f in report["tiles"]["failed"]:
        assert failed[f["tile"]] == f["error"]
        assert f"data-tile='{f['tile']}' data-state='failed'" in d["tiles_html"]
    assert d["status"] == "finished" and "data-status='finished'" in d["info"]
    assert d["progress"]["done"][0] == report["tiles"]["succeeded"]
    assert len(d["sigma0"]["xs"]) == len(report["levels"]["region"]) + len(report["levels"]["hemisphere"]) + 1 - sum(
        1 for r in report["levels"]["region"] + report["levels"]["hemisphere"] if not r["ok"])
    d2 = dashboard_data(tiny_run, dask_link="http://127.0.0.1:8787/status")
    assert "href='http://127.0.0.1:8787/status'" in d2["info"]


def test_data_before_the_run_exists(tmp_path: Path) -> None:
    d = dashboard_data(tmp_path / "not-yet")
    assert d["tiles"]["tile"] == [] and d["status"] == "waiting for the plan"
    from bokeh.document import Document

    doc = Document()
    dashboard_app(tmp_path / "not-yet")(doc)  # builds a page that will wait
    assert doc.get_model_by_name("tiles") is not None


def test_server_binds_localhost_and_serves_the_page(tiny_run: Path) -> None:
    server = serve(tiny_run, port=0)
    try:
        assert server.address == "127.0.0.1"
        html = None

        def fetch() -> None:
            nonlocal html
            with urllib.request.urlopen(f"http://127.0.0.1:{server.port}/", timeout=20) as r:
                html = r.read().decode()
            server.io_loop.add_callback(server.io_loop.stop)

        th = threading.Thread(target=fetch)
        th.start()
        server.io_loop.start()
        th.join(timeout=30)
        assert html is not None and "mercury-dem" in html and "bokeh" in html.lower()
    finally:
        server.stop()


def test_legends_sit_outside_the_plot_areas(tmp_path: Path) -> None:
    """A legend inside the map hid the isolated 84° N tile; every legend is laid out below its plot."""
    from bokeh.document import Document
    from bokeh.models import Legend

    doc = Document()
    dashboard_app(tmp_path / "not-yet")(doc)
    for name in ("tile_map", "progress_bars"):
        fig = doc.get_model_by_name(name)
        assert not [m for m in fig.center if isinstance(m, Legend)], name
        assert [m for m in fig.below if isinstance(m, Legend)], name
