"""Live replanning around dynamic threats, the MAVLink part (docs/design.md, "Live replanning"): watch, predict,
plan, swap missions.

Runs beside the supervisor's monitor as its own task with its own subscription. On a predicted conflict:

1. commit point ahead of the vehicle (where it will be when the new mission can be live), planned from there
   to the goal with the threat picture, warm-started from the old remaining route, within a wall budget;
2. the new mission keeps every item before the commit point unchanged and is uploaded while the vehicle
   flies (ArduPilot keeps flying its active item); a guard holds the vehicle (LOITER) if it could finish its
   active item before the upload is verified, because uploads are not atomic and the next item may be
   half-written;
3. verified by readback, then MAV_CMD_DO_SET_MISSION_CURRENT to the commit point if the vehicle's active item
   was replaced (and MISSION_CURRENT must confirm it), AUTO again if it was held.

A failed upload holds the vehicle and re-uploads; no safe plan holds it and retries until a plan is found or
the old route is clear again. Every decision goes to the event log.
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import math
import time
from collections.abc import Awaitable, Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import (
    CommandError,
    CompanionError,
    MissionUploadError,
    VehicleHolding,
)
from companion.mavlink.items import MissionItem
from companion.mavlink.link import MAV_COMP_ID_ADSB, Link, Message, Subscription
from companion.mavlink.protocol import MissionClient
from companion.mavlink.vehicle_limits import ARDUPLANE_TURN_EFFICIENCY, AutopilotLimits
from companion.mission import picture
from companion.mission.builder import MissionSpec
from companion.mission.events import EventLog
from companion.mission.geo import enu_to_geodetic, geodetic_to_enu, to_int_e7
from companion.mission.restore import restore_mission
from companion.replanning.guard import GUARD_DT_S, first_breach, predict_own_path
from companion.replanning.holds import (
    FLOWN_WIDER_M,
    HOLD_MARGIN_M,
    CircleExit,
    HoldPattern,
    arc_to,
    circle_exit,
    circle_traffic_separation,
    copter_hold,
    flown_ring,
    plane_hold,
    ring,
)
from companion.replanning.replan import (
    CommitPoint,
    MissionRoute,
    ReplanConfig,
    VehicleClock,
    commit_point,
    replan_problem,
    replan_settings,
    splice,
    warm_starts,
)
from companion.replanning.threats import (
    Conflict,
    TrackPicture,
    predict_conflicts,
    route_separations,
)
from companion.replanning.worker import PlanWorker, expects_traffic
from planner.plan import PlanStatus
from planner.trajectory.checks import nearest_obstacle
from planner.world.config import G0
from planner.world.environment import Threats
from planner.world.scenario import Scenario

log = logging.getLogger(__name__)
WATCHED = ("GLOBAL_POSITION_INT", "ADSB_VEHICLE", "MISSION_CURRENT", "MISSION_ITEM_REACHED", "HEARTBEAT")
# ADS-B reports come from the autopilot (its own receiver, forwarded) or from a receiver that is a MAVLink component
# of the same vehicle; that receiver's other messages (its HEARTBEAT) and every other system's are not ours
ADSB_SOURCES = {"ADSB_VEHICLE": (MAV_COMP_ID_ADSB,)}
BAND_INSET_M = 0.5  # a commit point is moved at least this far inside the altitude band
GOOD = (PlanStatus.EXACT.value, PlanStatus.APPROXIMATE.value)
CONTACTS_EVERY_S = 0.25  # wall seconds between two ``contacts`` records (the status page's traffic picture)
CONTACT_PATH_S = 60.0  # vehicle seconds of each contact's predicted path in a ``contacts`` record
PACE_TAU_S = 8.0  # vehicle seconds over which the ground speed along the route is smoothed
GUARD_MIN_ALT_M = 10.0  # m above home: below it the vehicle is taking off or landing, which the guard leaves be
GUARD_REPEAT_WALL_S = 1.0  # wall seconds between two guard actions
JOIN_LATENCY_S = 1.0  # vehicle seconds between choosing the item to join and the autopilot flying to it
FLOWN_CHECK_DT_S = 0.5  # vehicle seconds between the points of a plan's flown path
HOLD_CHECK_WALL_S = 0.5  # wall seconds between two looks for a hold pattern after none was found, and between
# two traffic checks of the circle being held (each takes CPU the planner needs: under load, 30 a second)
RESUME_HORIZON_S = 20.0  # vehicle seconds of the path flown on resuming that are checked
# m beyond d_coll that what a plane flies on resuming must clear, as a hold's: with 5 m, a plane resumed on ArduPlane
# SITL (under load) came 7.2 m from a cylinder the check had passed at 15 m; with 10 m the simulator's plane once
# circled through 120 replans, every route planned from its circle 19.1-20.0 m from a cylinder (before holds took
# circles a little short of their margin and kept the route where it kept the traffic further; docs/design.md)
RESUME_MARGIN_M = HOLD_MARGIN_M
# vehicle seconds before the exit point of its hold circle that a plane is resumed onto the route planned from there
# (ArduPlane rolls out of its bank over about a second), and the least time beyond planning and upload it circles
# before the exit (docs/design.md, "Leaving a hold")
EXIT_LEAD_S = 1.0
EXIT_MARGIN_S = 3.0
EXIT_LATE_S = 3.0  # vehicle seconds after the exit was due that it counts as missed (the plan's time is gone)
# m beyond d_coll the resume at a circle's exit is checked with (leg_blocked): its route was planned from there with
# RESUME_MARGIN_M more than d_coll and its turns' swing, and, aligned with its first leg, the plane flies it with
# little turn; the check's paths turn up to WIDE_TURNS times wider than the path-follower's bound, which is for
# turning back from anywhere. Checked with a margin, exits were refused at 13.9-19.9 m and planned again, for good
EXIT_CHECK_MARGIN_M = 0.0
RESUME_ROLL_OUT_S = 3.0  # vehicle seconds a plane held on a circle may circle on after its resume is checked
# how much wider than its path-follower's bound (AutopilotLimits.wide_turn_radius) a plane may turn (_flown_paths,
# and onto a hold circle): resuming, ArduPlane SITL at 23.5 m/s turned back from a hold at 58 m against the L1
# law's 37 m, then flew straight at the item from there, 22.7 m into a cylinder the path predicted at 37 m cleared.
# SITL's plane turns at ARDUPLANE_TURN_EFFICIENCY (0.58) of the rate its bank implies, so up to 1/0.58 = 1.72 times
# wider; with 1.6, the simulator flying that came 6.5 m from a cylinder on resuming (crossing_traffic, 1 of 10)
WIDE_TURNS = 1.05 / ARDUPLANE_TURN_EFFICIENCY
# vehicle seconds a plane may fly on straight after a hold is commanded before it turns onto the circle (ArduPlane
# SITL at 10x: ~2 s between the acknowledged DO_REPOSITION and the first change of heading, our latency included)
HOLD_TURN_LAG_S = 2.5
MIN_HOLD_RADIUS_TURNS = 2.0  # the smallest hold circle commanded, in tightest turns (ArduPlane flies it wider)
# the guard acts on a predicted clearance below this share of d_coll: its path model is a few metres off in a turn
# (the demo's plane: predicted 9.9 m, flown 15.4 m), and a hold that was not needed turns the plane off its route
GUARD_SHARE_OF_D_COLL = 0.5


def watch(link: Link) -> Subscription:
    """The replanner's subscription: :data:`WATCHED` from the target autopilot, and ADSB_VEHICLE also from an
    ADS-B receiver of the same vehicle (:data:`ADSB_SOURCES`)."""
    return link.subscribe(*WATCHED, extra_components=ADSB_SOURCES)



@dataclass
class ReplanRecord:
    """One replan, as written to flight.json and drawn on the report."""

    n: int
    reason: str
    threat: str
    t_mission: float
    conflict_in_s: float
    sep_before_m: float
    sep_after_m: float | None = None
    plan_status: str = ""
    budget_s: float = 0.0  # the planner's time budget for this plan (it doubles after a failed plan)
    plan_s: float = 0.0
    upload_s: float = 0.0
    latency_s: float | None = None  # conflict detected → new mission current (wall)
    held: bool = False
    upload_path: str = ""  # "partial FIRST-LAST", "whole" or "unchanged" (MissionClient.upload_changed_verified)
    outcome: str = ""
    commit: list[float] = field(default_factory=list)
    old_route: list[list[float]] = field(default_factory=list)
    new_route: list[list[float]] = field(default_factory=list)

    def summary(self) -> dict[str, Any]:
        """The event-log view (routes left out)."""
        d = {k: v for k, v in self.__dict__.items() if k not in ("old_route", "new_route")}
        return {k: round(v, 3) if isinstance(v, float) else v for k, v in d.items()}


@dataclass
class Leaving:
    """A plane's way off its hold circle: the ``exit`` its route is planned from, the mission time it is ``due``
    there and, once that route is live, the item after the exit (``seq``) and the arc still to circle at the last
    look (``left_m``)."""

    exit: CircleExit
    due: float
    seq: int | None = None
    left_m: float | None = None


class LiveReplanner:
    """Watches the flight and replaces the mission when a threat will come too close.

    ``items`` is the verified mission being flown; ``rate`` the vehicle's seconds per wall second if known
    (our simulator's speed-up), else measured; ``seed`` makes the replans reproducible for a given picture.
    """

    def __init__(self, link: Link, client: MissionClient, events: EventLog, scenario: Scenario,
                 spec: MissionSpec, items: Sequence[MissionItem], cfg: ReplanConfig | None = None, *,
                 rate: float | None = None, seed: int = 0, limits: AutopilotLimits | None = None,
                 worker: PlanWorker | None = None) -> None:
        """``worker``: a planner process started earlier (``fly`` starts one as soon as the link is open, so its
        start and imports overlap the boot wait, the parameter reads and the upload); it is warmed up on this
        route and closed with the replanner (closing it again, as its starter may, is harmless)."""
        self.link, self.client, self.events = link, client, events
        self.limits = limits  # the vehicle's own (loiter radius, braking); None: the config's and scenario's
        self.scenario, self.spec = scenario, spec
        self.cfg = cfg or ReplanConfig()
        self.clock = VehicleClock(rate)
        self.tracks = TrackPicture(scenario.home)
        self.route = MissionRoute.of(items, scenario.home)
        # every mission known verified on the vehicle, with the (monotonic) time its readback matched
        self.verified: list[tuple[float, list[MissionItem]]] = [(time.monotonic(), list(items))]
        self.records: list[ReplanRecord] = []
        self.seed = seed
        self.position: np.ndarray | None = None
        self.current_seq = 0
        self._mission_wall: float | None = None  # wall time of the mission start
        self._mission_t0: float | None = None  # vehicle time of the mission start, once the clock is synced
        self.holding: str | None = None  # why the vehicle is held, or None
        self.held_in: str | None = None  # the mode it is held in (GUIDED for a plane's checked circle)
        self.hold_pattern: HoldPattern | None = None  # the checked pattern it holds on
        self.velocity = np.zeros(2)  # ENU m/s over the ground, from GLOBAL_POSITION_INT
        self._held_since: float | None = None  # mission time the current hold began
        # a plane held on a circle leaves it where its new route starts: the exit being planned, then the one live
        self._planning_exit: Leaving | None = None
        self._exit: Leaving | None = None
        self._last_replan = -math.inf  # mission time
        self._hold_refused_at = -math.inf  # wall time no checked hold pattern was found
        self._route_kept_at = -math.inf  # wall time a late plan's hold was refused for the route being flown
        self._hold_checked_at = -math.inf  # wall time the hold circle was last checked against the traffic
        self._failed_plans = 0  # plans in a row that were not safe enough to use (each next one gets more budget)
        self._last_check = -math.inf  # wall
        self._upload_wall_s = 0.05  # running estimate of one verified upload (wall s)
        self._announced: set[int] = set()
        self.custom_mode: int | None = None  # the vehicle's mode, from HEARTBEAT
        self.groundspeed = 0.0
        self.pace: float | None = None  # smoothed ground speed along the route (m/s), once measured
        self._pace_t: float | None = None  # vehicle time of the last ground speed
        self._paused_in: int | None = None  # a mode we did not command, while replanning is paused
        self._link_down = False  # between the supervisor's link_lost and its re-sync: no telemetry, no uploads
        self._fresh_since = 0.0  # monotonic: position and active item must be newer than this to predict from
        # monotonic time of the latest position and (if the autopilot streams it) active item
        self._seen: dict[str, float] = {"GLOBAL_POSITION_INT": 0.0}
        self._sub: Any = None
        self._contacts_at = -math.inf  # wall time of the last ``contacts`` record
        # started now, and warmed up on the whole route, so the first conflict finds it ready; a flight with nothing
        # moving (the flown-safety guard may still need a static replan) starts it only when it is first needed
        self._worker: PlanWorker | None = None
        self._expect_traffic = expects_traffic(scenario, rate)
        if self._expect_traffic or worker is not None:
            self._start_worker(worker)
        self.guard_enabled = True  # the flown-safety guard (companion/replanning/guard.py)
        self._guard_at = -math.inf  # wall time of the last guard action

    def _start_worker(self, started: PlanWorker | None = None) -> PlanWorker:
        """The planner process, warmed up on the whole route: ``started`` (a process already running) or a new one.
        A vehicle that holds on circles is also warmed with the wider margin its routes from a hold keep: that is
        another roadmap (its clearance is part of the graph), and building it at the first held plan made that plan
        0.07 s slower on an idle core, 0.1 s under load on SITL."""
        if self._worker is None:
            settings = replan_settings(self.scenario.planner, self.cfg)
            self._worker = started if started is not None else PlanWorker()
            for margin in (0.0, RESUME_MARGIN_M) if self.link.profile.hold_circles else (0.0,):
                self._worker.warm(replan_problem(self.scenario, self.route.points[0], self.route.goal,
                                                 self.scenario.environment.threats, 0.0, static_margin=margin),
                                  settings)
        return self._worker

    # -- picture ------------------------------------------------------------------------------------
    @property
    def goal_seq(self) -> int:
        return self.route.goal_seq

    async def ready(self) -> None:
        """Wait until the planner is warm (call before the flight starts: a replan made while the planner
        process is still starting takes seconds instead of its budget)."""
        if self._worker is None:
            return
        waited = await self._worker.ready()
        self.events.log("planner_ready", waited_s=round(waited, 3))

    def mission_started(self, wall: float) -> None:
        """Call when MISSION_START was accepted (at ``wall``, monotonic s): mission time (the scripted
        threats' clock) starts there."""
        self._mission_wall = wall

    @property
    def mission_t0(self) -> float | None:
        """Vehicle time of the mission start (None before it, or before any telemetry)."""
        if self._mission_t0 is None and self._mission_wall is not None and self.clock.synced:
            self._mission_t0 = self.clock.now(self._mission_wall)
        return self._mission_t0

    def now(self) -> float:
        """Mission time (vehicle s since the mission start; vehicle time before it)."""
        return self.clock.now(time.monotonic()) - (self.mission_t0 or 0.0)

    def near_goal(self) -> bool:
        """Whether the last position is near the goal: a completion report from before a swap (different
        numbering) must not end the flight."""
        if self.position is None:
            return True
        return float(np.linalg.norm(self.position - self.route.goal)) < max(
            5 * self.scenario.vehicle.acceptance_radius, 150.0)

    def observe(self, msg: Message) -> None:
        kind = msg.get_type()
        if kind in ("GLOBAL_POSITION_INT", "MISSION_CURRENT"):
            self._seen[kind] = time.monotonic()
        if kind == "GLOBAL_POSITION_INT":
            self.clock.observe(msg.time_boot_ms, time.monotonic())
            p = geodetic_to_enu(msg.lat / 1e7, msg.lon / 1e7, self.scenario.home.alt + msg.relative_alt / 1000,
                                self.scenario.home)
            self.position = np.array([p[0], p[1], msg.relative_alt / 1000.0])
            self.groundspeed = math.hypot(msg.vx, msg.vy) / 100.0
            self.velocity = np.array([msg.vy / 100.0, msg.vx / 100.0])  # NED north/east → ENU east/north
            self._track_pace(self.groundspeed, msg.time_boot_ms / 1000.0)
        elif kind == "HEARTBEAT":
            self.custom_mode = int(msg.custom_mode)
        elif kind == "ADSB_VEHICLE" and self.mission_t0 is not None:
            if self.tracks.update(msg, self.now()) is not None and msg.ICAO_address not in self._announced:
                self._announced.add(msg.ICAO_address)
                self.events.log("track", id=f"adsb-{msg.ICAO_address:06x}", callsign=str(msg.callsign))
        elif kind == "MISSION_CURRENT":
            self.current_seq = int(msg.seq)
        elif kind == "MISSION_ITEM_REACHED":
            self.current_seq = max(self.current_seq, int(msg.seq) + 1)

    def threats(self, now: float) -> Threats:
        """Scripted threats (mission-time laws) and live ADS-B tracks."""
        for tid in self.tracks.expire(now, self.cfg.track_max_age_s):
            self.events.log("track_expired", id=tid)
        return self.tracks.threats(now, self.cfg.track_radius_m, self.cfg.track_growth_m_s,
                                   self.scenario.environment.threats)

    @property
    def speed(self) -> float:
        """Speed for ETAs along the route: the vehicle's own pace over the ground while it flies the route in
        AUTO (:meth:`_track_pace`), the commanded cruise speed until that is known. ArduPlane SITL asked for
        18 m/s airspeed flies 19.2 m/s over the ground: predicted at cruise speed, a conflict 20 s ahead
        was 25 m out, more than the margin (measured on crossing_traffic)."""
        return self.pace if self.pace is not None else self.scenario.vehicle.cruise_speed

    def _track_pace(self, groundspeed: float, t_vehicle: float) -> None:
        """Smooth the ground speed over :data:`PACE_TAU_S`, starting from cruise, while flying the route in AUTO
        (not in a hold or the climb-out); each sample kept within ±30 % of cruise."""
        cruise = self.scenario.vehicle.cruise_speed
        flying = self.holding is None and self.on_route() and (
            self.custom_mode is None or self.custom_mode == self._number("AUTO"))
        last, self._pace_t = self._pace_t, t_vehicle
        if not flying or last is None or t_vehicle <= last:
            return
        v = float(np.clip(groundspeed, 0.7 * cruise, 1.3 * cruise))
        keep = math.exp(-(t_vehicle - last) / PACE_TAU_S)
        # from cruise, not from the first sample: a plane joining its route is still levelling off and turning,
        # and a jump of the pace would move every predicted conflict (1 m/s over 30 s: 30 m) at once
        self.pace = keep * (cruise if self.pace is None else self.pace) + (1.0 - keep) * v

    def _number(self, name: str) -> int:
        return self.link.profile.mode_number(name)

    def _name(self, custom_mode: int) -> str:
        return self.link.profile.mode_name(custom_mode)

    @property
    def hold_mode(self) -> str:
        return self.link.profile.hold_mode

    @property
    def loiter_radius(self) -> float:
        """The radius a plane's hold circles at: the vehicle's WP_LOITER_RAD when read, else the config's."""
        if self.hold_pattern is not None and self.hold_pattern.kind == "circle":
            return self.hold_pattern.radius
        return self.limits.loiter_radius if self.limits is not None else self.cfg.plane_loiter_radius_m

    def in_control(self) -> bool:
        """The vehicle flies our mission in AUTO, or holds in the mode we put it in. Any other mode (the pilot
        took over, a failsafe's RTL) belongs to someone else: the replanner then only watches."""
        if self.custom_mode is None:
            return True
        ours = self._number(self.held_in or self.hold_mode) if self.holding is not None else self._number("AUTO")
        mine = self.custom_mode == ours
        if not mine and self._paused_in != self.custom_mode:
            self._paused_in = self.custom_mode
            self.events.log("replanning_paused", mode=self._name(self.custom_mode))
        elif mine and self._paused_in is not None:
            self._paused_in = None
            self.events.log("replanning_resumed")
        return mine

    def link_lost(self) -> None:
        """The supervisor found the link lost: positions are stale and nothing can be uploaded, so stop
        predicting until :meth:`link_restored` (the vehicle flies, or holds on, its verified mission)."""
        if not self._link_down:
            self._link_down = True
            self.events.log("replanning_paused", reason="link lost", decision=(
                "the vehicle holds" if self.holding is not None else "the vehicle flies its verified mission"))

    def link_restored(self) -> None:
        """The link is back and the supervisor has re-synced the mission: predict again from fresh telemetry."""
        if self._link_down:
            self._link_down = False
            self._fresh_since = time.monotonic()  # position and active item are from before the outage
            self.events.log("replanning_resumed", reason="link restored, mission re-synced")

    def remaining(self) -> tuple[np.ndarray, np.ndarray]:
        assert self.position is not None
        return self.route.remaining(self.position, max(self.current_seq, int(self.route.seqs[0])))

    def predict(self, now: float, threats: Threats) -> list[Conflict]:
        """Conflicts on the remaining route, flown from now; for a held vehicle, flown from any moment it may
        be back on it after resuming (:meth:`rejoin_delays`): the earliest conflict of all."""
        route, _ = self.remaining()
        c = self.cfg
        found = [predict_conflicts(route, self.speed, 0.0, now + d, threats, c.horizon_s,
                                   self.scenario.hazard.d_coll, c.margin_m, c.sample_dt_s)
                 for d in self.rejoin_delays()]
        return sorted((x for f in found for x in f), key=lambda x: x.t)

    def rejoin_delays(self) -> np.ndarray:
        """Vehicle seconds a vehicle resumed now may take to be flying its route again: none when it is not
        held or stops dead (a copter in BRAKE); for a plane circling in LOITER, anything up to one circle,
        which is why a hold that merely delays a plane by a few seconds must not look like a cleared threat."""
        if self.holding is None or not self.link.profile.hold_circles:
            return np.zeros(1)
        circle = 2.0 * math.pi * self.loiter_radius / self.speed
        held = self.now() - self._held_since if self._held_since is not None else circle
        # having turned away for ``held`` seconds it needs about as long to turn back; never more than a circle
        longest = min(circle, 2.0 * held + self.cfg.rejoin_step_s)
        return np.arange(0.0, longest + self.cfg.rejoin_step_s, self.cfg.rejoin_step_s)

    def on_route(self) -> bool:
        """Flying the route (past the takeoff and the speed item): the start waypoint or later."""
        return self.current_seq >= int(self.route.seqs[0]) and self.current_seq <= self.goal_seq

    # -- task ---------------------------------------------------------------------------------------
    async def run(self) -> None:
        """Watch until cancelled; raises :class:`VehicleHolding` when no verified mission can be made live."""
        with watch(self.link) as sub:
            self._sub = sub
            while True:
                try:
                    self.observe(await sub.get(self.cfg.check_interval_wall_s))
                except TimeoutError:
                    pass
                for msg in sub.drain():
                    self.observe(msg)
                wall = time.monotonic()
                if wall - self._last_check < self.cfg.check_interval_wall_s or self.position is None \
                        or self.mission_t0 is None:
                    continue
                self._last_check = wall
                await self.step()

    async def aclose(self) -> None:
        """Stop the planner process (waits for a plan in progress to end, at most its budget)."""
        if self._worker is not None:
            await asyncio.to_thread(self._worker.close)

    async def __aenter__(self) -> LiveReplanner:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def _pump(self) -> None:
        for msg in self._sub.drain() if self._sub is not None else ():
            self.observe(msg)

    async def step(self) -> None:
        """One look at the picture: replan on a conflict, or, while holding, retry or resume."""
        if self._link_down or min(self._seen.values()) < self._fresh_since:
            return
        now = self.now()
        threats = self.threats(now)
        self._log_contacts(now, threats)
        if not self.in_control():
            return
        if self.holding is None and await self._guard(now):
            return
        if self.holding is not None:
            await self._recheck_hold(now, threats)
            if self._exit is not None:
                await self._leave_hold(now)
                return
            if now - self._last_replan >= self.cfg.hold_retry_s:
                await self._retry_from_hold(now, threats)
            return
        if not len(threats) or self.current_seq > self.goal_seq:
            return
        conflicts = self.predict(now, threats)
        if not conflicts:
            self._failed_plans = 0
            return
        if now - self._last_replan < self.cfg.min_interval_s:
            return
        await self.replan(conflicts[0], now, threats)

    async def _guard(self, now: float) -> bool:
        """The flown-safety guard: predict the vehicle's own path (:func:`predict_own_path`) and, if it will come
        within d_coll of a static obstacle, hold it on a checked pattern before it gets there (a static route from
        where it is is then planned by the retries from the hold). True when it acted."""
        if not self.guard_enabled or self.position is None or not self.on_route() \
                or self.position[2] < GUARD_MIN_ALT_M or time.monotonic() - self._guard_at < GUARD_REPEAT_WALL_S:
            return False
        route, seqs = self.remaining()
        radius = self._turn_radius() if self.link.profile.hold_circles else 0.0
        before = np.flatnonzero(self.route.seqs < seqs[1]) if len(seqs) > 1 else np.zeros(0, dtype=int)
        origin = self.route.points[before[-1]] if before.size else self.position
        path = predict_own_path(self.position, self.velocity, origin, route[1:], radius,
                                self.scenario.vehicle.acceptance_radius)
        breach = first_breach(path, self.scenario.environment, GUARD_SHARE_OF_D_COLL * self.scenario.hazard.d_coll)
        if breach is None:
            return False
        self._guard_at = time.monotonic()
        self.events.log("guard", obstacle=breach.obstacle, clearance_m=round(breach.clearance_m, 1),
                        in_s=round(breach.in_s, 1), at=[round(c, 1) for c in breach.point])
        await self.hold(f"flown-safety guard: predicted {breach.clearance_m:.0f} m from {breach.obstacle} in "
                        f"{breach.in_s:.1f} s (d_coll {self.scenario.hazard.d_coll:g} m)")
        if self.holding is not None:
            self._last_replan = -math.inf  # plan from the hold at once
        return True

    def _log_contacts(self, now: float, threats: Threats) -> None:
        """A ``contacts`` record (every threat, where it is and where it is predicted to go), at most every
        :data:`CONTACTS_EVERY_S` wall seconds: the status page's picture of the traffic."""
        wall = time.monotonic()
        if wall - self._contacts_at < CONTACTS_EVERY_S:
            return
        self._contacts_at = wall
        self.events.log("contacts", t_mission=round(now, 2),
                        contacts=picture.contacts(threats, now, min(self.cfg.horizon_s, CONTACT_PATH_S)))

    # -- replanning ---------------------------------------------------------------------------------
    async def replan(self, conflict: Conflict, now: float, threats: Threats, lead_m: float | None = None) -> bool:
        """Plan from a commit point and make the result the live mission; True when it is."""
        t_detect = time.monotonic()
        self._last_replan = now
        cfg = self.cfg
        rec = ReplanRecord(len(self.records) + 1, "conflict" if self.holding is None else "retry while holding",
                           conflict.threat_id, round(now, 2), round(conflict.t - now, 2),
                           round(conflict.separation, 2), held=self.holding is not None)
        self.records.append(rec)
        self.events.log("conflict", n=rec.n, threat=rec.threat, in_s=rec.conflict_in_s,
                        separation_m=rec.sep_before_m, d_coll_m=self.scenario.hazard.d_coll)
        route, seqs = self.remaining()
        budget = self._budget(conflict, now)
        if lead_m is None:
            lead_m = self._commit_lead_m(conflict, now, budget)
        current = max(self.current_seq, int(self.route.seqs[0]))
        departing = not self.on_route()
        if departing:  # still climbing out: the new route starts at the planned start, which stays as it is
            start = self.route.points[0]
            cp = CommitPoint(start.copy(), 0.0, now + float(np.linalg.norm(start - route[0])) / self.speed,
                             int(self.route.seqs[0]) + 1, self.route.points.copy())
        else:
            cp = commit_point(route, seqs, current, lead_m, self.speed, now)
        # held (planned from the hold's retries, at the vehicle: lead 0) on a circle: the route starts where the
        # plane leaves it, flying its tangent
        exit_ = self._hold_exit(budget) if self.holding is not None and not departing else None
        self._planning_exit = None
        if exit_ is not None:
            cp = CommitPoint(exit_.point.copy(), 0.0, now + exit_.arc_m / self.flying_speed, cp.first_new_seq,
                             np.vstack([exit_.point, cp.old_tail[1:]]), exit_.heading)
            self._planning_exit = Leaving(exit_, cp.t)
        env = self.scenario.environment  # the vehicle's own height may sit a hair outside the band
        ground = float(env.ground(cp.point[0], cp.point[1]))
        cp.point[2] = cp.old_tail[0, 2] = np.clip(cp.point[2], ground + env.z_min + BAND_INSET_M,
                                                  ground + env.z_max - BAND_INSET_M)
        rec.commit = [round(float(v), 1) for v in cp.point]
        rec.old_route = cp.old_tail.round(1).tolist()
        # the way the vehicle will fly through the commit point (along the old route; held: its own track), so the
        # new route cannot begin with a turn it cannot fly (a hairpin there carried SITL's plane 29-38 m into a
        # cylinder); now that holds are checked, a plan that fails for it holds safely (docs/design.md)
        # held on a circle, the route is planned with the margin its resume will be checked with (leg_blocked):
        # planned with d_coll alone, every route from one circle was refused on resuming, for 197 replans
        resumed = RESUME_MARGIN_M if self.holding is not None and self.link.profile.hold_circles else 0.0
        problem = replan_problem(self.scenario, cp.point, self.route.goal, threats, cp.t, self.speed,
                                 heading=self._start_heading(cp), threat_margin=cfg.margin_m, static_margin=resumed)
        settings = replan_settings(self.scenario.planner, cfg)
        rec.budget_s = budget
        t0 = time.monotonic()
        seeds = warm_starts(cp.old_tail, cfg.detour_offsets_m, settings.pso.n_waypoints + 2)
        # a plan that overruns (a loaded machine, a planner process still starting) must not let the vehicle fly
        # on into the rewritten items and the conflict while it waits: the swap's guard applies already
        worker = self._start_worker()
        plan = asyncio.create_task(worker.plan(problem, settings, [self.seed, rec.n], seeds, budget),
                                   name="replan-plan")
        await self._guarded(plan, cp.first_new_seq, self._guard_threshold_s(),
                            "the plan is late: the vehicle could reach the commit point before it is ready", rec,
                            route_separation=rec.sep_before_m)
        job = plan.result()
        rec.plan_s = round(time.monotonic() - t0, 3)
        rec.plan_status = status = job.status
        self._pump()
        if not departing and self.current_seq > cp.first_new_seq + 1:
            # the plan took so long (a loaded machine) that the vehicle is past the commit point and its next
            # item: the new route would start behind it and its timing is gone. Plan again from here, now.
            rec.outcome = "stale: the vehicle passed the commit point while it was planned"
            self.events.log("replan_stale", n=rec.n, plan_s=rec.plan_s, first_new=cp.first_new_seq,
                            current=self.current_seq)
            self._last_replan = -math.inf
            return False
        new_route = job.waypoints.astype(float)
        after = route_separations(new_route, self.speed, 0.0, cp.t, threats, cfg.horizon_s, cfg.sample_dt_s)
        rec.sep_after_m = round(min((c.separation for c in after), default=math.inf), 2)
        rec.new_route = new_route.round(1).tolist()
        d_coll = self.scenario.hazard.d_coll
        # good: clear by the margin; else still used if it is safe and better than the route being flown
        safe = status in GOOD and (rec.sep_after_m >= d_coll + cfg.margin_m
                                   or rec.sep_after_m >= max(d_coll, conflict.separation))
        if not safe and job.violations and set(job.violations) <= {"turn"} and self.holding is None:
            # turns tighter than the vehicle's: what matters is the path it will fly through them (the
            # waypoints are its mission items), checked as flown against the obstacles and the traffic; only for
            # a vehicle flying its route towards the commit point (one that is held joins from elsewhere: on SITL
            # such a plan joined from a hold overshot its tight turn 22.8 m into a cylinder)
            flown = self._flown_separation(cp, new_route, threats)
            if flown is not None:
                safe = flown >= d_coll + cfg.margin_m or flown >= max(d_coll, conflict.separation)
                self.events.log("replan_flown_check", n=rec.n, separation_m=round(flown, 1), used=safe)
        self._failed_plans = 0 if safe else self._failed_plans + 1
        self.events.log("replan_planned", n=rec.n, status=rec.plan_status, budget_s=budget, plan_s=rec.plan_s,
                        separation_after_m=rec.sep_after_m, commit=rec.commit, waypoints=len(new_route),
                        violations=job.violations, old_route=rec.old_route, new_route=rec.new_route)
        if not safe and self.holding is None and conflict.separation >= d_coll:
            rec.outcome = "no better route: the current one (inside the margin, outside d_coll) is kept"
            self.events.log("replan_skipped", n=rec.n, reason=rec.outcome)
            return False
        if not safe:
            rec.outcome = "no safe plan: holding"
            await self.hold(f"no safe plan within {budget:g} s ({rec.plan_status}, predicted separation "
                            f"{rec.sep_after_m:.0f} m)")
            rec.held = True
            return False
        items = splice(self.route.items, cp.first_new_seq, new_route[1:] if departing else new_route,
                       self.goal_seq, self.spec,
                       length=len(self.verified[-1][1]) if self.client.writes_in_part else None)
        t_up = time.monotonic()
        live = await self.swap(items, cp.first_new_seq, rec)
        rec.upload_s = round(time.monotonic() - t_up, 3)
        if not live:
            rec.outcome = "verified but no longer clear: holding"
            self.events.log("replan_not_live", **rec.summary())
            return False
        rec.latency_s = round(time.monotonic() - t_detect, 3)
        rec.outcome = "new mission current"
        self.events.log("replanned", **rec.summary())
        return True

    def _flown_separation(self, cp: CommitPoint, route: np.ndarray, threats: Threats) -> float | None:
        """The least traffic separation along ``route`` as the vehicle will fly it from the commit point (every
        path of :meth:`_flown_paths` from its wide turn radius, to the route's end), or None when one of those
        paths comes within d_coll of a static obstacle."""
        heading = self._start_heading(cp)
        if heading is None:
            first = route[1] - route[0] if len(route) > 1 else np.array([0.0, 1.0, 0.0])
            heading = first / max(float(np.linalg.norm(first[:2])), 1e-6)
        radius = self._wide_turn_radius(self.speed) if self.link.profile.hold_circles else self._turn_radius()
        length = float(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())
        worst = math.inf
        for path in self._flown_paths(route[0], heading[:2] * self.speed, route[0], route[1:], radius,
                                      min(length / self.speed + 10.0, self.cfg.horizon_s), dt=FLOWN_CHECK_DT_S):
            if first_breach(path, self.scenario.environment, self.scenario.hazard.d_coll) is not None:
                return None
            seps = route_separations(path[:, 1:4], self.speed, 0.0, cp.t, threats, self.cfg.horizon_s,
                                     self.cfg.sample_dt_s)
            worst = min([worst, *(c.separation for c in seps)])
        return worst

    def _flown_paths(self, position: np.ndarray, velocity: np.ndarray, origin: np.ndarray, targets: np.ndarray,
                     radius: float, horizon_s: float, dt: float = GUARD_DT_S, direct: bool = False,
                     behind: bool = False) -> Iterator[np.ndarray]:
        """The paths the vehicle may fly along ``targets`` (:func:`predict_own_path`), one at a time (a check that
        finds a breach stops predicting). A plane's path-follower is not modelled closely enough for one: it may
        turn as wide as ``radius`` or WIDE_TURNS times it, take each item at its acceptance radius or as early as
        ArduPlane switches, and (``behind``: its item behind it) turn round either way. A copter (no circles) has
        one."""
        accept = self.scenario.vehicle.acceptance_radius
        plane = self.link.profile.hold_circles
        radii = (radius, WIDE_TURNS * radius) if plane else (radius,)
        accepts = tuple(dict.fromkeys((accept, self._switch_m()))) if plane else (accept,)
        senses = (-1, 1) if plane and behind else (0,)
        for r, a, sense in itertools.product(radii, accepts, senses):
            yield predict_own_path(position, velocity, origin, targets, r, a, horizon_s=horizon_s, dt=dt,
                                   direct=direct, sense=sense)

    @property
    def flying_speed(self) -> float:
        """The speed it flies turns and circles at: its ground speed, at least the cruise speed (a plane slowed
        by a climb, or a vehicle not yet up to speed, still turns as wide as at cruise)."""
        return max(self.groundspeed, self.scenario.vehicle.cruise_speed)

    def _turn_radius(self) -> float:
        """The vehicle's tightest turn at its ground speed (its roll limit when read, else the scenario's bank)."""
        bank = math.radians(self.limits.max_bank_deg if self.limits is not None else self.scenario.vehicle.max_bank_deg)
        return self.flying_speed ** 2 / (G0 * math.tan(bank))

    def _wide_turn_radius(self, speed: float) -> float:
        """How wide a plane's path-follower turns onto a track far off its heading (AutopilotLimits.wide_turn_radius;
        twice the tightest turn without read limits), never less than the tightest turn."""
        wide = self.limits.wide_turn_radius(speed) if self.limits is not None else 2.0 * self._turn_radius()
        return max(wide, self._turn_radius())

    def _start_heading(self, cp: CommitPoint) -> np.ndarray | None:
        """Unit (3,) direction the vehicle flies through the commit point: the old route's there, or its own
        velocity when the commit point is where it is (a replan from a hold); None while climbing out (a copter's
        too: it turns on the spot)."""
        if not self.link.profile.hold_circles:
            return None
        if float(np.linalg.norm(cp.point[:2] - (self.position[:2] if self.position is not None else cp.point[:2]))) \
                < 1.0 and float(np.linalg.norm(self.velocity)) > 1.0:
            v = np.array([*self.velocity, 0.0])
        elif cp.heading is not None:
            v = np.array(cp.heading, dtype=float)
            v[2] = 0.0
        else:
            return None
        n = float(np.linalg.norm(v))
        return v / n if n > 1e-6 else None

    async def _guarded(self, task: asyncio.Task, first_new_seq: int, threshold_s: float, reason: str,
                       rec: ReplanRecord, route_separation: float | None = None) -> None:
        """Wait for ``task`` (a plan or an upload) watching the vehicle meanwhile: hold it, saying ``reason``,
        once it could step into item ``first_new_seq`` or a later one within ``threshold_s`` of vehicle time
        while the task still runs (``route_separation``: see :meth:`hold`). On any exception (a cancel included)
        the task is cancelled first."""
        try:
            while not task.done():
                await asyncio.wait({task}, timeout=0.01)
                self._pump()
                if self.holding is None and not task.done() and \
                        self._eta_leave_prefix(first_new_seq) < threshold_s:
                    await self.hold(reason, route_separation)
                    rec.held = rec.held or self.holding is not None
        except BaseException:
            task.cancel()
            await asyncio.gather(task, return_exceptions=True)
            raise

    async def swap(self, items: list[MissionItem], first_new_seq: int, rec: ReplanRecord) -> bool:
        """Upload ``items`` while flying and make them the live mission (see the module docstring); False
        when they were verified but are no longer safe to join (the vehicle is then held)."""
        cfg = self.cfg
        self._pump()
        if self.holding is None and not self.link.profile.flies_copy_during_upload:
            await self.hold("the vehicle would re-read its items from storage during the upload")
            rec.held = True
        elif self.holding is None and self._eta_leave_prefix(first_new_seq) < self._guard_threshold_s():
            await self.hold("the vehicle could finish its active item before the new mission is verified")
            rec.held = True
        for attempt in range(1, cfg.upload_attempts + 1):
            t0 = time.monotonic()
            # only what changed where the autopilot takes a partial write (ArduPilot), else the whole mission
            upload = asyncio.create_task(self.client.upload_changed_verified(items, self.verified[-1][1]),
                                         name="replan-upload")
            try:
                await self._guarded(upload, first_new_seq, cfg.guard_s,
                                    "upload not verified yet and the vehicle is about to leave its item", rec)
            except asyncio.CancelledError:
                # cancelled mid-upload (flight ended, Ctrl-C): the stored mission may be mixed, so hold first
                if self.holding is None:
                    await asyncio.shield(self.hold("cancelled during an upload: the stored mission may be mixed"))
                raise
            try:
                rec.upload_path = upload.result()
            except (CompanionError, TimeoutError) as e:
                self.events.log("replan_upload_failed", n=rec.n, attempt=attempt, error=str(e))
                if self.holding is None:  # the stored mission may now be part old, part new
                    await self.hold("upload failed: the stored mission may be mixed")
                    rec.held = True
                refused = isinstance(e, MissionUploadError) and e.refused
                if refused or attempt == cfg.upload_attempts:
                    # a refusal will likely come again: first put the last verified mission back, so that what
                    # is stored is verified while the vehicle holds and whatever happens next
                    restored, left_with = await restore_mission(self.client, self.events, self.verified[-1][1])
                    if restored:
                        self.verified.append((time.monotonic(), list(self.verified[-1][1])))
                    if attempt == cfg.upload_attempts:
                        raise VehicleHolding(f"replan {rec.n}: no verified upload after {attempt} attempts ({e}); "
                                             f"{left_with}; the vehicle is holding") from e
                continue
            self._upload_wall_s = 0.7 * self._upload_wall_s + 0.3 * (time.monotonic() - t0)
            break
        self.route = MissionRoute.of(items, self.scenario.home)
        self.verified.append((time.monotonic(), list(items)))
        self.events.log("replan_verified", n=rec.n, items=len(items), first_new=first_new_seq)
        self.events.log("mission", **picture.mission(items, self.scenario.home))
        self._pump()
        leaving, self._planning_exit = self._planning_exit, None
        if self.holding is not None and leaving is not None:
            # the route starts at the hold circle's exit: the plane circles on to it, and is resumed there towards
            # the item after it once the join is checked again from where it is then (_leave_hold)
            leaving.seq = min(first_new_seq + 1, self.goal_seq)
            await self.set_current(leaving.seq)
            self._exit = leaving
            self.events.log("hold_exit", n=rec.n, seq=leaving.seq, at=[round(float(v), 1) for v in leaving.exit.point],
                            in_m=round(leaving.exit.arc_m, 1))
            return True
        target = self.current_seq
        replaced = self.current_seq >= first_new_seq
        if replaced:  # its active item was replaced: join the new route
            target = self._join_seq(first_new_seq)
        if self.holding is not None:  # a held plane has circled on: never turn it back for an item behind it
            target = self.ahead_seq(target)
        if not self._clear_from(target):
            reason = "no safe plan: the new route is no longer clear from where the vehicle is"
            await self.hold(reason)
            # retried from here like any plan that is not safe; a hold refused leaves the vehicle flying on, and its
            # conflicts are predicted again
            if self.holding is not None:
                self.holding = reason
            rec.held = True
            if target != self.current_seq:
                await self.set_current(target)
            return False
        if self.holding is not None and (blocked := self.leg_blocked(target)) is not None:
            # held off the route: the straight leg back to the join crosses an obstacle; keep holding on the
            # checked pattern and plan again from where the vehicle is
            self.events.log("resume_blocked", seq=target, obstacle=blocked[1], clearance_m=round(blocked[0], 1))
            if target != self.current_seq:
                await self.set_current(target)
            rec.held = True
            return False
        resume = self.resume if self.holding is not None else None
        if target != self.current_seq or (replaced and self.holding is None):
            # ArduPlane keeps flying its own copy of a replaced active item until that item is restarted (on the
            # simulator at 5x under load, towards the old item 12 through the intruder: -8.2 m); a held vehicle
            # restarts it on re-entering AUTO
            await self.set_current(target, then=resume)
        elif resume is not None:
            await resume()
        return True

    def _guard_threshold_s(self) -> float:
        """Vehicle seconds before leaving its unchanged items below which a swap holds the vehicle first."""
        return self.cfg.guard_s + 2.0 * self._upload_wall_s * self.clock.rate

    def _switch_m(self) -> float:
        """How far before a waypoint the vehicle may count it reached (ArduPlane switches early)."""
        return max(self.scenario.vehicle.acceptance_radius, self.link.profile.early_switch_m)

    def _budget(self, conflict: Conflict, now: float) -> float:
        """Wall seconds for this plan: the configured budget, doubled for each plan in a row that was not safe (a
        loaded machine gives the planner less of a core: under a CPU hog at 5x the simulated plane flew into an
        intruder after two 0.15 s plans timed out), up to ``max_budget_s`` and only while the commit lead it needs
        still fits in the first half of the way to the conflict. A vehicle that holds has checked time: the
        longest budget at once (under load, in ``fuseplan demo``, every 0.15 s plan from a hold with the resume's
        margin timed out and the plane held until the intruder had passed)."""
        cfg = self.cfg
        if self.holding is not None:
            return max(cfg.max_budget_s, cfg.budget_s)
        budget = min(cfg.budget_s * 2.0 ** self._failed_plans, max(cfg.max_budget_s, cfg.budget_s))
        room = self._room_m(conflict, now)
        while budget > cfg.budget_s and self._short_lead_m(budget) > room:
            budget = max(budget / 2.0, cfg.budget_s)
        return budget

    def _short_lead_m(self, budget_s: float) -> float:
        """The commit lead that covers planning within ``budget_s``, the upload and the lead margin alone."""
        cfg = self.cfg
        plan_s = (budget_s + cfg.check_interval_wall_s) * self.clock.rate
        return (plan_s + self._upload_wall_s * self.clock.rate + cfg.lead_margin_s) * self.speed

    def _room_m(self, conflict: Conflict, now: float) -> float:
        """The first half of the way to the conflict: what a commit lead may take (the rest is the detour's)."""
        return (conflict.t - now) * self.speed * 0.5

    def _commit_lead_m(self, conflict: Conflict, now: float, budget_s: float) -> float:
        """How far ahead of the vehicle the new route starts. Far enough that the vehicle, flying on while the
        plan is made, cannot reach the first new item before the upload is verified: the swap's guard then
        has no reason to hold it. A plane held in LOITER for a guard turns off its route for seconds (at SITL's
        speed-up, for every wall second of upload, ten), which spoils the timing the new route was planned for
        and starts the next conflict; so the lead covers the guard's own threshold and the early waypoint
        switching it counts. Shortened to the planning-and-upload time alone when the conflict is too close
        for that (the guard then holds if it must)."""
        cfg = self.cfg
        plan_s = (budget_s + cfg.check_interval_wall_s) * self.clock.rate
        full = (plan_s + self._guard_threshold_s() + cfg.lead_margin_s) * self.speed + self._switch_m()
        short = self._short_lead_m(budget_s)
        return full if full <= self._room_m(conflict, now) else short

    def _join_seq(self, first_new_seq: int) -> int:
        """The commit point's item, or the next one if the vehicle is already past the commit point (it
        would otherwise turn back for it)."""
        seqs, pts = self.route.seqs, self.route.points
        k = int(np.flatnonzero(seqs == first_new_seq)[0])
        if self.position is None or k + 1 >= len(seqs):
            return first_new_seq
        ahead = pts[k + 1] - pts[k]
        passed = float(np.dot(self.position - pts[k], ahead)) > self.scenario.vehicle.acceptance_radius * \
            float(np.linalg.norm(ahead))
        if passed:
            self.events.log("commit_point_passed", joining=int(seqs[k + 1]))
            return int(seqs[k + 1])
        return first_new_seq

    def _clear_from(self, seq: int, delays: np.ndarray | None = None) -> bool:
        """Whether the mission from item ``seq`` on, flown from where the vehicle is now (and, if it is held,
        from whenever it may be back on it: :meth:`rejoin_delays`, or ``delays`` vehicle seconds), keeps every
        threat at d_coll or more (the plan was checked from the commit point at its ETA; this checks the join)."""
        if self.position is None:
            return True
        now = self.now()
        route, _ = self.route.remaining(self.position, max(seq, int(self.route.seqs[0])))
        threats = self.threats(now)
        seps = [c for d in (self.rejoin_delays() if delays is None else delays) for c in route_separations(
            route, self.speed, 0.0, now + d, threats, self.cfg.horizon_s, self.cfg.sample_dt_s)]
        worst = min(seps, key=lambda c: c.separation, default=None)
        if worst is not None:
            self.events.log("join_check", seq=seq, threat=worst.threat_id, separation_m=round(worst.separation, 1),
                            in_s=round(worst.t - now, 1))
        return worst is None or worst.separation >= self.scenario.hazard.d_coll

    async def set_current(self, seq: int, then: Callable[[], Awaitable[None]] | None = None) -> None:
        """DO_SET_MISSION_CURRENT and wait until MISSION_CURRENT shows it (the vehicle took it). ``then`` (a held
        vehicle's resume) runs as soon as the command is acknowledged, while that confirmation is on its way: it
        comes with the autopilot's next status message, a loop or more later (ArduPlane SITL at 10x: 10-20 ms)."""
        with self.link.subscribe("MISSION_CURRENT", predicate=lambda m: m.seq == seq) as sub:
            await self.client.set_current(seq)
            if then is not None:
                self.current_seq = seq
                await then()
            try:
                await sub.get(2.0)
            except TimeoutError:
                raise CommandError(0, None, f"MISSION_CURRENT did not confirm item {seq}") from None
        self.current_seq = seq
        self.events.log("set_current", seq=seq)

    def _eta_leave_prefix(self, first_new_seq: int) -> float:
        """Vehicle seconds until it could step into an item at or after ``first_new_seq`` (being rewritten):
        when it completes item ``first_new_seq − 1``, or its active item if that is already being replaced.
        Pessimistic: the faster of cruise and ground speed, and ArduPlane's early waypoint switching."""
        if self.position is None:
            return math.inf
        route, seqs = self.remaining()
        target = max(self.current_seq, first_new_seq - 1)
        hit = np.flatnonzero(seqs >= target)
        if not hit.size:
            return math.inf
        legs = np.linalg.norm(np.diff(route[:hit[0] + 1], axis=0), axis=1)
        return max(float(legs.sum()) - self._switch_m(), 0.0) / max(self.speed, self.groundspeed, 1.0)

    def note_upload(self, seconds: float) -> None:
        """The initial mission's verified upload took ``seconds`` (wall): the first guess for a replan's."""
        self._upload_wall_s = max(self._upload_wall_s, float(seconds))

    # -- holding ------------------------------------------------------------------------------------
    async def _mode(self, name: str) -> None:
        custom = self._number(name)
        await self.client.command_long(mavlink.MAV_CMD_DO_SET_MODE, *self.link.profile.set_mode_params(custom))
        self.custom_mode = custom  # accepted; the next HEARTBEAT will say so too

    async def hold(self, reason: str, route_separation: float | None = None) -> None:
        """Stop the vehicle advancing through its mission where it is (its profile's ``hold_mode``).
        ``route_separation``: what the route it flies keeps from the traffic (m, predicted; a plan that is only
        late): a circle keeping the traffic less far than that, and the route keeping d_coll, is no hold (on SITL,
        a plan 4 s from an intruder the route passed at 23.9 m: the circle predicted at 22.8 m was flown at 5.0 m)."""
        if self.holding is not None:
            return
        if self.custom_mode is not None and self.custom_mode != self._number("AUTO"):
            # not flying the mission (a failsafe, the pilot): it cannot step into a mixed item; leave it be
            self.events.log("not_holding", reason=reason, mode=self._name(self.custom_mode))
            return
        if time.monotonic() - self._hold_refused_at < HOLD_CHECK_WALL_S or (
                route_separation is not None and time.monotonic() - self._route_kept_at < HOLD_CHECK_WALL_S):
            return  # just refused: checking again takes the CPU the planner needs (under load, 30 checks a second)
        pattern = self._checked_hold()
        if pattern is not None and route_separation is not None \
                and route_separation >= self.scenario.hazard.d_coll \
                and pattern.traffic_separation_m < route_separation:
            # only holds for a late plan wait for the next look: a swap's or the guard's hold is taken
            self._route_kept_at = time.monotonic()
            self.events.log("hold_refused", reason=reason, decision=(
                f"the route keeps the traffic further ({route_separation:.1f} m) than the best hold "
                f"({pattern.traffic_separation_m:.1f} m): the vehicle keeps flying it"))
            return
        if pattern is None:
            # no circle clear of the obstacles and the traffic: the leg it flies was cleared when it was planned
            self._hold_refused_at = time.monotonic()
            self.events.log("hold_refused", reason=reason, decision="no checked hold pattern: the vehicle keeps "
                            "flying its current, already-cleared leg")
            return
        if pattern.kind == "circle" and self.link.profile.hold_reposition:
            try:
                await self._circle(pattern)
                self.held_in = "GUIDED"
            except (CommandError, AttributeError) as e:  # refused, or a backend without COMMAND_INT
                self.events.log("hold_circle_refused", error=str(e), pattern=pattern.summary())
                loiter = self._loiter_here()
                if loiter is None:
                    self.events.log("hold_refused", reason=reason, decision="LOITER's own circle is not clear "
                                    "either: the vehicle keeps flying its current, already-cleared leg")
                    return
                pattern = loiter
                await self._mode(self.hold_mode)
                self.held_in = self.hold_mode
        else:
            await self._mode(self.hold_mode)
            self.held_in = self.hold_mode
        self.hold_pattern = pattern
        self.holding = reason
        self._held_since = self.now()
        self.events.log("hold", mode=self.held_in, reason=reason, pattern=pattern.summary())

    async def _recheck_hold(self, now: float, threats: Threats) -> None:
        """While circling a hold of ours: the traffic is checked against the circle again (at most every
        :data:`HOLD_CHECK_WALL_S` wall seconds); a circle that no longer keeps it at d_coll is replaced by a
        checked one that keeps it further (the traffic's prediction changes as it flies)."""
        pattern = self.hold_pattern
        if (pattern is None or pattern.kind != "circle" or self.held_in != "GUIDED" or not len(threats)
                or self.position is None or time.monotonic() - self._hold_checked_at < HOLD_CHECK_WALL_S):
            return
        self._hold_checked_at = time.monotonic()
        d_coll = self.scenario.hazard.d_coll
        sep = circle_traffic_separation(self.position, pattern.centre, pattern.radius, pattern.clockwise,
                                        self.flying_speed, now, threats)
        if sep >= d_coll:
            return
        new = self._checked_hold()
        if new is None or new.kind != "circle" or new.traffic_separation_m <= sep:
            self.events.log("hold_unclear", separation_m=round(sep, 1), pattern=pattern.summary(),
                            note="no other checked circle keeps the traffic further")
            return
        try:
            await self._circle(new)
        except (CommandError, AttributeError) as e:
            self.events.log("hold_circle_refused", error=str(e), pattern=new.summary())
            return
        self.hold_pattern = new
        self._exit = None  # on another circle: planned again from it
        self.events.log("hold_moved", separation_m=round(sep, 1), pattern=new.summary())

    def _checked_hold(self) -> HoldPattern | None:
        """The hold pattern for where the vehicle is now, checked against the static world and the traffic
        (:mod:`companion.replanning.holds`): a plane on ArduPilot circles a centre and radius of ours, a PX4 VTOL its
        own loiter around where it is (profile ``hold_reposition``); any other vehicle stops (its stopping run
        checked, and flown whatever the verdict: stopping is a copter's safest move). None: no circle is clear (or,
        for a circling vehicle, no position to check one from)."""
        profile = self.link.profile
        if profile.hold_circles:
            if self.position is None:
                return None
            if not profile.hold_reposition:  # PX4 VTOL: its own loiter around where it is
                return self._loiter_here()
            now = self.now()
            return plane_hold(self.position, self.velocity, self.loiter_radius, self.scenario.environment,
                              self.scenario.hazard.d_coll, self.flying_speed, self.threats(now), now,
                              min_radius=MIN_HOLD_RADIUS_TURNS * self._turn_radius(),
                              turn_radius=WIDE_TURNS * self._wide_turn_radius(self.flying_speed),
                              lag_m=HOLD_TURN_LAG_S * self.flying_speed)
        if self.position is None:
            return HoldPattern("brake", np.zeros(3), 0.0, True, np.zeros((1, 3)), math.inf, None, math.inf)
        d_coll = self.scenario.hazard.d_coll
        env = self.scenario.environment
        stop = self.limits.stopping_distance if self.limits is not None else \
            self.scenario.vehicle.cruise_speed ** 2 / 5.0
        speed_share = min(self.groundspeed / max(self.scenario.vehicle.cruise_speed, 0.1), 1.0) ** 2
        pattern = copter_hold(self.position, self.velocity, stop * speed_share, env, d_coll)
        if pattern.clearance_m < d_coll:
            self.events.log("hold_unclear", pattern=pattern.summary(),
                            note="the stopping run comes within d_coll; stopping is still the safest move")
        return pattern

    async def _circle(self, pattern: HoldPattern) -> None:
        """ArduPlane: MAV_CMD_DO_REPOSITION (COMMAND_INT: ArduPlane answers it UNSUPPORTED as COMMAND_LONG) with
        MAV_DO_REPOSITION_FLAGS_CHANGE_MODE (GUIDED) at the pattern's centre, altitude above home, and radius
        (param3), clockwise unless param4 is set."""
        lat, lon, _ = enu_to_geodetic(np.array([pattern.centre[0], pattern.centre[1], 0.0]), self.scenario.home)
        await self.client.command_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                      -1.0, 1.0, float(pattern.radius), 0.0 if pattern.clockwise else 1.0,
                                      x=to_int_e7(float(lat)), y=to_int_e7(float(lon)), z=float(pattern.centre[2]))
        self.custom_mode = self._number("GUIDED")

    def _loiter_here(self) -> HoldPattern | None:
        """The autopilot's own LOITER (a circle of the loiter radius around where the mode changes), when that
        circle is clear of the obstacles: the fallback when our circle cannot be commanded."""
        assert self.position is not None
        centre = self.position.copy()
        circle = np.vstack([ring(centre, self.loiter_radius, centre[2]),  # as asked, and as ArduPlane flies it
                            flown_ring(centre, self.loiter_radius, centre[2])])
        clearance, worst = nearest_obstacle(circle, self.scenario.environment)
        if clearance < self.scenario.hazard.d_coll + HOLD_MARGIN_M:
            return None
        return HoldPattern("circle", centre, self.loiter_radius, True, circle, clearance, worst, math.inf)

    def route_blocked(self, seq: int) -> tuple[float, str | None] | None:
        """(clearance, obstacle) when a leg of the mission from item ``seq`` on comes within d_coll of a static
        obstacle (a route that was never checked: an edited PLAN.json, a ground station's mission); else None."""
        ahead = self.route.points[self.route.seqs >= seq]
        if len(ahead) < 2:
            return None
        seg = np.diff(ahead, axis=0)
        n = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / 5.0).astype(int), 1)
        pts = np.vstack([a + np.outer(np.arange(k + 1) / k, s) for a, s, k in zip(ahead[:-1], seg, n, strict=True)])
        clearance, worst = nearest_obstacle(pts, self.scenario.environment)
        return None if clearance >= self.scenario.hazard.d_coll else (clearance, worst)

    def ahead_seq(self, seq: int) -> int:
        """The first route item from ``seq`` on that a plane can fly to from where it is: not passed along the
        route (beyond it along the leg k -> k+1), not behind it (against its velocity) and not within two wide
        turns plus a second of flight (what it cannot turn onto without a loop). Resumed towards such an item,
        ArduPlane loops back round through whatever is beside it: on SITL, after a hold beside item 5, 33 m into a
        cylinder. The goal is always kept. A copter keeps ``seq``."""
        if self.position is None or not self.link.profile.hold_circles:
            return seq
        seqs, pts = self.route.seqs, self.route.points
        p, v = self.position[:2], self.velocity
        near = 2.0 * self._wide_turn_radius(self.groundspeed) + max(self.groundspeed, 1.0) * JOIN_LATENCY_S
        moving = float(np.linalg.norm(v)) > 1.0
        target = seq
        for k in np.flatnonzero((seqs >= seq) & (seqs < self.goal_seq)):
            to = pts[k, :2] - p
            passed = k + 1 < len(seqs) and float(np.dot(p - pts[k, :2], pts[k + 1, :2] - pts[k, :2])) > 0
            behind = moving and float(np.dot(to, v)) <= 0.0
            if not (passed or behind or float(np.linalg.norm(to)) < near) or k + 1 >= len(seqs):
                break
            target = int(seqs[k + 1])
        if target != seq:
            self.events.log("join_ahead", behind=seq, joining=target)
        return target

    def leg_blocked(self, seq: int, margin_m: float = RESUME_MARGIN_M) -> tuple[float, str | None] | None:
        """(clearance, obstacle) when what AUTO flies on resuming at item ``seq`` comes too close to a static
        obstacle: the straight leg from the vehicle to the item, or the path a plane flies onto it and on
        (:func:`predict_own_path`, 20 s, straight at the item from where its turn ends, each turn it may make, each
        item taken as early as the autopilot may), within d_coll + ``margin_m``; None when both are clear."""
        if self.position is None:
            return None
        hit = np.flatnonzero(self.route.seqs >= seq)
        if not hit.size:
            return None
        target = self.route.points[hit[0]]
        leg = np.linspace(self.position, target, max(int(np.linalg.norm(target - self.position) / 5.0), 1) + 1)
        env, d_coll = self.scenario.environment, self.scenario.hazard.d_coll
        need = d_coll + margin_m
        clearance, worst = nearest_obstacle(leg, env)
        if clearance < need:
            return clearance, worst
        if self.link.profile.hold_circles and float(np.linalg.norm(self.velocity)) > 1.0:
            # AUTO flies to the item straight from wherever the plane ends its turn towards it (no leg to hold to),
            # so every path it may fly is checked (_flown_paths): resumed 101 m from its item, SITL's plane took it
            # early and cut to the next leg 6.5 m from a cylinder the path taking it at its 20 m cleared by 20.3 m
            wide = self._wide_turn_radius(self.groundspeed)
            for position, velocity in self._rolling_out():
                behind = float(np.dot(target[:2] - position[:2], velocity[:2])) < 0.0
                for path in self._flown_paths(position, velocity, position, self.route.points[hit[0]:],
                                              wide, RESUME_HORIZON_S, direct=True, behind=behind):
                    # by the margin too: the model starts wings level, and a plane resumed from a hold circle is
                    # banked (on the simulator, resumed 3 s into its circle, a path predicted clear came 6.3 m from a
                    # cylinder)
                    breach = first_breach(path, env, need)
                    if breach is not None:
                        return breach.clearance_m, breach.obstacle
        return None

    def _rolling_out(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Where a plane may start its turn back to the route from, with its velocity: where it is now, and, held on
        a circle, where it is after circling on for :data:`RESUME_ROLL_OUT_S` (the resume's latency and the roll
        out of the circle's bank; on the simulator flying ArduPlane's L1 law, a plane resumed at heading 340° from
        a counter-clockwise hold was still turning left at 316° when it rolled out, and its right turn back to the
        route, predicted 25-66 m clear of a cylinder from where the resume was checked, came 0.6 m from it)."""
        assert self.position is not None
        here = [(self.position, self.velocity)]
        pattern = self.hold_pattern
        speed = float(np.linalg.norm(self.velocity))
        if pattern is None or pattern.kind != "circle" or speed < 1.0:
            return here
        turn = (1.0 if pattern.clockwise else -1.0) * speed / (pattern.radius + FLOWN_WIDER_M)  # rad/s, right +
        pos, vel, dt = self.position.copy(), np.asarray(self.velocity, dtype=float).copy(), 0.25
        for _ in range(round(RESUME_ROLL_OUT_S / dt)):
            a = -turn * dt  # a right (clockwise) turn rotates the ENU velocity clockwise
            vel = np.array([vel[0] * math.cos(a) - vel[1] * math.sin(a), vel[0] * math.sin(a) + vel[1] * math.cos(a)])
            pos = pos + np.array([vel[0] * dt, vel[1] * dt, 0.0])
        return [*here, (pos, vel)]

    async def resume(self) -> None:
        """Back to AUTO at the current item, unless someone else has changed the mode meanwhile. AUTO is not
        someone else's: an autopilot may acknowledge the hold before its HEARTBEAT shows it (PX4 does: a stale
        AUTO arrived between the hold and the resume and left the vehicle holding for good), and a pilot who put
        it back in AUTO wants the mission flown; AUTO is sent either way."""
        if self.custom_mode is not None and self.custom_mode not in (self._number(self.held_in or self.hold_mode),
                                                                     self._number("AUTO")):
            self.events.log("not_resuming", reason="the mode was changed by someone else",
                            mode=self._name(self.custom_mode))
            self.holding = self.held_in = self.hold_pattern = self._exit = None
            return
        await self._mode("AUTO")
        self.events.log("resume", reason=self.holding, seq=self.current_seq)
        self.holding = self.held_in = self.hold_pattern = self._exit = None

    def _hold_exit(self, budget_s: float) -> CircleExit | None:
        """Where a plane circling its hold will leave it for a route planned now within ``budget_s``: far enough
        round the circle it flies that the plan and its upload are done first (:func:`circle_exit`). None when it
        is not circling a hold of ours (a copter, a hold not yet captured: it is planned from where it is)."""
        pattern = self.hold_pattern
        if pattern is None or pattern.kind != "circle" or not self.link.profile.hold_circles \
                or self.position is None or float(np.linalg.norm(self.velocity)) < 1.0:
            return None
        if abs(float(np.linalg.norm(self.position[:2] - pattern.centre[:2])) - pattern.radius) > 1.5 * FLOWN_WIDER_M:
            return None  # still joining its circle
        out = self.position[:2] - pattern.centre[:2]
        if (float(out[0] * self.velocity[1] - out[1] * self.velocity[0]) < 0.0) != pattern.clockwise:
            return None  # circling the other way than the pattern says (an autopilot's own loiter): not trusted
        wall = budget_s + 2.0 * (self._upload_wall_s + self.cfg.check_interval_wall_s)
        lead = (wall * self.clock.rate + EXIT_MARGIN_S) * self.flying_speed
        return circle_exit(self.position, pattern.centre, pattern.clockwise, self.route.goal, lead)

    async def _leave_hold(self, now: float) -> None:
        """Held with a route planned from the circle's exit: resume towards the item after the exit as the plane
        comes to it (:data:`EXIT_LEAD_S` early), when the join is clear from there; else hold on and plan again."""
        leaving = self._exit
        assert leaving is not None and leaving.seq is not None and self.position is not None \
            and self.hold_pattern is not None
        seq, centre, clockwise = leaving.seq, self.hold_pattern.centre, self.hold_pattern.clockwise
        r = max(float(np.linalg.norm(self.position[:2] - centre[:2])), 1.0)
        left = arc_to(self.position, centre, clockwise, leaving.exit.point) * r
        step = self.flying_speed * self.cfg.check_interval_wall_s * self.clock.rate
        lead = EXIT_LEAD_S * self.flying_speed + step
        lap = 2.0 * math.pi * r
        prev, leaving.left_m = leaving.left_m, left
        if lead < left < lap - 2.0 * step:  # not there yet, or passed between two looks (a loaded machine)
            crossed = prev is not None and left > prev + 0.5 * lap
            if crossed or now > leaving.due + EXIT_LATE_S:  # the route's timing is gone: plan again from the circle
                self.events.log("hold_exit_missed", seq=seq, due=round(leaving.due, 1), left_m=round(left, 1))
                self._exit = None
                self._last_replan = -math.inf
            return
        self._exit = None
        blocked = self.leg_blocked(seq, EXIT_CHECK_MARGIN_M)
        # on its way from the exit: it may roll out of the circle a little late, never a circle late
        if blocked is not None or not self._clear_from(seq, np.array([0.0, RESUME_ROLL_OUT_S])):
            self.events.log("hold_exit_refused", seq=seq, obstacle=blocked and blocked[1],
                            clearance_m=blocked and round(blocked[0], 1))
            self._last_replan = -math.inf  # plan again from the circle at once
            return
        if self.current_seq != seq:  # someone moved it meanwhile: resume towards the item checked
            await self.set_current(seq, then=self.resume)
        else:
            await self.resume()

    async def _retry_from_hold(self, now: float, threats: Threats) -> None:
        """While holding: resume if the old route is clear again, else plan from here."""
        self._last_replan = now
        conflicts = self.predict(now, threats) if len(threats) else []
        seq = self.ahead_seq(max(self.current_seq, int(self.route.seqs[0])))
        if not conflicts and (blocked := self.leg_blocked(seq) or self.route_blocked(seq)) is not None:
            # resuming would fly straight from here through an obstacle: a route from here first
            clearance, obstacle = blocked
            self.events.log("resume_blocked", seq=seq, obstacle=obstacle, clearance_m=round(clearance, 1))
            assert self.position is not None
            conflicts = [Conflict(f"static {obstacle}", now, clearance, tuple(self.position), 0, 0.0)]
        if not conflicts:
            self.events.log("threat_cleared", rejoin_s=float(self.rejoin_delays()[-1]))
            if seq != self.current_seq:
                await self.set_current(seq)
            await self.resume()
            return
        await self.replan(conflicts[0], now, threats, lead_m=0.0)
