"""The flight's event log: one JSON object per line (``events.jsonl``), optionally echoed to a callback and passed
to listeners (the status page).

:class:`Event` is the catalogue of what may be logged: every name the companion logs, with its meaning, how it is
shown (:class:`Tone`: the CLI's colour on a terminal, the status page's log class) and whether ``fly`` echoes it.
The log refuses any other name, so a typo fails the first test that reaches it instead of shipping; the CLI, the
status page (served the tones with its script) and the report read names from here, not from lists of their own.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from enum import StrEnum
from pathlib import Path
from typing import Any, TextIO


class Tone(StrEnum):
    """How an event is shown to a person."""

    QUIET = "quiet"  # drawn (map, chips) but no line of the page's log
    PLAIN = "plain"
    GOOD = "good"
    WARN = "warn"
    BAD = "bad"


class Event(StrEnum):
    """Every event the companion logs (and the status page's own ``status_skipped``)."""

    meaning: str
    tone: Tone
    echoed: bool  # a line of ``fly``'s progress output (unless -q)

    def __new__(cls, value: str, meaning: str, tone: Tone = Tone.PLAIN, echoed: bool = False) -> Event:
        member = str.__new__(cls, value)
        member._value_ = value
        member.meaning, member.tone, member.echoed = meaning, tone, echoed
        return member

    # the plan and the scene
    SCENE = "scene", "the scenario and the plan, drawn on the page's map (again after a plan within limits)", Tone.QUIET
    MISSION = "mission", "the mission items as uploaded (and after each replan)", Tone.QUIET
    VEHICLE_WORLD = "vehicle_world", "the fence, rally points and goal downloaded from the vehicle, planned around"
    PLAN_BEYOND_VEHICLE = "plan_beyond_vehicle", "the plan asks for more than the autopilot's parameters allow"
    PLANNED_AGAIN = "planned_again", "the scenario planned again within the vehicle's limits"
    PLAN_ACCEPTED = ("plan_accepted", "the plan passed every check before the upload: its length and clearance",
                     Tone.GOOD, True)
    PLAN_REFUSED = ("plan_refused", "the plan was refused before the upload, and why (told to the ground station)",
                    Tone.BAD, True)
    # the link and the autopilot
    SIM_STARTED = "sim_started", "the built-in simulated autopilot listens"
    SIGNING = "signing", "MAVLink 2 signing is on (the key's fingerprint)"
    TELEMETRY_RATES = "telemetry_rates", "the autopilot's answers to the telemetry rate requests"
    OTHER_AUTOPILOTS = "other_autopilots", "HEARTBEATs from more than one autopilot on the link"
    BOOTING = "booting", "the autopilot is still booting; the companion waits", Tone.WARN, True
    BOOTED = "booted", "the autopilot finished booting", Tone.PLAIN, True
    CONNECTED = "connected", "the autopilot answered: system, autopilot, mode, armed", Tone.PLAIN, True
    VEHICLE_LIMITS = "vehicle_limits", "the vehicle's limits read from its parameters"
    READY = "ready", "the vehicle reports ready (GPS, EKF, home)", Tone.PLAIN, True
    VEHICLE_FIX = "vehicle_fix", "where the vehicle is before the upload"
    DEPARTURE = "departure", "the departure from where the vehicle is, checked"
    FENCE_CAPACITY = "fence_capacity", "the fence against what the autopilot can store"
    MISSION_ROOM = "mission_room", "spare items uploaded behind the mission for a replan's longer route"
    TRAFFIC = "traffic", "the scenario's intruders reported as ADS-B on a spare port (--traffic)"
    LINK_LOST = "link_lost", "no HEARTBEAT for too long; the vehicle flies its verified mission", Tone.BAD, True
    LINK_RESTORED = "link_restored", "HEARTBEATs again after an outage", Tone.GOOD, True
    WAITING_FOR_LINK = "waiting_for_link", "an upload step failed on a lost link; waiting for it"
    LINK_BACK = "link_back", "the link came back while an upload waited"
    LINK_NOT_BACK = "link_not_back", "the link did not come back in time for the upload"
    LINK_GAP = "link_gap", "an outage between upload steps: the vehicle's mission is read back"
    STATUSTEXT = "statustext", "a STATUSTEXT from the autopilot", Tone.PLAIN, True
    # the upload
    BACKUP = "backup", "the vehicle's own mission or fence downloaded before ours replaces it"
    BACKUP_FAILED = "backup_failed", "the vehicle's mission or fence could not be downloaded", Tone.BAD, True
    UPLOAD_START = "upload_start", "the mission and fence upload begins"
    UPLOAD_FAILED = "upload_failed", "an upload attempt failed", Tone.BAD, True
    UPLOAD_VERIFIED = "upload_verified", "the mission and fence uploaded and read back equal", Tone.GOOD, True
    MISSION_VALID = "mission_valid", "the autopilot accepted the mission (PX4's MISSION_CURRENT verdict)"
    RESYNC = "resync", "after an outage the vehicle still has our verified mission", Tone.PLAIN, True
    RESYNC_FAILED = "resync_failed", "reading the mission back after an outage failed; tried again"
    RESYNC_MISMATCH = "resync_mismatch", "after an outage the vehicle's mission is not ours", Tone.BAD, True
    MISSION_RESTORED = "mission_restored", "the vehicle's previous mission or fence put back", Tone.PLAIN, True
    MISSION_RESTORE_ATTEMPT_FAILED = "mission_restore_attempt_failed", "one attempt to put the previous one back failed"
    MISSION_RESTORE_FAILED = "mission_restore_failed", "the previous mission or fence could not be put back", \
        Tone.BAD, True
    # the flight
    MODE = "mode", "the companion set a flight mode", Tone.PLAIN, True
    ARMED = "armed", "the companion armed the vehicle", Tone.PLAIN, True
    ARM_REFUSED = "arm_refused", "the autopilot refused to arm", Tone.BAD, True
    WAITING_FOR_PILOT_ARM = "waiting_for_pilot_arm", "without --arm the pilot arms the vehicle", Tone.PLAIN, True
    SET_CURRENT = "set_current", "the mission's current item set (and confirmed)", Tone.PLAIN, True
    MISSION_START = "mission_start", "MISSION_START sent: the vehicle flies the mission", Tone.GOOD, True
    CURRENT = "current", "the autopilot's current mission item changed", Tone.QUIET
    REACHED = "reached", "a mission item reached", Tone.PLAIN, True
    POSITION = "position", "the vehicle's position (a few a second, for the map)", Tone.QUIET
    DISARMED = "disarmed", "the vehicle disarmed before the goal"
    TIMEOUT = "timeout", "the flight took longer than --flight-timeout", Tone.BAD, True
    FINISHED = "finished", "the companion stopped supervising: completed or not, and why", Tone.PLAIN, True
    FAILED = "failed", "the flight failed on an error", Tone.BAD, True
    ABORTED = "aborted", "the companion stopped supervising (interrupted, or a mission not ours)"
    # traffic and live replanning
    TRACK = "track", "a new ADS-B track", Tone.PLAIN, True
    TRACK_EXPIRED = "track_expired", "a track not heard for too long, dropped", Tone.PLAIN, True
    CONTACTS = "contacts", "the threats the replanner sees now, for the map", Tone.QUIET
    PLANNER_READY = "planner_ready", "the replanner's planning process is warm"
    CONFLICT = "conflict", "a predicted loss of separation with a threat; replan n starts", Tone.WARN, True
    GUARD = "guard", "the flown-safety guard predicts the route too close to an obstacle: hold"
    COMMIT_POINT_PASSED = "commit_point_passed", "the vehicle passed the commit point while a replan ran", Tone.WARN
    REPLAN_FLOWN_CHECK = "replan_flown_check", "a replan's route checked as the vehicle would fly it"
    REPLAN_PLANNED = "replan_planned", "a replan's route planned", Tone.PLAIN, True
    REPLAN_SKIPPED = "replan_skipped", "no better route: the current one is kept", Tone.WARN
    REPLAN_STALE = "replan_stale", "the vehicle passed the commit point while it was planned", Tone.WARN
    REPLAN_UPLOAD_FAILED = "replan_upload_failed", "a replan's upload attempt failed", Tone.BAD, True
    REPLAN_VERIFIED = "replan_verified", "a replan's mission uploaded and read back equal"
    REPLAN_NOT_LIVE = "replan_not_live", "a verified replan no longer clear when it would go live", Tone.WARN
    REPLANNED = "replanned", "a replan's mission is current: latency from the conflict", Tone.GOOD, True
    REPLANNER_FAILED = "replanner_failed", "the live replanner stopped on an error", Tone.BAD, True
    REPLANNING_PAUSED = "replanning_paused", "replanning paused: a mode not the companion's, or the link lost", \
        Tone.WARN
    REPLANNING_RESUMED = "replanning_resumed", "replanning resumed"
    THREAT_CLEARED = "threat_cleared", "no conflict left: the vehicle may rejoin its route", Tone.GOOD, True
    JOIN_CHECK = "join_check", "the rejoin point's separation from a threat checked"
    JOIN_AHEAD = "join_ahead", "the rejoin moved to a later item"
    # holding
    HOLD = "hold", "the vehicle holds (loiter or brake) while no clear route is ready", Tone.WARN, True
    HOLD_REFUSED = "hold_refused", "no checked hold pattern: the vehicle keeps its route"
    HOLD_CIRCLE_REFUSED = "hold_circle_refused", "the autopilot refused the hold circle"
    HOLD_UNCLEAR = "hold_unclear", "the hold pattern is not clear of a threat"
    HOLD_MOVED = "hold_moved", "the hold moved to a clearer circle"
    HOLD_FAILED = "hold_failed", "the vehicle could not be put in a hold", Tone.BAD, True
    HOLD_EXIT = "hold_exit", "leaving the hold circle onto the new route"
    HOLD_EXIT_REFUSED = "hold_exit_refused", "the exit from the hold is not clear"
    HOLD_EXIT_MISSED = "hold_exit_missed", "the exit's time passed: planned again from the circle"
    NOT_HOLDING = "not_holding", "not flying the mission (a failsafe, the pilot): no hold", Tone.WARN
    RESUME = "resume", "the hold ends: AUTO again", Tone.GOOD, True
    RESUME_BLOCKED = "resume_blocked", "the way back to the route crosses an obstacle: planned again"
    NOT_RESUMING = "not_resuming", "someone else changed the mode: the companion leaves it", Tone.WARN
    # the service (fuseplan serve): its own log, service.jsonl, and each request's events.jsonl
    SERVE_START = "serve_start", "the service started: its link, configuration and component id", Tone.PLAIN, True
    SERVE_STOP = "serve_stop", "the service stopped (SIGINT or SIGTERM)", Tone.PLAIN, True
    STOP_DEFERRED = "stop_deferred", "a stop waits for the mission change in hand (an upload, a replan)", Tone.WARN, \
        True
    WAITING_FOR_AUTOPILOT = "waiting_for_autopilot", "no autopilot on the link yet: the service waits", Tone.WARN, True
    AUTOPILOT_RESTARTED = "autopilot_restarted", "the autopilot booted again: a new session", Tone.WARN, True
    SESSION_ERROR = "session_error", "the link went during a transfer: the session starts again", Tone.WARN, True
    PARAMS_FAILED = "params_failed", "the vehicle's limits could not be read: the scenario's are used", Tone.WARN
    BASELINE = "baseline", "the mission on the vehicle when the service connected (left alone)", Tone.PLAIN, True
    CHANGED_WHILE_AWAY = "changed_while_away", "the mission changed while the link was down", Tone.WARN
    READBACK_FAILED = "readback_failed", "a mission readback failed (the operator's upload under way): looked again"
    MISSION_CLEARED = "mission_cleared", "the operator cleared the mission: nothing to plan to"
    REQUEST = "request", "a request opened: its report folder", Tone.PLAIN, True
    PLAN_REQUEST = "plan_request", "the operator uploaded a mission: the service plans to its goal", Tone.PLAIN, True
    SUPERSEDED = "superseded", "a route not flown, replaced by a later request", Tone.QUIET
    PLANNING = "planning", "the request's scenario, planned now", Tone.QUIET
    PLANNED = "planned", "the request planned: status, length, time", Tone.PLAIN, True
    ROUTE_SET = "route_set", "the verified safe route replaced the operator's mission", Tone.GOOD, True
    # the status page's own
    STATUS_SKIPPED = "status_skipped", "records a slow browser missed (the page's own, never in events.jsonl)", \
        Tone.WARN


ENDINGS = frozenset({Event.FINISHED, Event.FAILED, Event.ABORTED})  # the last word on a flight
BY_NAME: dict[str, Event] = {e.value: e for e in Event}
NAMES = frozenset(BY_NAME)


class EventLog:
    """Append-only JSON-lines log with wall time ``t`` (s since the log opened) on every record."""

    def __init__(self, path: Path | None = None, echo: Callable[[dict[str, Any]], None] | None = None,
                 keep: bool = True) -> None:
        self._file: TextIO | None = path.open("w") if path is not None else None
        self._t0 = time.monotonic()
        self.records: list[dict[str, Any]] = []  # every record, unless ``keep`` is False (a log that never ends)
        self._keep = keep
        self._listeners: list[Callable[[dict[str, Any]], None]] = [echo] if echo is not None else []

    def subscribe(self, listener: Callable[[dict[str, Any]], None]) -> None:
        """Pass every record from now on to ``listener`` too (it must not block: it runs inside :meth:`log`)."""
        self._listeners.append(listener)

    def unsubscribe(self, listener: Callable[[dict[str, Any]], None]) -> None:
        self._listeners.remove(listener)

    def log(self, event: Event | str, **fields: Any) -> dict[str, Any]:
        """Append one record; ``event`` must be in the catalogue (:class:`Event`), else ValueError."""
        if event not in NAMES:
            raise ValueError(f"event {event!r} is not in the catalogue (companion.mission.events.Event)")
        rec = {"t": round(time.monotonic() - self._t0, 3), "event": str(event), **fields}
        if self._keep:
            self.records.append(rec)
        if self._file is not None:
            self._file.write(json.dumps(rec, default=str) + "\n")
            self._file.flush()
        for listener in self._listeners:
            listener(rec)
        return rec

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
