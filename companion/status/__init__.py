"""The live status page (docs/design.md, "The status page"): the flight's event records, served read-only to
browsers from the companion's own event loop while it flies, or from a report directory afterwards."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, TypeVar

from companion.mission.events import EventLog
from companion.status.hub import StatusHub
from companion.status.server import Bind, Limits, StatusServer, read_token
from planner.errors import FuseplanError

T = TypeVar("T")
__all__ = ["Bind", "Limits", "StatusHub", "StatusServer", "read_token", "serve_flight", "serve_report", "load_events"]


async def serve_flight(flight: Callable[[], Awaitable[T]], events: EventLog, bind: Bind, token: str | None,
                       announce: Callable[[str], None]) -> T:
    """Run ``flight()`` with the page served at ``bind`` (and under its ``allowed_hosts``, ``--status-host``): every
    record of ``events`` goes to the browsers too. ``announce`` gets the page's address once it listens."""
    hub = StatusHub()
    hub.extend(events.records)
    events.subscribe(hub.publish)
    try:
        async with StatusServer(hub, bind, token) as server:
            announce(server.url)
            return await flight()
    finally:
        events.unsubscribe(hub.publish)


def load_events(directory: Path) -> list[dict[str, Any]]:
    """The records of ``directory/events.jsonl`` (a ``fuseplan fly`` report), with one-line errors."""
    path = directory / "events.jsonl"
    try:
        lines = path.read_text().splitlines()
    except FileNotFoundError:
        raise FuseplanError(f"{directory}: no events.jsonl here (is it a `fuseplan fly` report directory?)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise FuseplanError(f"{path}: cannot read: {getattr(e, 'strerror', None) or e}") from e
    records = []
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError as e:
            if n == len(lines):  # the last line of a flight that was killed mid-write
                break
            raise FuseplanError(f"{path}, line {n}: not a JSON record ({e.msg})") from None
        if not isinstance(rec, dict) or "event" not in rec:
            raise FuseplanError(f"{path}, line {n}: not an event record (no \"event\" field)")
        records.append(rec)
    return records


async def serve_report(directory: Path, bind: Bind, token: str | None, announce: Callable[[str], None],
                       stop: asyncio.Event | None = None) -> None:
    """Serve the page for a finished flight's report directory at ``bind`` (and under its ``allowed_hosts``) until
    ``stop`` is set (or the task is cancelled)."""
    hub = StatusHub()
    hub.extend(load_events(directory))
    async with StatusServer(hub, bind, token) as server:
        announce(server.url)
        await (stop or asyncio.Event()).wait()
