"""The dashboard in a real browser (headless Chromium via Selenium) while a tiny run is in progress.

The run (``--scheduler sync``, a subprocess) and the dashboard (``mercury-dem dashboard``, a
subprocess on a free port of 127.0.0.1) start together; the page is loaded, then two
snapshots of the tile states are taken from the browser (the Bokeh document's data and
the tile spans in the DOM) as tiles finish, with a screenshot each. Skipped when
Chromium, chromedriver or Selenium is missing (install: apt-get install chromium chromium-driver).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from mercury_dem.dashboard import free_port
from tests.viz.runs import write_tiny_config

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
CHROMEDRIVER = shutil.which("chromedriver") or ("/usr/bin/chromedriver" if Path("/usr/bin/chromedriver").exists() else None)
REPO = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or CHROMEDRIVER is None,
    reason="Chromium and chromedriver are not installed (Debian: apt-get install chromium chromium-driver)",
)

#: JS: tile ids and states as the browser's Bokeh document holds them.
JS_MODEL = """
const doc = (window.Bokeh && Bokeh.documents && Bokeh.documents[0]) || null;
if (!doc) return null;
const ds = doc.get_model_by_name('tiles');
if (!ds) return null;
return {tile: Array.from(ds.data.tile || []).map(Number), state: Array.from(ds.data.state || [])};
"""

#: JS: the tile spans of the page (inside Bokeh's shadow roots): [tile id, state] pairs.
JS_DOM = """
const out = [];
const walk = (root) => {
  for (const el of root.querySelectorAll('*')) {
    if (el.classList && el.classList.contains('tile') && el.dataset.tile) out.push([Number(el.dataset.tile), el.dataset.state]);
    if (el.shadowRoot) walk(el.shadowRoot);
  }
};
walk(document);
return out;
"""


def _driver(profile: Path) -> Any:
    webdriver = pytest.importorskip("selenium.webdriver", reason="pip install selenium (the test extra)")
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--disable-dev-shm-usage", f"--user-data-dir={profile}", "--window-size=1300,1000"):
        opts.add_argument(flag)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)


def _wait(what: str, fn: Any, timeout: float, every: float = 0.5) -> Any:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        v = fn()
        if v:
            return v
        time.sleep(every)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")


def _stop(p: subprocess.Popen[bytes]) -> None:
    if p.poll() is None:
        p.send_signal(signal.SIGTERM)
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(timeout=20)


def test_dashboard_follows_a_live_run(tiny_mission_path: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    cfg = write_tiny_config(tmp_path / "tiny.yaml")
    port = free_port()
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    cli = [sys.executable, "-m", "mercury_dem.cli"]
    # the children keep their own descriptors; ours are closed at once (no ResourceWarning)
    with open(tmp_path / "dashboard.log", "wb") as dash_log, open(tmp_path / "run.log", "wb") as run_log:
        dash = subprocess.Popen([*cli, "dashboard", str(run), "--port", str(port), "--interval", "0.5"],
                                stdout=dash_log, stderr=subprocess.STDOUT, env=env, cwd=REPO)
        job = subprocess.Popen([*cli, "run", str(tiny_mission_path), "--out", str(run), "--scheduler", "sync",
                                "--config", str(cfg)], stdout=run_log, stderr=subprocess.STDOUT, env=env, cwd=REPO)
    driver = None
    try:
        driver = _driver(tmp_path / "chromium-profile")
        url = f"http://127.0.0.1:{port}/"

        def load() -> bool:
            try:
                driver.get(url)
            except Exception:  # noqa: BLE001 - the server may not listen yet
                return False
            return True

        _wait("the dashboard to answer", lambda: dash.poll() is None and load(), 60, 1.0)
        model = lambda: driver.execute_script(JS_MODEL)  # noqa: E731

        def first() -> Any:
            m = model()
            if m and m["tile"]:
                states = m["state"]
                if any(s in ("done", "failed") for s in states) and "pending" in states:
                    return m
            return None

        snap1 = _wait("a first finished tile with others pending", first, 240)
        dom1 = dict(map(tuple, driver.execute_script(JS_DOM)))
        driver.save_screenshot(str(tmp_path / "dashboard-1.png"))
        # Count what the page showed as well as the model read a moment before it (a tile can finish
        # in between): the second snapshot must have more finished tiles than either.
        n1 = max(sum(s != "pending" for s in dom1.values()), sum(s != "pending" for s in snap1["state"]))

        def second() -> Any:
            m = model()
            return m if m and sum(s != "pending" for s in m["state"]) > n1 else None

        snap2 = _wait("another tile to finish", second, 240)
        def page_caught_up() -> Any:  # the Div update lands after the model's
            d = dict(map(tuple, driver.execute_script(JS_DOM)))
            return d if sum(s != "pending" for s in d.values()) > n1 else None

        dom2 = _wait("the page to show the newly finished tile", page_caught_up, 30)
        driver.save_screenshot(str(tmp_path / "dashboard-2.png"))
    finally:
        if driver is not None:
            driver.quit()
        _stop(job)
        _stop(dash)
    # the tile grid is on the page: every planned tile, in the model and as DOM elements
    plan_tiles = sorted(snap1["tile"])
    assert len(plan_tiles) == 14 and sorted(dom1) == plan_tiles and sorted(dom2) == plan_tiles
    s1, s2 = dict(zip(snap1["tile"], snap1["state"])), dict(zip(snap2["tile"], snap2["state"]))
    changed = [t for t in plan_tiles if s1[t] == "pending" and s2[t] in ("done", "failed")]
    assert changed, f"no tile changed state between the snapshots: {s1} -> {s2}"
    assert all(s2[t] != "pending" for t in plan_tiles if s1[t] != "pending")  # nothing goes back
    assert any(dom1[t] == "pending" and dom2[t] in ("done", "failed") for t in changed)  # the DOM followed
    for k in (1, 2):
        png = tmp_path / f"dashboard-{k}.png"
        assert png.stat().st_size > 10_000
    if os.environ.get("MERCURY_DEM_UPDATE_DOCS_IMAGE"):
        (REPO / "docs" / "images").mkdir(parents=True, exist_ok=True)
        shutil.copy(tmp_path / "dashboard-2.png", REPO / "docs" / "images" / "dashboard.png")


def test_embedded_dashboard_renders_in_an_iframe(tiny_run: Path, tmp_path: Path) -> None:
    """What a notebook shows after ``embed(RUN)``: its HTML output in a page of another origin, rendered by Chromium."""
    from mercury_dem.dashboard import embed

    driver = None
    with embed(tiny_run, interval_ms=500) as dash:
        host_page = tmp_path / "notebook-output.html"
        host_page.write_text(f"<html><body><h1>a notebook output cell</h1>{dash._repr_html_()}</body></html>")
        try:
            driver = _driver(tmp_path / "chromium-profile")
            driver.get(host_page.as_uri())
            frame = driver.find_element("css selector", "iframe.mercury-dem-dashboard")
            assert frame.get_attribute("src") == dash.url
            driver.switch_to.frame(frame)
            tiles = _wait("the tile spans inside the iframe", lambda: driver.execute_script(JS_DOM), 120)
            model = driver.execute_script(JS_MODEL)
            driver.switch_to.default_content()
            driver.save_screenshot(str(tmp_path / "embedded.png"))
        finally:
            if driver is not None:
                driver.quit()
    assert len(tiles) == 14 and all(state in ("done", "failed") for _, state in tiles)
    assert sorted(model["tile"]) == sorted(t for t, _ in tiles)
    assert (tmp_path / "embedded.png").stat().st_size > 10_000
    assert not dash.running
    if os.environ.get("MERCURY_DEM_UPDATE_DOCS_IMAGE"):
        (REPO / "docs" / "images").mkdir(parents=True, exist_ok=True)
        shutil.copy(tmp_path / "embedded.png", REPO / "docs" / "images" / "dashboard-embedded.png")
