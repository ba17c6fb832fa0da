"""The flight's decisions in the pilot's message list (issue 36): an :class:`Announcer` listens to the flight's
:class:`~companion.mission.events.EventLog` and sends a STATUSTEXT line, at its MAV_SEVERITY, for each event the
operator must know about: the plan accepted (its length and clearance) or refused (why), the mission verified, a
conflict predicted, a hold and the resume, a replan made live or its upload failed, the link lost and back, a
failure, the end of the flight.

A line is at most 50 characters in the common case (one STATUSTEXT, no chunking), ``fuseplan: `` in front when it
still fits; reasons that do not fit (a refusal, a failure) go out whole in chunks (:mod:`companion.mavlink.statustext`).
A repeated decision about the same thing (a conflict with the same traffic, predicted again at every replanning
look; a hold refused again) is sent at most once every :data:`REPEAT_S` wall seconds.

While the link is down nothing can be sent: a lost link is announced when it is back, with the outage's length
(``link lost 6 s, back``). The autopilot routes the companion's STATUSTEXT (a broadcast message) to its other
ports, where the ground station listens (docs/autopilots.md, 9.4). A line is sent once, unacknowledged, as any
STATUSTEXT: the event log and the report are the record.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any

from companion.flight.supervisor import DepartureRefused
from companion.mavlink.errors import CompanionError, FenceTooLarge
from companion.mavlink.statustext import TEXT_BYTES, Severity, StatusTexts
from companion.mission.events import EventLog

log = logging.getLogger(__name__)

PREFIX = "fuseplan: "
REPEAT_S = 15.0  # wall s: the same decision about the same thing is not announced again sooner
Line = tuple[str, Severity, str]  # text, severity, repeat key (the same key within REPEAT_S is not sent again)


def _clause(reason: object) -> str:
    """The first clause of a reason ("no safe plan within 2 s (approximate, …)" → "no safe plan within 2 s")."""
    text = str(reason or "")
    for sep in (": ", " (", "; "):
        text = text.split(sep, 1)[0]
    return text.strip()


def _plan_accepted(r: dict[str, Any]) -> Line:
    return f"plan accepted: {r['length_m']:.0f} m, clearance {r['min_clearance_m']:.1f} m", Severity.INFO, ""


def _conflict(r: dict[str, Any]) -> Line:
    """Separation: the predicted distance between the surfaces, 0 when they would overlap."""
    return (f"conflict: {r['threat']} in {r['in_s']:.0f} s, sep {max(r['separation_m'], 0.0):.0f} m",
            Severity.WARNING, f"conflict {r['threat']}")


def _hold(r: dict[str, Any]) -> Line:
    return f"hold ({r['mode']}): {_clause(r['reason'])}", Severity.WARNING, ""


def _finished(r: dict[str, Any]) -> Line:
    if r.get("completed"):
        return "flight complete: goal reached", Severity.INFO, ""
    return f"flight not completed: {r.get('reason')}", Severity.WARNING, ""


def _link_restored(r: dict[str, Any]) -> Line:
    return f"link lost {r['outage_s']:.0f} s, back", Severity.WARNING, ""


# event name → its line; an event not here is not announced
LINES: dict[str, Callable[[dict[str, Any]], Line]] = {
    "plan_accepted": _plan_accepted,
    "plan_refused": lambda r: (f"plan refused: {r['reason']}", Severity.ERROR, ""),
    "upload_verified": lambda r: ("mission uploaded and verified", Severity.INFO, ""),
    "conflict": _conflict,
    "hold": _hold,
    "hold_refused": lambda r: ("no clear hold: flying the cleared leg", Severity.WARNING, "hold_refused"),
    "resume": lambda r: ("hold over: mission resumed", Severity.NOTICE, ""),
    "replanned": lambda r: (f"replan {r['n']} live, sep {r['sep_after_m']:.0f} m", Severity.NOTICE, ""),
    "replan_upload_failed": lambda r: (f"replan {r['n']} upload failed (try {r['attempt']})", Severity.WARNING, ""),
    "link_restored": _link_restored,
    "link_back": lambda r: ("link lost during upload, back", Severity.WARNING, ""),
    "mission_restore_failed": lambda r: (f"{r['mission_type']} restore failed: {r['error']}", Severity.CRITICAL, ""),
    "replanner_failed": lambda r: (f"replanner stopped: {r['error']}", Severity.CRITICAL, ""),
    "hold_failed": lambda r: (f"hold failed: {r['error']}", Severity.CRITICAL, ""),
    "aborted": lambda r: (f"stopped supervising: {r['reason']}", Severity.CRITICAL, ""),
    "failed": lambda r: (f"failure: {r['error']}", Severity.CRITICAL, ""),
    "finished": _finished,
}


def line_for(record: dict[str, Any]) -> Line | None:
    """The line an event record is announced with, or None (not one the operator needs, or malformed)."""
    make = LINES.get(record.get("event", ""))
    if make is None:
        return None
    try:
        return make(record)
    except (KeyError, TypeError, ValueError):  # a field missing or None: no line rather than a broken flight
        log.debug("no announcement for %s", record)
        return None


def with_prefix(text: str) -> str:
    """``fuseplan: `` + text when that is one STATUSTEXT or the text needs chunks anyway; else the text alone."""
    return text if len(text) <= TEXT_BYTES < len(PREFIX) + len(text) else PREFIX + text


class Announcer:
    """Sends the flight's decisions to the ground station while it is entered (``with Announcer(link, events)``),
    as a listener of ``events``. Leaving on a refusal (:class:`DepartureRefused`, :class:`FenceTooLarge`: nothing
    was uploaded) logs ``plan_refused`` (``reason``) and announces it; on another companion error, it announces the
    failure; both while the link is still open (enter it inside the link's context)."""

    def __init__(self, link: Any, events: EventLog, repeat_s: float = REPEAT_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.texts = StatusTexts(link)
        self.events = events
        self.repeat_s = repeat_s
        self._clock = clock
        self._last: dict[str, float] = {}  # repeat key → when last sent

    @property
    def sent(self) -> list[tuple[int, str]]:
        """(severity, text) of every line sent."""
        return self.texts.sent

    def __enter__(self) -> Announcer:
        self.events.subscribe(self)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        try:
            if isinstance(exc, (DepartureRefused, FenceTooLarge)):
                self.events.log("plan_refused", reason=str(exc))
            elif isinstance(exc, CompanionError):
                self.say(f"failure: {exc}", Severity.ERROR)
            elif isinstance(exc, (asyncio.CancelledError, KeyboardInterrupt)):
                self.say("stopped supervising: interrupted", Severity.WARNING)
        finally:
            self.events.unsubscribe(self)

    def __call__(self, record: dict[str, Any]) -> None:
        """An event record in (a listener: never raises, never blocks beyond a socket write)."""
        try:
            line = line_for(record)
            if line is None:
                return
            text, severity, key = line
            now = self._clock()
            if key and now - self._last.get(key, -float("inf")) < self.repeat_s:
                return
            if self.say(text, severity) and key:
                self._last[key] = now
        except Exception:  # an announcement must never break the flight that logs the event
            log.exception("announcing %s", record.get("event"))

    def say(self, text: str, severity: Severity) -> bool:
        return self.texts.send(with_prefix(text), severity)
