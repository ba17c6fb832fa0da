"""The event catalogue (companion.mission.events.Event): every name the companion logs is in it, every name in it
is logged (or is the status page's own), the log refuses any other, and the CLI, the status page and the report
take their names from it."""

from __future__ import annotations

import ast
import asyncio
import json
import re
from pathlib import Path

import pytest

from companion.cli import _echo_event
from companion.mission.events import BY_NAME, ENDINGS, NAMES, Event, EventLog, Tone
from companion.status import Bind, StatusHub, StatusServer

COMPANION = Path(__file__).resolve().parents[3] / "companion"
PAGE_ONLY = {Event.STATUS_SKIPPED}  # the status hub's own record, never logged


def _logged() -> dict[str, list[str]]:
    """Every event name at a ``.log(...)`` call in companion/: string literals in the first argument (also inside a
    conditional expression) and ``Event.MEMBER``s, with where."""
    found: dict[str, list[str]] = {}
    for path in sorted(COMPANION.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "log"
                    and node.args):
                continue
            where = f"{path.relative_to(COMPANION.parent)}:{node.lineno}"
            for part in ast.walk(node.args[0]):
                if isinstance(part, ast.Constant) and isinstance(part.value, str):
                    found.setdefault(part.value, []).append(where)
                elif isinstance(part, ast.Attribute) and isinstance(part.value, ast.Name) and part.value.id == "Event":
                    found.setdefault(Event[part.attr].value, []).append(where)
    return found


def test_every_event_the_companion_logs_is_in_the_catalogue() -> None:
    logged = _logged()
    assert len(logged) > 80  # the walk found the call sites
    unknown = {name: where for name, where in logged.items() if name not in NAMES}
    assert unknown == {}


def test_every_event_in_the_catalogue_is_logged_somewhere() -> None:
    """A name that is styled or drawn but never logged (as conflict_predicted was) is dead weight or a bug."""
    assert sorted(set(Event) - PAGE_ONLY - set(_logged())) == []


def test_every_event_has_a_one_line_meaning_and_a_tone() -> None:
    for e in Event:
        assert e.meaning and "\n" not in e.meaning and len(e.meaning) < 120, e
        assert isinstance(e.tone, Tone) and isinstance(e.echoed, bool)
    assert BY_NAME["conflict"] is Event.CONFLICT and "conflict_predicted" not in NAMES
    assert ENDINGS <= set(Event)


def test_the_log_refuses_a_name_outside_the_catalogue(tmp_path: Path) -> None:
    heard: list[dict] = []
    log = EventLog(tmp_path / "events.jsonl", echo=heard.append)
    log.log("scene", name="s")
    log.log(Event.REACHED, seq=1)
    for wrong in ("conflict_predicted", "Reached", "reached ", ""):
        with pytest.raises(ValueError, match="not in the catalogue"):
            log.log(wrong, seq=2)
    log.close()
    lines = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert [r["event"] for r in lines] == ["scene", "reached"] == [r["event"] for r in heard]
    assert type(heard[1]["event"]) is str  # plain strings in the records, as before


def _page_js() -> str:
    return (COMPANION / "status" / "page.js").read_text()


def test_every_event_name_page_js_uses_is_in_the_catalogue() -> None:
    page = _page_js()
    used = set(re.findall(r'case "([a-z_]+)"', page)) | set(re.findall(r'\be === "([a-z_]+)"', page))
    assert {"scene", "conflict", "replanned", "finished", "status_skipped"} <= used  # the patterns still match
    assert sorted(used - NAMES) == []
    assert "new Set([" not in page.replace("new Set()", "")  # no list of event names of its own


def test_the_page_is_served_the_catalogues_tones() -> None:
    async def get_script() -> bytes:
        async with StatusServer(StatusHub(), Bind.parse("127.0.0.1:0", []), None) as server:
            reader, writer = await asyncio.open_connection("127.0.0.1", server.port)
            writer.write(b"GET /page.js HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
            await writer.drain()
            body = await reader.read()
            writer.close()
            await writer.wait_closed()
            return body.partition(b"\r\n\r\n")[2]

    script = asyncio.run(get_script()).decode()
    first, _, rest = script.partition("\n")
    tones = json.loads(re.fullmatch(r"const EVENT_TONES = Object\.freeze\((.*)\);", first).group(1))
    assert tones == {e.value: e.tone.value for e in Event}
    assert rest == _page_js()


def test_flys_progress_lines_are_the_catalogues_echoed_events(capsys: pytest.CaptureFixture[str]) -> None:
    for e in Event:
        rec = {"t": 1.0, "event": e.value}
        if e in (Event.CONFLICT, Event.REPLAN_PLANNED, Event.REPLANNED):
            continue  # spelled out from their fields
        _echo_event(rec)
        out = capsys.readouterr().out
        assert (out == f"  [   1.0 s] {e.value}\n") == e.echoed, e
    _echo_event({"t": 2.0, "event": "conflict", "threat": "intruder-1", "in_s": 4.0, "separation_m": 3.0,
                 "d_coll_m": 10.0, "n": 1})
    assert "CONFLICT with intruder-1" in capsys.readouterr().out


def test_a_log_that_keeps_no_records_still_writes_and_tells_every_one(tmp_path: Path) -> None:
    """``keep=False`` (fuseplan serve's own log, which lasts as long as the service): nothing held in memory."""
    heard: list[dict] = []
    log = EventLog(tmp_path / "service.jsonl", echo=heard.append, keep=False)
    for _ in range(3):
        log.log("readback_failed", error="DENIED")
    log.close()
    assert log.records == [] and len(heard) == 3
    assert len((tmp_path / "service.jsonl").read_text().splitlines()) == 3
