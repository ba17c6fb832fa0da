"""A ground station on another port of a real autopilot, for the SITL flights (issue 36): in its own thread (the
flight runs ``fuseplan fly`` synchronously meanwhile) it connects as system 255 / Mission Planner's component, first
runs ``first(link)`` if given (an upload), then keeps every whole STATUSTEXT line it receives, from anyone, until
closed: what the autopilot routed on from the companion's port among them.

It turns off the streams the companion turns off too (PX4's GCS link floods it as the companion link does): once,
on PX4 SITL at 10x on a loaded machine, the companion's first line never reached this thread, which shares the
interpreter with the flight and was reading that flood over UDP."""

from __future__ import annotations

import asyncio
import json
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from pathlib import Path

from companion.mavlink.link import Link
from companion.mavlink.statustext import Reassembler
from companion.mavlink.telemetry import request_rates


@dataclass(frozen=True)
class Line:
    system: int
    component: int
    severity: int
    text: str


def accepted_line(report: Path) -> str:
    """The plan-accepted line the companion sends for the plan in ``report``/PLAN.json."""
    metrics = json.loads((report / "PLAN.json").read_text())["metrics"]
    return f"fuseplan: plan accepted: {metrics['length_m']:.0f} m, clearance {metrics['min_clearance_m']:.1f} m"


class StatusTextGcs:
    def __init__(self, url: str, first: Callable[[Link], Awaitable[None]] | None = None,
                 heartbeat_timeout: float = 20.0) -> None:
        self.url, self.first, self.heartbeat_timeout = url, first, heartbeat_timeout
        self.lines: list[Line] = []
        self.error: BaseException | None = None
        self.streams_off_s = 0.0  # wall s the streams took to turn off (the one wait this adds to a flight test)
        self._ready = threading.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._thread = threading.Thread(target=asyncio.run, args=(self._run(),), name="statustext-gcs", daemon=True)

    def from_companion(self, component: int = 191) -> list[Line]:
        """The lines the companion's link (MAV_COMP_ID_ONBOARD_COMPUTER) sent."""
        return [ln for ln in self.lines if ln.component == component]

    async def _run(self) -> None:
        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        try:
            async with Link(self.url, source_system=255, source_component=190, open_timeout=5.0) as link:
                await link.wait_heartbeat(self.heartbeat_timeout)  # heard, and the autopilot has heard us
                t0 = time.monotonic()
                await request_rates(link, rates=())  # its profile's streams_off only
                self.streams_off_s = time.monotonic() - t0
                if self.first is not None:
                    await self.first(link)
                with link.subscribe("STATUSTEXT", any_source=True, maxsize=10000) as sub:
                    self._ready.set()
                    joiner = Reassembler()
                    while not self._stop.is_set():
                        try:
                            msg = await sub.get(0.1)
                        except TimeoutError:
                            continue
                        text = joiner.feed(msg)
                        if text is not None:
                            self.lines.append(Line(msg.get_srcSystem(), msg.get_srcComponent(), msg.severity, text))
        except BaseException as e:  # handed to the test thread by __enter__ / close
            self.error = e
        finally:
            self._ready.set()

    def __enter__(self) -> StatusTextGcs:
        self._thread.start()
        self._ready.wait(60.0)
        if self.error is not None:
            self._thread.join(5.0)
            raise self.error
        return self

    def close(self) -> None:
        if self._loop is not None and self._stop is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop.set)
        self._thread.join(10.0)

    def __exit__(self, *exc: object) -> None:
        self.close()
