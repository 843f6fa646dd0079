"""``mercury_dem.dashboard.embed``: the dashboard server in a thread, shown as an iframe in a notebook.

The notebook side (the iframe in an executed notebook's output, the server answering while
the kernel runs the pipeline, and stopped afterwards) is in ``tests/notebooks``; the iframe
rendered by Chromium is in ``test_browser.py``.
"""

from __future__ import annotations

import http.client
import re
import socket
import urllib.request
from pathlib import Path

import psutil
import pytest

from mercury_dem.dashboard import embed, free_port


def _closed(port: int) -> bool:
    try:
        socket.create_connection(("127.0.0.1", port), timeout=2).close()
    except OSError:
        return True
    return False


def _websocket_status(port: int, origin: str) -> int:
    """HTTP status of a websocket upgrade to the Bokeh server with the given Origin header."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=20)
    try:
        conn.request("GET", "/ws", headers={
            "Connection": "Upgrade", "Upgrade": "websocket", "Sec-WebSocket-Version": "13",
            "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ==", "Origin": origin,
            "Sec-WebSocket-Protocol": "bokeh"})
        return conn.getresponse().status
    finally:
        conn.close()


def test_embed_serves_the_run_on_loopback_and_stops(tiny_run: Path) -> None:
    from bokeh.client import pull_session

    with embed(tiny_run, interval_ms=500) as dash:
        assert dash.running and dash.host == "127.0.0.1" and dash.url == f"http://127.0.0.1:{dash.port}/"
        html = dash._repr_html_()
        assert re.search(rf"<iframe class='mercury-dem-dashboard' src='http://127\.0\.0\.1:{dash.port}/'", html)
        with urllib.request.urlopen(dash.url, timeout=30) as r:
            assert r.status == 200 and "bokeh" in r.read().decode().lower()
        # the page's document, over the server's websocket: the run's tile grid and its states
        with pull_session(url=dash.url) as session:
            tiles = session.document.get_model_by_name("tiles").data
            info = session.document.get_model_by_name("info").text
        assert len(tiles["tile"]) == 14 and set(tiles["state"]) <= {"done", "failed"}
        assert "data-status='finished'" in info
        # it listens on the loopback interface only, and refuses websockets from other origins
        mine = [c for c in psutil.Process().net_connections(kind="tcp")
                if c.status == psutil.CONN_LISTEN and c.laddr.port == dash.port]
        assert mine and {c.laddr.ip for c in mine} == {"127.0.0.1"}
        assert _websocket_status(dash.port, "http://evil.example") == 403
        assert _websocket_status(dash.port, f"http://127.0.0.1:{dash.port}") == 101
    assert not dash.running and _closed(dash.port)
    assert "stopped" in repr(dash) and "<iframe" not in dash._repr_html_()
    dash.stop()  # again: nothing to do


def test_embed_on_a_busy_port_says_so(tmp_path: Path) -> None:
    port = free_port()
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        with pytest.raises(RuntimeError, match=rf"failed to start on 127\.0\.0\.1:{port}"):
            embed(tmp_path / "run", port=port)


def test_embed_proxy_url_and_origins(tmp_path: Path) -> None:
    with embed(tmp_path / "run", url="/proxy/{port}/", origins=["jupyter.example.org"]) as dash:
        assert dash.url == f"/proxy/{dash.port}/"
        assert f"src='/proxy/{dash.port}/'" in dash._repr_html_()
        assert _websocket_status(dash.port, "https://jupyter.example.org") == 101
        assert _websocket_status(dash.port, "https://other.example.org") == 403
