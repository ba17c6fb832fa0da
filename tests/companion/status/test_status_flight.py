"""The status page during a real flight (`fuseplan demo --status-page 0`, a child process on the built-in
simulator): 50 browsers' worth of event streams and one that stops reading leave the replans within their budget
and the companion's memory bounded; afterwards the report directory serves the same records."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import aiohttp
import pytest
from demo_flight import Companion, check_load, start_clients

from companion.cli import main
from companion.status import Bind, load_events, serve_report
from planner.errors import FuseplanError


@pytest.mark.slow(covered_by="companion/status/test_status_browser.py::"
                             "test_the_page_shows_route_vehicle_intruder_and_replan_as_they_happen")
def test_fifty_browsers_and_a_stalled_one_leave_the_replans_in_budget(tmp_path: Path) -> None:
    """The same load as the browser test's flight, without a browser (where Chromium is missing)."""
    with Companion(tmp_path, "demo", "--status-page", "0") as companion:
        clients = start_clients(companion.url)
        code = companion.wait()
        assert code == 0, companion.output
        print(check_load(companion, clients, tmp_path / "fuseplan-demo"))


def _report(tmp_path: Path) -> Path:
    d = tmp_path / "report"
    d.mkdir()
    recs = [{"t": 0.0, "event": "scene", "name": "rescue_dynamic"}, {"t": 0.5, "event": "position", "x": 1.0},
            {"t": 9.0, "event": "finished", "completed": True, "reason": "goal waypoint reached", "reached": 3}]
    (d / "events.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs) + '{"t": 9.1, "event": "fin')
    (d / "flight.json").write_text(json.dumps({"replans": 1, "replan_latency_s": {"median": 0.14, "max": 0.14},
                                               "min_clearance_m": 16.5}))
    return d


@pytest.mark.asyncio
async def test_a_report_directory_serves_its_records(tmp_path: Path) -> None:
    d = _report(tmp_path)
    stop = asyncio.Event()
    urls: list[str] = []
    task = asyncio.create_task(serve_report(d, Bind.parse("0"), None, urls.append, stop))
    while not urls:
        await asyncio.sleep(0.01)
    async with aiohttp.ClientSession() as s, s.get(urls[0] + "events") as r:
        await r.content.readuntil(b"\n\n")  # the reset
        got = [json.loads((await r.content.readuntil(b"\n\n")).split(b"data: ")[1]) for _ in range(3)]
    stop.set()
    await task
    assert [g["event"] for g in got] == ["scene", "position", "finished"]  # the torn last line left out


def test_report_summarises_and_refuses_what_is_not_a_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    d = _report(tmp_path)
    assert main(["report", str(d)]) == 0
    out = capsys.readouterr().out
    assert "rescue_dynamic, 3 events" in out and "goal waypoint reached" in out and "replans 1" in out
    assert "min clearance 16.5 m" in out
    (d / "flight.json").write_text(json.dumps({"replans": 0, "replan_latency_s": None, "min_clearance_m": None}))
    assert main(["report", str(d)]) == 0  # an empty map's clearance is infinite: null in flight.json
    assert "replans 0" in capsys.readouterr().out
    assert main(["report", str(tmp_path / "nothing")]) == 2
    assert "no events.jsonl here" in capsys.readouterr().err
    (d / "events.jsonl").write_text('{"t": 0, "event": "scene"}\nnot json\n{"t": 1, "event": "x"}\n')
    with pytest.raises(FuseplanError, match="line 2: not a JSON record"):
        load_events(d)
    assert main(["report", str(d), "--serve", "0.0.0.0:0"]) == 2
    assert "--status-token FILE" in capsys.readouterr().err
