"""``fuseplan serve``: the companion as a service (issue 36). It runs until cancelled, beside the autopilot:

1. **Link.** One :class:`~companion.mavlink.link.Link` for the service's whole life, sending its HEARTBEAT as the
   path planner (MAV_COMP_ID_PATHPLANNER, 195) so ground stations list it; the link reconnects by itself with
   back-off (a TCP peer that closed, a restarted autopilot), and each new connection or HEARTBEAT gap (``outages``)
   is a new session here: the autopilot booted, its parameters read again, its mission read back.
2. **Requests.** While the vehicle is disarmed, a change of the vehicle's mission that is not the service's own
   upload is a plan request: noticed from MISSION_CURRENT (its ``total``, and its ``mission_id`` where the
   autopilot sends one, :mod:`companion.mavlink.mission_ids`: PX4; where it does not, ArduPilot, a new mission of
   the same length is found by a readback every ``poll_s``), read back until two readbacks agree (the operator's
   upload may still be under way), then read with the vehicle's fence.
3. **Plan.** The base scenario with the configured zones, the fence as zones, the operator's goal and vias, the
   vehicle's position as the start (:mod:`companion.service.planning`), made again within the vehicle's limits as
   ``fly`` does, its departure checked from where the vehicle stands. Accepted: the verified safe route replaces the
   mission (the operator's read first, restored if the upload fails); refused: the operator's mission stays.
4. **Flight.** When the pilot arms with the service's route on the vehicle, it is supervised as ``fly`` supervises
   (a :class:`FlightSupervisor` that never arms or starts; the live replanner and its flown-safety guard, which
   replace the mission, hold the vehicle and resume it as in ``fly``).
5. **Telling.** Every decision is an event of the request's :class:`EventLog` (``plan_request``,
   ``plan_accepted`` with length_m, min_clearance_m and waypoints once the departure check passes, as ``fly`` logs
   it; ``upload_verified``; ``route_set``; ``plan_refused`` with reason; ``failed``), which the flight's
   :class:`~companion.flight.announce.Announcer` sends to the ground station as STATUSTEXT lines (plan accepted
   with its length and clearance, mission uploaded and verified, refused and why, the flight's decisions).

Each request writes a report folder under the log folder (events.jsonl, the request's scenario, PLAN.json, the
mission files and, after a flight, flight.json and track.png); the service's own events go to ``service.jsonl``.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Awaitable, Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from companion.flight.announce import Announcer
from companion.flight.fly import (
    DEFAULT_LOITER_RADIUS_M,
    FlyOptions,
    _departure_check,
    _plan_within,
    _write_flight_report,
    _write_mission_files,
    record_flown_missions,
)
from companion.flight.report import write_json
from companion.flight.supervisor import DepartureRefused, FixedMission, FlightOutcome, FlightSupervisor, Pilot
from companion.mavlink.errors import CompanionError, UploadAborted
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, normalise_frame
from companion.mavlink.link import Link
from companion.mavlink.mission_ids import plan_ids
from companion.mavlink.params import read_params
from companion.mavlink.protocol import MissionClient
from companion.mavlink.storage import mission_difference
from companion.mavlink.telemetry import TelemetryRates
from companion.mavlink.vehicle_limits import AutopilotLimits, limits_from, parameter_names
from companion.mission import picture
from companion.mission.builder import mission_from_plan_json, spec_from_plan_json
from companion.mission.events import EventLog
from companion.mission.vehicle_state import VehicleState, subscribe
from companion.mission.vehicle_world import operator_world
from companion.replanning.replan import ReplanConfig, with_room
from companion.replanning.replanner import LiveReplanner
from companion.service.config import ConfigError, ServeConfig
from companion.service.planning import PlanRefusal, plan_request, request_scenario
from planner.errors import FuseplanError
from planner.world.scenario import Scenario, load_scenario

log = logging.getLogger(__name__)

MAV_COMP_ID_PATHPLANNER = 195
SETTLE_S = 0.3  # wall seconds between the readbacks that must agree before a changed mission is read as a request
SETTLE_READS = 4  # readbacks tried before a mission that keeps changing is left for the next look
POSITION_WAIT_S = 5.0
PARAMS_WAIT_S = 10.0
SESSION_RETRY_S = 0.5  # wall s before a session that failed (a transfer the link broke) is begun again
WATCHED = ("HEARTBEAT", "MISSION_CURRENT", "GLOBAL_POSITION_INT")  # what the service watches between flights
REBOOT_BACK_MS = 1000  # the autopilot's boot time going back more than this: it restarted
CHANGE_WAIT_S = 10.0  # wall s a stop waits for a replan in flight to finish its mission change (and the hold round it)
UPLOAD_WAIT_S = 45.0  # wall s a stop waits for a request's upload to be verified or the operator's mission restored
# (a link that breaks during it is waited for up to LINK_BACK_S = 30 s); docs/fuseplan-serve.service's TimeoutStopSec
# is above both


def mission_key(items: Sequence[MissionItem], home_at_zero: bool) -> tuple:
    """What makes two readbacks of a mission the same mission: every item's command, frame (normalised),
    parameters and position, not its ``current`` flag, nor ArduPilot's home at item 0 (set again at arming)."""
    body = items[1:] if home_at_zero and items else items
    return tuple((it.command, normalise_frame(it.frame), *(_same_nan(p) for p in (it.param1, it.param2, it.param3,
                  it.param4)), it.x, it.y, round(it.z, 3), it.autocontinue) for it in body)


def _same_nan(value: float) -> float | None:
    """NaN (PX4's "unchanged" yaw) as None: NaN is unequal to itself, so two readbacks would never match."""
    return None if math.isnan(value) else value


def _armed(hb: Any) -> bool:
    return bool(hb is not None and hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)


@dataclass
class Accepted:
    """A request whose safe route the vehicle holds (verified), and what its flight needs."""

    number: int
    report: Path
    events: EventLog
    doc: dict[str, Any]
    scenario: Scenario
    items: list[MissionItem]  # as uploaded (with room for replans where the autopilot writes in part)
    planned: int  # items of the planned mission, without the room
    sup: FlightSupervisor
    key: tuple  # mission_key of the route as the vehicle reads it back
    operator: list[MissionItem]  # the operator's mission, the backup
    flown: bool = False
    verified: list[MissionItem] = field(default_factory=list)  # the mission last verified on the vehicle by us: the
    # route, then after a flight the live replanner's last (a replan, or the mission it restored)


@dataclass
class Handled:
    """One request as a test or the status line sees it."""

    number: int
    report: Path
    verdict: str  # "accepted", "refused", "failed"
    reason: str = ""
    noticed_at: float = 0.0  # time.monotonic() when the change was seen
    done_at: float = 0.0  # when the verdict was reached (for "accepted": the route verified on the vehicle)
    flight: dict[str, Any] | None = None


@dataclass
class _Session:
    """What the service knows of the autopilot on the current connection."""

    outages: int
    told: tuple[int, int] | None = None  # MISSION_CURRENT's total and mission id last heard
    ids_known: bool = False  # the autopilot sends mission ids (PX4): no readback polls needed
    boot_ms: int | None = None  # the autopilot's time since boot in its last GLOBAL_POSITION_INT
    changed_at: float | None = None  # when the total changed (a readback is due)
    poll_at: float = 0.0  # the next readback while disarmed


@dataclass
class Service:
    """``fuseplan serve`` (module docstring); ``echo`` gets every event record (the CLI's progress lines)."""

    cfg: ServeConfig
    echo: Callable[[dict[str, Any]], None] | None = None
    source_system: int = 1
    handled: list[Handled] = field(default_factory=list)
    connections: int = 0
    link: Link | None = None
    accepted: Accepted | None = None
    seen: tuple | None = None  # mission_key of the mission last read from the vehicle
    _requests: int = 0
    _limits: AutopilotLimits | None = None  # the autopilot's, read at each connect
    listeners: list[Callable[[dict[str, Any]], None]] = field(default_factory=list)  # every record (status page)
    _busy: bool = False  # a request's upload is under way: a stop waits for its end (never a half-changed mission)
    _uploaded: bool = False  # the request in hand has begun its upload
    _stopping: bool = False
    _pilot: Pilot | None = None  # the pilot of the flight being supervised (the live replanner), else None
    _stop_task: asyncio.Task | None = None
    _plan_stop: threading.Event = field(default_factory=threading.Event)  # ends a search in its thread at a stop

    def stop(self, task: asyncio.Task) -> None:
        """Stop ``task`` (running :meth:`run`): at once, but while the vehicle's mission is being changed. A request
        being planned is dropped (nothing changed on the vehicle yet; its search ends at its next iteration); one
        whose upload is under way is let finish, verified or the operator's mission restored (at most UPLOAD_WAIT_S);
        in a supervised flight, the live replanner's mission change and the hold round it are let finish (at most
        CHANGE_WAIT_S): no mission is left half-changed and the vehicle is let go flying its verified mission."""
        if self._stopping:
            return  # already on its way out
        self._stopping = True
        self._plan_stop.set()
        pilot = self._pilot
        wait: Callable[[], bool]
        if self._busy:
            wait, bound = (lambda: self._busy), UPLOAD_WAIT_S
        elif pilot is not None and (pilot.changing or pilot.holding is not None):
            wait, bound = (lambda: self._pilot is pilot and (pilot.changing or pilot.holding is not None)), \
                CHANGE_WAIT_S
        else:
            task.cancel()
            return
        self.log.log("stop_deferred", upload=self._busy, changing=pilot is not None and pilot.changing,
                     holding=None if pilot is None else pilot.holding, up_to_s=bound)
        self._stop_task = asyncio.get_running_loop().create_task(self._stop_when(task, wait, bound))

    @staticmethod
    async def _stop_when(task: asyncio.Task, busy: Callable[[], bool], bound: float) -> None:
        deadline = time.monotonic() + bound
        while busy() and time.monotonic() < deadline:
            await asyncio.sleep(0.02)
        task.cancel()

    def _fan(self, rec: dict[str, Any]) -> None:
        """Every record of the service's logs to the echo and the listeners."""
        for listener in ([self.echo] if self.echo is not None else []) + self.listeners:
            listener(rec)

    # -- life --------------------------------------------------------------------------------------
    async def run(self) -> None:
        """Serve until cancelled (SIGINT/SIGTERM in the CLI); a fault of one request never ends the service."""
        cfg = self.cfg
        self.base = load_scenario(cfg.scenario, list(cfg.overrides))
        # the telemetry log of the service's whole link (every message both ways, as MAVProxy keeps one per session)
        self.tlog = cfg.log_folder / datetime.now(UTC).strftime("service-%Y%m%dT%H%M%SZ.tlog")
        try:  # the log folder's files, made at start-up: a folder the service cannot write in is the config's fault
            cfg.log_folder.mkdir(parents=True, exist_ok=True)
            # the service's own log lasts as long as the service: written and fanned out, not kept in memory
            self.log = EventLog(cfg.log_folder / "service.jsonl", echo=self._fan, keep=False)
            link = Link(cfg.url, source_system=self.source_system, source_component=MAV_COMP_ID_PATHPLANNER,
                        target_system=cfg.target_system, baud=cfg.baud, heartbeat_timeout=cfg.heartbeat_timeout,
                        open_timeout=math.inf, tlog=self.tlog)
        except OSError as e:
            raise ConfigError(f"{cfg.source}: service.log_folder: cannot write {e.filename or cfg.log_folder}: "
                              f"{e.strerror or e}") from None
        self.log.log("serve_start", link=cfg.url, config=str(cfg.source), component=MAV_COMP_ID_PATHPLANNER,
                     tlog=self.tlog.name)
        try:
            async with link:
                self.link, self.client = link, MissionClient(link)
                rates = self.rates = TelemetryRates(link).start()
                try:
                    while True:
                        try:
                            await self._watch(await self._connect())
                        except (CompanionError, TimeoutError, OSError) as e:  # the link went during a transfer
                            self.log.log("session_error", error=str(e) or type(e).__name__)
                            await asyncio.sleep(SESSION_RETRY_S)
                finally:
                    rates.stop()
        finally:
            self.log.log("serve_stop")
            self.log.close()

    async def _connect(self) -> _Session:
        """Wait for the autopilot (forever), then for its boot; read its limits and the mission it holds."""
        link = self.link
        assert link is not None
        said = False
        while not await link.wait_back(5.0):
            if not said:
                self.log.log("waiting_for_autopilot", url=link.url)
                said = True
        self.connections += 1
        session = _Session(outages=link.outages)
        self.log.log("connected", n=self.connections, system=link.target_system, autopilot=link.autopilot,
                     vehicle_type=link.vehicle_type, outages=link.outages, reconnects=link.reconnects,
                     outage_s=round(link.last_outage_s, 2) if link.outages else None)
        sup = FlightSupervisor(link, self.client, self.log, arm=False)
        await sup.wait_booted()
        try:
            params = await asyncio.wait_for(read_params(link, parameter_names(link.profile.layout,
                                                                              self.base.vehicle.type)), PARAMS_WAIT_S)
        except (CompanionError, TimeoutError) as e:
            self.log.log("params_failed", error=str(e))
            params = {}
        self._limits = limits_from(params, link.profile.layout, self.base.vehicle, DEFAULT_LOITER_RADIUS_M)
        mission = await self._read_settled()
        key = mission_key(mission, self.client.home_at_zero(MISSION))
        if self.seen is None:  # the first connection: what the vehicle holds already is no request
            self.log.log("baseline", items=len(mission), note="a mission already on the vehicle is left alone; "
                         "upload one to ask for a plan")
            self.seen = key
        elif key and key != self.seen and not self._own(mission, key):
            self.log.log("changed_while_away", items=len(mission))
            if _armed(link.last_heartbeat_msg):
                self.seen = key
                self._refuse_armed(mission, time.monotonic())
            else:
                await self._request(mission, time.monotonic())
        else:
            self.seen = key
        session.poll_at = time.monotonic() + self.cfg.poll_s
        return session

    # -- watching for requests and flights ---------------------------------------------------------
    async def _watch(self, session: _Session) -> None:
        """Until the connection changes (a new one, or a HEARTBEAT gap): notice plan requests while disarmed, and
        supervise a flight of the accepted route once the pilot arms."""
        link = self.link
        assert link is not None
        sub = link.subscribe(*WATCHED)

        async def unwatched(work: Awaitable[None]) -> None:
            """``work`` (a flight, a request's planning and upload) with the watch closed: nobody reads it meanwhile
            and it would fill with 1000 stale messages (overflow warnings) to be read through afterwards."""
            nonlocal sub
            sub.close()
            try:
                await work
            finally:
                sub = link.subscribe(*WATCHED)

        try:
            while link.outages == session.outages:
                try:
                    msg = await sub.get(0.25)
                except TimeoutError:
                    msg = None
                now = time.monotonic()
                if msg is not None and msg.get_type() == "GLOBAL_POSITION_INT":
                    if session.boot_ms is not None and msg.time_boot_ms + REBOOT_BACK_MS < session.boot_ms:
                        # restarted faster than the HEARTBEAT timeout (a UDP link sees no gap): a new session
                        self.log.log("autopilot_restarted", boot_ms=msg.time_boot_ms, before_ms=session.boot_ms)
                        self.rates.stop()
                        self.rates.start()  # it forgot the rates asked for
                        return
                    session.boot_ms = msg.time_boot_ms
                    continue
                armed = _armed(link.last_heartbeat_msg)
                if msg is not None and msg.get_type() == "MISSION_CURRENT":
                    ids = plan_ids(msg)
                    told = (msg.total, ids.mission)
                    if told != session.told:  # the first one too: it may come after an upload since the readback
                        session.changed_at = now
                    session.told, session.ids_known = told, session.ids_known or ids.known
                if armed:
                    accepted = self.accepted
                    if accepted is not None and not accepted.flown and self.seen == accepted.key:
                        await unwatched(self._supervise(accepted))  # the flight has its own subscription
                        session.poll_at = time.monotonic() + self.cfg.poll_s
                        continue
                # a readback every poll_s only where the autopilot gives no mission id (ArduPilot); where it does
                # (PX4), every change is told and nothing else is asked of the autopilot
                due = session.changed_at is not None or (not armed and not session.ids_known and now >= session.poll_at)
                if not due or link.heartbeat_age > link.heartbeat_timeout:
                    continue
                noticed = session.changed_at or now
                session.changed_at, session.poll_at = None, now + self.cfg.poll_s
                try:
                    mission = await self._read_settled()
                except CompanionError as e:  # e.g. DENIED while the operator's upload is under way: look again
                    self.log.log("readback_failed", error=str(e))
                    session.changed_at = noticed
                    await asyncio.sleep(SETTLE_S)
                    continue
                key = mission_key(mission, self.client.home_at_zero(MISSION))
                if key == self.seen:
                    continue
                if self._own(mission, key):
                    self.seen = key  # our own route (read back after a restart, our upload's total, or a replan's)
                    continue
                if not key:  # cleared (or a fresh autopilot): nothing to plan to
                    self.seen = key
                    self.log.log("mission_cleared")
                    continue
                if _armed(link.last_heartbeat_msg):
                    self.seen = key
                    self._refuse_armed(mission, noticed)
                    continue
                await unwatched(self._request(mission, noticed))
                session.poll_at = time.monotonic() + self.cfg.poll_s
        finally:
            sub.close()

    def _own(self, mission: list[MissionItem], key: tuple) -> bool:
        """``mission`` (read back, ``key`` its mission_key) is the one the service last verified on the vehicle: its
        route, or the live replanner's last mission after a flight (compared as the upload's readback is, item by
        item as the autopilot stores them); it becomes the accepted key, so it is never taken for a request."""
        accepted = self.accepted
        if accepted is None:
            return False
        if key != accepted.key:
            if not accepted.verified or mission_difference(accepted.verified, mission, self.client.home_at_zero(
                    MISSION), self.client.firmware) is not None:
                return False
            accepted.key = key
        return True

    async def _read_settled(self) -> list[MissionItem]:
        """The vehicle's mission once two readbacks agree (an upload in progress changes it between them)."""
        home0 = self.client.home_at_zero(MISSION)
        last = await self.client.download(MISSION)
        for _ in range(SETTLE_READS):
            await asyncio.sleep(SETTLE_S)
            again = await self.client.download(MISSION)
            if mission_key(again, home0) == mission_key(last, home0):
                return again
            last = again
        return last

    # -- one request -------------------------------------------------------------------------------
    def _open_request(self, noticed: float) -> tuple[Handled, EventLog]:
        self._requests += 1
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
        report = self.cfg.log_folder / f"{stamp}-request-{self._requests:03d}"
        report.mkdir(parents=True, exist_ok=True)
        events = EventLog(report / "events.jsonl", echo=self._fan)
        events.subscribe(Announcer(self.link, events))  # its decisions to the ground station, as fly's
        handled = Handled(self._requests, report, "", noticed_at=noticed)
        self.handled.append(handled)
        self.log.log("request", n=self._requests, report=str(report))
        return handled, events

    def _refuse_armed(self, mission: list[MissionItem], noticed: float) -> None:
        handled, events = self._open_request(noticed)
        reason = "vehicle armed: the mission is not replaced in flight; upload again once disarmed"
        events.log("plan_request", items=len(mission), armed=True)
        events.log("plan_refused", reason=reason)
        handled.verdict, handled.reason, handled.done_at = "refused", reason, time.monotonic()
        events.close()

    async def _request(self, mission: list[MissionItem], noticed: float) -> None:
        """Plan the operator's ``mission`` (read back) round the vehicle's fence and the configured zones from the
        vehicle's position; replace the mission with the verified route, or refuse and keep the operator's."""
        link = self.link
        assert link is not None
        home0 = self.client.home_at_zero(MISSION)
        self.seen = mission_key(mission, home0)  # handled once, whatever the verdict
        handled, events = self._open_request(noticed)
        events.log("plan_request", items=len(mission), total_seen=len(mission) - (1 if home0 else 0))
        if self.accepted is not None and not self.accepted.flown:
            self.accepted.events.log("superseded", by=handled.number)
            self.accepted.events.close()
        self.accepted = None
        self._uploaded = False
        try:
            accepted = await self._plan_and_replace(mission, handled, events)
        except asyncio.CancelledError:  # stopped before the upload (else the stop waits for it): nothing changed
            if not self._uploaded:
                events.log("failed", error="the service stopped before the upload: the operator's mission is "
                           "unchanged", stage="planning")
                handled.verdict, handled.reason = "failed", "stopped before the upload"
                handled.done_at = time.monotonic()
            events.close()
            raise
        except (PlanRefusal, DepartureRefused) as e:
            reason = str(e)
            events.log("plan_refused", reason=reason)
            handled.verdict, handled.reason = "refused", reason
        except UploadAborted as e:  # the operator's mission restored (or the vehicle's state told)
            events.log("failed", error=str(e), stage="upload")
            handled.verdict, handled.reason = "failed", str(e)
        except (CompanionError, TimeoutError, FuseplanError, OSError) as e:
            events.log("failed", error=str(e) or type(e).__name__)
            handled.verdict, handled.reason = "failed", str(e) or type(e).__name__
        else:
            self.accepted = accepted
            handled.verdict = "accepted"
        handled.done_at = time.monotonic()
        if self.accepted is None:
            events.close()
        if self._stopping:
            raise asyncio.CancelledError  # the stop asked for while the request was in hand

    async def _plan_and_replace(self, mission: list[MissionItem], handled: Handled, events: EventLog) -> Accepted:
        link, client, cfg = self.link, self.client, self.cfg
        assert link is not None
        home0 = client.home_at_zero(MISSION)
        fence = await client.download(FENCE)
        rally = await client.download(RALLY)
        world = operator_world(fence, rally, mission, home_at_zero=home0, source=Path(link.url))
        events.log("vehicle_world", zones=[z.name for z in world.zones], rally=len(world.rally),
                   goal=None if world.goal is None else [world.goal.lat, world.goal.lon], vias=len(world.vias))
        if world.goal is None:
            raise PlanRefusal("the mission has no waypoint with a position: nothing to plan to")
        try:
            pos = await link.wait_for("GLOBAL_POSITION_INT", timeout=POSITION_WAIT_S)
        except TimeoutError:
            raise CompanionError(f"no GLOBAL_POSITION_INT within {POSITION_WAIT_S:.0f} s: where the vehicle is is "
                                 "unknown") from None
        report = handled.report
        path, overrides = request_scenario(cfg, world, (pos.lat / 1e7, pos.lon / 1e7), report)
        events.log("planning", scenario=str(path))
        doc, sc = await asyncio.to_thread(plan_request, path, overrides, cfg.seed, cfg.budget_s, self._plan_stop)
        events.log("planned", status=doc["status"], length_m=round(float(doc["metrics"]["length_m"]), 1),
                   plan_s=round(float(doc["metrics"]["plan_time_s"]), 2))
        write_json(report / "PLAN.json", doc)
        limits = self._limits or limits_from({}, link.profile.layout, sc.vehicle, DEFAULT_LOITER_RADIUS_M)
        opts = FlyOptions(connect=cfg.url, arm=False, fence=False, report=report, replan=cfg.replan,
                          flight_timeout=cfg.flight_timeout,
                          plan_again=lambda extra: plan_request(path, [*overrides, *extra], cfg.seed, cfg.budget_s,
                                                                self._plan_stop))
        doc, sc = await _plan_within(doc, sc, limits, opts, events)
        events.log("scene", **picture.scene(sc, doc))  # the status page's map of this request
        sup = FlightSupervisor(link, client, events, arm=False, home=sc.home)
        _departure_check(doc, sc, limits, events)(*await sup.vehicle_fix())
        autopilot = link.profile.layout
        items = mission_from_plan_json(doc, sc, autopilot)
        spec = spec_from_plan_json(doc, sc, autopilot)
        _write_mission_files(report, doc, sc, items, spec, [])
        planned = len(items)
        if cfg.replan and client.writes_in_part:
            items = with_room(items, ReplanConfig().spare_items)
        if _armed(link.last_heartbeat_msg):
            raise PlanRefusal("vehicle armed while planning: the mission is not replaced in flight")
        if self._stopping:
            raise asyncio.CancelledError  # a stop that came as the plan was finished: nothing changed yet
        self._busy = self._uploaded = True  # from here a stop waits: the mission is changed, verified or restored
        try:
            # reads the operator's mission first, restores it if the upload fails; the pilot may arm meanwhile
            await sup.upload(items, before=self._refuse_if_armed)
        finally:
            self._busy = False
        events.log("mission", **picture.mission(items, sc.home))
        key = mission_key(sup.readback, home0)  # the readback that verified the upload: the route as stored
        self.seen = key
        events.log("route_set", items=len(items), planned_items=planned, operator_items=len(mission))
        return Accepted(handled.number, report, events, doc, sc, list(items), planned, sup, key, list(mission),
                        verified=list(items))

    def _refuse_if_armed(self) -> None:
        """Right before the route's transfer starts (the latest HEARTBEAT): armed, the operator's mission stays."""
        link = self.link
        assert link is not None
        if _armed(link.last_heartbeat_msg):
            raise PlanRefusal("vehicle armed before the upload: the mission is not replaced in flight")

    # -- a flight ----------------------------------------------------------------------------------
    async def _supervise(self, accepted: Accepted) -> None:
        """The pilot armed with the accepted route on the vehicle: supervise it to its end as ``fly`` does (the
        service never arms or starts; its live replanner replaces the mission, holds and resumes as ``fly``'s does),
        then write flight.json in the request's folder."""
        link, cfg = self.link, self.cfg
        assert link is not None
        accepted.flown = True
        events, sc, doc, items = accepted.events, accepted.scenario, accepted.doc, accepted.items
        events.log("armed", note="the pilot armed: supervising the flight")
        sup = accepted.sup
        out = sup.outcome = FlightOutcome(False, "", mission_count=len(items), fence_count=0)
        length = float(doc["metrics"]["length_m"])
        timeout = cfg.flight_timeout or 120.0 + 4.0 * length / sc.vehicle.cruise_speed
        spec = spec_from_plan_json(doc, sc, link.profile.layout)
        replanner = None
        with subscribe(link) as sub:
            async with contextlib.AsyncExitStack() as stack:
                if cfg.replan:
                    replanner = await stack.enter_async_context(LiveReplanner(
                        link, self.client, events, sc, spec, items, None, seed=int(doc.get("seed") or 0),
                        limits=self._limits))
                pilot = replanner if replanner is not None else FixedMission(items, VehicleState(sc.home))
                pilot.state.mission_started(time.monotonic())
                self._pilot = pilot
                try:
                    await sup.monitor(pilot, timeout, out, sub)
                except CompanionError as e:
                    out.completed, out.reason = False, str(e)
                    events.log("failed", error=str(e), started=True)
                finally:
                    self._pilot = None
        events.log("finished", completed=out.completed, reason=out.reason, reached=len(out.items_reached))
        # the missions as flown, as fly records them: the last verified on the vehicle (the route, a replan's, or
        # the one a replan restored) is mission.*, and the service's own from now on
        missions, index = record_flown_missions(accepted.report, doc, sc, spec, [], sup, replanner, events)
        if missions:
            accepted.verified = list(missions[-1].items)
        opts = FlyOptions(connect=cfg.url, report=accepted.report, replan=cfg.replan)
        flight = await asyncio.to_thread(_write_flight_report, opts, doc, sc, out, None, link.profile.layout,
                                         (accepted.planned, len(items)), replanner, None, self._limits, index,
                                         self.tlog)
        for h in self.handled:
            if h.number == accepted.number:
                h.flight = flight
        events.close()


__all__ = ["Handled", "MAV_COMP_ID_PATHPLANNER", "Service", "mission_key"]
