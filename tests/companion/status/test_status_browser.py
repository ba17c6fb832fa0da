"""The status page in a real browser: headless Chromium (Debian's package, driven by Playwright) watching
`fuseplan demo --status-page 0` on the built-in simulator. The route, the vehicle moving, the intruder and the
replan are read from the page's DOM as they happen; screenshots are saved with the test's output. Meanwhile 50
more event streams and one that stops reading load the page, and the replans must stay within their targets."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from demo_flight import Companion, check_load, start_clients

sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install -e '.[test]')")

CHROMIUM = os.environ.get("FUSEPLAN_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
if not CHROMIUM:
    pytest.skip("Debian's chromium is not installed (apt-get install chromium; .ci/run installs it)",
                allow_module_level=True)
# headless, and nothing that reaches for the internet: the machines here have none (Chromium's background
# services would be refused, many at a time)
FLAGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync"]
WAIT_MS = 60_000


def artifacts(tmp_path: Path) -> Path:
    """Where screenshots go: $FUSEPLAN_TEST_ARTIFACTS if set (CI keeps it), else the test's own folder."""
    d = Path(os.environ.get("FUSEPLAN_TEST_ARTIFACTS") or tmp_path)
    d.mkdir(parents=True, exist_ok=True)
    return d


def test_the_page_shows_route_vehicle_intruder_and_replan_as_they_happen(
        tmp_path: Path, record_property: pytest.RecordProperty) -> None:
    out = artifacts(tmp_path)
    with sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=FLAGS)
        try:
            page = browser.new_page(viewport={"width": 1400, "height": 850})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            with Companion(tmp_path, "demo", "--status-page", "0") as companion:
                clients = start_clients(companion.url)
                page.goto(companion.url)
                # the planned route and the map, from the scene record
                page.wait_for_function("() => document.getElementById('route').points.length >= 10",
                                      timeout=WAIT_MS)
                assert page.locator("#static .cylinder").count() == 6  # rescue_dynamic's six cylinders
                # the vehicle, moving while the flight goes on
                page.wait_for_selector("#vehicle:not([hidden])", timeout=WAIT_MS)
                first = page.evaluate("[+vehicle.dataset.x, +vehicle.dataset.y]")
                moved = page.wait_for_function(
                    """([x, y]) => { const v = document.getElementById('vehicle');
                       return Math.hypot(v.dataset.x - x, v.dataset.y - y) > 20
                              && !document.body.dataset.finished && [+v.dataset.x, +v.dataset.y]; }""",
                    arg=first, timeout=WAIT_MS).json_value()
                # the intruder reported over ADS-B, with its predicted path, before the flight is over
                intruder = page.wait_for_function(
                    """() => { const c = document.querySelector('.contact.adsb');
                       return c && !document.body.dataset.finished
                              && {id: c.dataset.id, path: c.querySelector('polyline').points.length}; }""",
                    timeout=WAIT_MS).json_value()
                # the replan made live: old and new route, commit point, latency, shown while the vehicle still
                # flies (an earlier attempt may have found no safe route in its budget and held the vehicle)
                replan = page.wait_for_function(
                    """() => { const g = document.querySelector('.replan.live');
                       return g && !document.body.dataset.finished && {
                         n: +g.dataset.n, latency: +g.dataset.latency,
                         old: g.querySelector('.old-route').points.length,
                         new: g.querySelector('.new-route').points.length,
                         commit: !!g.querySelector('.commit'),
                         row: document.querySelector(`#replan-table tr[data-n="${g.dataset.n}"]`).textContent }; }""",
                    timeout=WAIT_MS).json_value()
                page.screenshot(path=str(out / "status_page_replan.png"))
                page.wait_for_selector("body[data-finished=completed]", timeout=WAIT_MS)
                track = page.evaluate("document.getElementById('track').points.length")
                live = page.locator(".replan.live").count()
                page.screenshot(path=str(out / "status_page_done.png"))
                assert companion.wait() == 0, companion.output
                load = check_load(companion, clients, tmp_path / "fuseplan-demo")
            # afterwards: the same page from the report directory
            with Companion(tmp_path, "report", "fuseplan-demo", "--serve", "0") as report:
                page.goto(report.url)
                page.wait_for_selector("body[data-finished=completed]", timeout=WAIT_MS)
                again = page.evaluate("""() => ({ replans: document.querySelectorAll('.replan.live').length,
                    track: document.getElementById('track').points.length,
                    route: document.getElementById('route').points.length })""")
        finally:
            browser.close()
    record_property("screenshots", str(out))
    print(f"vehicle {first} -> {moved}; intruder {intruder}; replan {replan}; track {track} points; "
          f"screenshots in {out}; {load}")
    assert intruder["id"].startswith("adsb-") and intruder["path"] >= 2
    assert replan["old"] >= 2 and replan["new"] >= 2 and replan["commit"]
    assert 0 < replan["latency"] <= 1.0 and "new mission current" in replan["row"]
    assert track >= 20
    assert live >= 1 and again["replans"] == live and again["track"] == track and again["route"] >= 10
    assert not errors, errors
