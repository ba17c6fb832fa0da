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
import math
import time
from collections.abc import Sequence

import numpy as np

from companion.mavlink.items import MissionItem
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.vehicle_limits import AutopilotLimits
from companion.mission.builder import MissionSpec
from companion.mission.events import EventLog
from companion.mission.vehicle_state import VehicleState
from companion.replanning.context import ReplanContext
from companion.replanning.guard import first_breach, predict_own_path
from companion.replanning.holds import arc_to
from companion.replanning.modes import RESUME_ROLL_OUT_S, Leaving, ModeControl
from companion.replanning.motion import VehicleMotion
from companion.replanning.planning import ReplanPlanning
from companion.replanning.prediction import Prediction
from companion.replanning.rejoin import RejoinChecks
from companion.replanning.replan import CommitPoint, ReplanConfig, ReplanRecord, splice
from companion.replanning.swap import LiveMission, MissionSwap
from companion.replanning.threats import Conflict
from companion.replanning.worker import PlanWorker, expects_traffic
from planner.world.environment import Threats
from planner.world.scenario import Scenario

GUARD_MIN_ALT_M = 10.0  # m above home: below it the vehicle is taking off or landing, which the guard leaves be
GUARD_REPEAT_WALL_S = 1.0  # wall seconds between two guard actions
# the guard acts on a predicted clearance below this share of d_coll: its path model is a few metres off in a turn
# (the demo's plane: predicted 9.9 m, flown 15.4 m), and a hold that was not needed turns the plane off its route
GUARD_SHARE_OF_D_COLL = 0.5
# vehicle seconds before the exit point of its hold circle that a plane is resumed onto the route planned from there
# (ArduPlane rolls out of its bank over about a second; docs/design.md, "Leaving a hold")
EXIT_LEAD_S = 1.0
# vehicle seconds after the exit was due that a plane still short of it has missed it (the plan's time is gone; plus
# EXIT_PACE_SLACK of the time to circle there), and the seconds of flight past it that a plane seen past it only now
# has missed it by; one that comes to it late, or passed it by less, is resumed only when the join, checked from
# where and when it is, is clear (on the simulator a held plane flew its circle at 16 m/s
# against the 18 m/s assumed, and came to an exit 418 m round it 3 s after it was due)
EXIT_LATE_S = 3.0
# of the time planned to circle to the exit, the share a plane may take longer and still be awaited there (the
# simulator's plane at 16 m/s against 18 assumed is 11 % slower; on a loaded CI machine a route whose exit lay most
# of a lap round was missed for it and planned a lap later)
EXIT_PACE_SLACK = 0.2
# m beyond d_coll the resume at a circle's exit is checked with (leg_blocked): its route was planned from there with
# RESUME_MARGIN_M more than d_coll and its turns' swing, and, aligned with its first leg, the plane flies it with
# little turn; the check's paths turn up to WIDE_TURNS times wider than the path-follower's bound, which is for
# turning back from anywhere. Checked with a margin, exits were refused at 13.9-19.9 m and planned again, for good
EXIT_CHECK_MARGIN_M = 0.0


class LiveReplanner:
    """Watches the flight and replaces the mission when a threat will come too close: the coordinator of its parts,
    each doing one thing on one shared :class:`VehicleState` (fed by the supervisor's subscription):
    :class:`Prediction` (traffic and conflicts), :class:`ReplanPlanning` (budget, commit point, plan, verdict),
    :class:`MissionSwap` (the verified mission and its upload), :class:`ModeControl` (holds and resumes) and
    :class:`RejoinChecks` (whether the way back to the route is clear).

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
        self.state = VehicleState(scenario.home, rate)
        self.ctx = ctx = ReplanContext(link, client, events, scenario, cfg or ReplanConfig(), self.state, limits)
        self.spec = spec
        self.motion = VehicleMotion(ctx)
        self.prediction = Prediction(ctx, self._flying_route)
        self.modes = ModeControl(ctx, self.motion, self.prediction)
        self.swap = MissionSwap(ctx, self.motion, self.prediction, self.modes, items)
        self.rejoin = RejoinChecks(ctx, self.motion, self.prediction, self.modes, self.swap)
        self.planning = ReplanPlanning(ctx, self.motion, self.prediction, self.modes, self.swap, seed)
        self.records: list[ReplanRecord] = []
        self.guard_enabled = True  # the flown-safety guard (companion/replanning/guard.py)
        self._guard_at = -math.inf  # wall time of the last guard action
        self._last_replan = -math.inf  # mission time
        # started now, and warmed up on the whole route, so the first conflict finds it ready; a flight with nothing
        # moving (the flown-safety guard may still need a static replan) starts it only when it is first needed
        if expects_traffic(scenario, rate) or worker is not None:
            self.planning.start_worker(worker)
        self.state.listen_link(self._on_link)

    # -- what the supervisor asks (its Pilot) --------------------------------------------------------
    @property
    def holding(self) -> str | None:
        """Why the vehicle is held, or None."""
        return self.modes.holding

    @property
    def goal_seq(self) -> int:
        return self.swap.goal_seq

    @property
    def mission(self) -> list[MissionItem]:
        """The mission last verified on the vehicle."""
        return self.swap.mission

    @property
    def changing(self) -> bool:
        """A replan's upload or restore is changing the vehicle's mission now."""
        return self.swap.changing

    @property
    def verified(self) -> list[tuple[float, list[MissionItem]]]:
        """Every mission known verified on the vehicle, with the (monotonic) time its readback matched."""
        return self.swap.verified

    @property
    def history(self) -> list[LiveMission]:
        """The missions the replans stored on the vehicle (and restored), in order (:class:`LiveMission`)."""
        return self.swap.history

    def near_goal(self) -> bool:
        """Whether the last position is near the goal: a completion report from before a swap (different
        numbering) must not end the flight."""
        position = self.state.position
        if position is None:
            return True
        return float(np.linalg.norm(position - self.swap.route.goal)) < max(
            5 * self.ctx.scenario.vehicle.acceptance_radius, 150.0)

    def note_upload(self, seconds: float) -> None:
        """The initial mission's verified upload took ``seconds`` (wall): the first guess for a replan's."""
        self.swap.note_upload(seconds)

    async def ready(self) -> None:
        await self.planning.ready()

    async def hold(self, reason: str, route_separation: float | None = None) -> None:
        await self.modes.hold(reason, route_separation)

    async def aclose(self) -> None:
        """Stop the planner process (waits for a plan in progress to end, at most its budget)."""
        await self.planning.aclose()

    async def __aenter__(self) -> LiveReplanner:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()

    def _flying_route(self) -> bool:
        """Flying the route in AUTO (its ground speed is its pace along the route)."""
        return self.modes.in_auto() and self.swap.on_route()

    # -- task ---------------------------------------------------------------------------------------
    async def run(self) -> None:
        """Look at the picture every ``check_interval_wall_s`` (from the start of one look to the next) until
        cancelled; raises :class:`VehicleHolding` when no verified mission can be made live."""
        interval = self.ctx.cfg.check_interval_wall_s
        while True:
            began = time.monotonic()
            if self.state.position is not None and self.state.mission_t0 is not None:
                await self.step()
            await asyncio.sleep(max(interval - (time.monotonic() - began), 0.0))

    async def step(self) -> None:
        """One look at the picture: replan on a conflict, or, while holding, retry or resume. Nothing while the
        supervisor has found the link lost, nor after it until fresh telemetry has come (positions are stale and
        nothing can be uploaded; the vehicle flies, or holds on, its verified mission)."""
        if not self.state.fresh:
            return
        state, modes = self.state, self.modes
        now = state.now()
        threats = self.prediction.threats(now)
        self.prediction.log_contacts(now, threats)
        if not modes.in_control():
            return
        if modes.holding is None and await self._guard():
            return
        if modes.holding is not None:
            await modes.recheck_hold(now, threats)
            if modes.exit is not None:
                await self._leave_hold(now)
                return
            if now - self._last_replan >= self.ctx.cfg.hold_retry_s:
                await self._retry_from_hold(now, threats)
            return
        if not len(threats) or state.current_seq > self.goal_seq:
            return
        conflicts = self._conflicts(now, threats)
        if not conflicts:
            self.planning.failed_plans = 0
            return
        if now - self._last_replan < self.ctx.cfg.min_interval_s:
            return
        await self.replan(conflicts[0], now, threats)

    def _on_link(self, up: bool) -> None:
        """The supervisor found the link lost (replanning pauses: :meth:`step` waits for fresh telemetry), or it is
        back with the mission re-synced."""
        if up:
            self.ctx.events.log("replanning_resumed", reason="link restored, mission re-synced")
        else:
            self.ctx.events.log("replanning_paused", reason="link lost", decision=(
                "the vehicle holds" if self.modes.holding is not None else "the vehicle flies its verified mission"))

    def _conflicts(self, now: float, threats: Threats) -> list[Conflict]:
        """Conflicts on the remaining route, flown from now; for a held vehicle, flown from any moment it may
        be back on it after resuming (:meth:`ModeControl.rejoin_delays`): the earliest conflict of all."""
        route, _ = self.swap.remaining()
        return self.prediction.conflicts(route, now, threats, self.modes.rejoin_delays())

    async def _guard(self) -> bool:
        """The flown-safety guard: predict the vehicle's own path (:func:`predict_own_path`) and, if it will come
        within d_coll of a static obstacle, hold it on a checked pattern before it gets there (a static route from
        where it is is then planned by the retries from the hold). True when it acted."""
        state, ctx, swap = self.state, self.ctx, self.swap
        if not self.guard_enabled or state.position is None or not swap.on_route() \
                or state.position[2] < GUARD_MIN_ALT_M or time.monotonic() - self._guard_at < GUARD_REPEAT_WALL_S:
            return False
        route, seqs = swap.remaining()
        radius = self.motion.turn_radius() if ctx.profile.hold_circles else 0.0
        before = np.flatnonzero(swap.route.seqs < seqs[1]) if len(seqs) > 1 else np.zeros(0, dtype=int)
        origin = swap.route.points[before[-1]] if before.size else state.position
        path = predict_own_path(state.position, state.velocity, origin, route[1:], radius,
                                ctx.scenario.vehicle.acceptance_radius, climbing=state.climb,
                                **self.motion.height_response())
        breach = first_breach(path, ctx.scenario.environment, GUARD_SHARE_OF_D_COLL * ctx.d_coll)
        if breach is None:
            return False
        self._guard_at = time.monotonic()
        ctx.events.log("guard", obstacle=breach.obstacle, clearance_m=round(breach.clearance_m, 1),
                       in_s=round(breach.in_s, 1), at=[round(c, 1) for c in breach.point])
        await self.modes.hold(f"flown-safety guard: predicted {breach.clearance_m:.0f} m from {breach.obstacle} in "
                              f"{breach.in_s:.1f} s (d_coll {ctx.d_coll:g} m)")
        if self.modes.holding is not None:
            self._last_replan = -math.inf  # plan from the hold at once
        return True

    # -- replanning ---------------------------------------------------------------------------------
    async def replan(self, conflict: Conflict, now: float, threats: Threats, lead_m: float | None = None) -> bool:
        """Plan from a commit point and make the result the live mission; True when it is."""
        t_detect = time.monotonic()
        self._last_replan = now
        ctx, state, modes, swap, planning = self.ctx, self.state, self.modes, self.swap, self.planning
        rec = ReplanRecord(len(self.records) + 1, "conflict" if modes.holding is None else "retry while holding",
                           conflict.threat_id, round(now, 2), round(conflict.t - now, 2),
                           round(conflict.separation, 2), held=modes.holding is not None)
        self.records.append(rec)
        ctx.events.log("conflict", n=rec.n, threat=rec.threat, in_s=rec.conflict_in_s,
                       separation_m=rec.sep_before_m, d_coll_m=ctx.d_coll)
        budget = planning.budget(conflict, now)
        if lead_m is None:
            lead_m = planning.commit_lead_m(conflict, now, budget)
        departing = not swap.on_route()
        cp = planning.commit(now, budget, lead_m, departing)
        rec.commit = [round(float(v), 1) for v in cp.point]
        rec.old_route = cp.old_tail.round(1).tolist()
        rec.budget_s = budget
        problem, settings = planning.problem(cp, threats)
        t0 = time.monotonic()
        # a plan that overruns (a loaded machine, a planner process still starting) must not let the vehicle fly
        # on into the rewritten items and the conflict while it waits: the swap's guard applies already
        plan = planning.plan(problem, settings, cp, budget, rec)
        await swap.guarded(plan, cp.first_new_seq, swap.guard_threshold_s(),
                           "the plan is late: the vehicle could reach the commit point before it is ready", rec,
                           route_separation=rec.sep_before_m)
        job = plan.result()
        rec.plan_s = round(time.monotonic() - t0, 3)
        rec.plan_status = job.status
        if not departing and state.current_seq > cp.first_new_seq + 1:
            # the plan took so long (a loaded machine) that the vehicle is past the commit point and its next
            # item: the new route would start behind it and its timing is gone. Plan again from here, now.
            rec.outcome = "stale: the vehicle passed the commit point while it was planned"
            ctx.events.log("replan_stale", n=rec.n, plan_s=rec.plan_s, first_new=cp.first_new_seq,
                           current=state.current_seq)
            self._last_replan = -math.inf
            return False
        safe = planning.safe(job, cp, conflict, threats, rec)
        new_route = job.waypoints.astype(float)
        ctx.events.log("replan_planned", n=rec.n, status=rec.plan_status, budget_s=budget, plan_s=rec.plan_s,
                       separation_after_m=rec.sep_after_m, commit=rec.commit, waypoints=len(new_route),
                       violations=job.violations, old_route=rec.old_route, new_route=rec.new_route)
        if not safe and modes.holding is None and conflict.separation >= ctx.d_coll:
            rec.outcome = "no better route: the current one (inside the margin, outside d_coll) is kept"
            ctx.events.log("replan_skipped", n=rec.n, reason=rec.outcome)
            return False
        if not safe:
            rec.outcome = "no safe plan: holding"
            await modes.hold(f"no safe plan within {budget:g} s ({rec.plan_status}, predicted separation "
                             f"{rec.sep_after_m:.0f} m)")
            rec.held = True
            return False
        items = splice(swap.route.items, cp.first_new_seq, new_route[1:] if departing else new_route,
                       self.goal_seq, self.spec,
                       length=len(swap.mission) if ctx.client.writes_in_part else None)
        t_up = time.monotonic()
        live = await self._make_live(items, cp, rec)
        rec.upload_s = round(time.monotonic() - t_up, 3)
        if not live:
            rec.outcome = "verified but no longer clear: holding"
            ctx.events.log("replan_not_live", **rec.summary())
            return False
        rec.latency_s = round(time.monotonic() - t_detect, 3)
        rec.outcome = "new mission current"
        ctx.events.log("replanned", **rec.summary())
        return True

    async def _make_live(self, items: list[MissionItem], cp: CommitPoint, rec: ReplanRecord) -> bool:
        """Upload ``items`` while flying (:meth:`MissionSwap.upload`) and make them the live mission; False when
        they were verified but are no longer safe to join (the vehicle is then held)."""
        state, modes, swap, rejoin = self.state, self.modes, self.swap, self.rejoin
        first_new_seq = cp.first_new_seq
        await swap.upload(items, first_new_seq, rec)
        leaving, modes.planning_exit = modes.planning_exit, None
        if modes.holding is not None and leaving is not None:
            # the route starts at the hold circle's exit: the plane circles on to it, and is resumed there towards
            # the item after it once the join is checked again from where it is then (_leave_hold)
            leaving.seq = min(first_new_seq + 1, self.goal_seq)
            await swap.set_current(leaving.seq)
            modes.exit = leaving
            self.ctx.events.log("hold_exit", n=rec.n, seq=leaving.seq,
                                at=[round(float(v), 1) for v in leaving.exit.point], in_m=round(leaving.exit.arc_m, 1))
            return True
        target = state.current_seq
        replaced = state.current_seq >= first_new_seq
        if replaced:  # its active item was replaced: join the new route
            target = rejoin.join_seq(first_new_seq)
        if modes.holding is not None:  # a held plane has circled on: never turn it back for an item behind it
            target = rejoin.ahead_seq(target)
        if not rejoin.clear_from(target):
            reason = "no safe plan: the new route is no longer clear from where the vehicle is"
            await modes.hold(reason)
            # retried from here like any plan that is not safe; a hold refused leaves the vehicle flying on, and its
            # conflicts are predicted again
            if modes.holding is not None:
                modes.holding = reason
            rec.held = True
            if target != state.current_seq:
                await swap.set_current(target)
            return False
        if modes.holding is not None and (blocked := rejoin.leg_blocked(target)) is not None:
            # held off the route: the straight leg back to the join crosses an obstacle; keep holding on the
            # checked pattern and plan again from where the vehicle is
            self.ctx.events.log("resume_blocked", seq=target, obstacle=blocked[1], clearance_m=round(blocked[0], 1))
            if target != state.current_seq:
                await swap.set_current(target)
            rec.held = True
            return False
        resume = modes.resume if modes.holding is not None else None
        if target != state.current_seq or (replaced and modes.holding is None):
            # ArduPlane keeps flying its own copy of a replaced active item until that item is restarted (on the
            # simulator at 5x under load, towards the old item 12 through the intruder: -8.2 m); a held vehicle
            # restarts it on re-entering AUTO
            await swap.set_current(target, then=resume)
        elif resume is not None:
            await resume()
        return True

    # -- leaving a hold -----------------------------------------------------------------------------
    async def _leave_hold(self, now: float) -> None:
        """Held with a route planned from the circle's exit: resume towards the item after the exit as the plane
        comes to it (:data:`EXIT_LEAD_S` early), when the join is clear from there; else hold on and plan again."""
        state, modes = self.state, self.modes
        leaving, pattern = modes.exit, modes.pattern
        assert leaving is not None and leaving.seq is not None and state.position is not None and pattern is not None
        seq, centre, clockwise = leaving.seq, pattern.centre, pattern.clockwise
        r = max(float(np.linalg.norm(state.position[:2] - centre[:2])), 1.0)
        left = arc_to(state.position, centre, clockwise, leaving.exit.point) * r
        speed = self.motion.flying_speed
        step = speed * self.ctx.cfg.check_interval_wall_s * state.clock.rate
        lead = EXIT_LEAD_S * speed + step
        lap = 2.0 * math.pi * r
        # the arc left at the last look, or as planned: an exit planned most of a lap ahead is not one just passed
        prev = leaving.exit.arc_m if leaving.left_m is None else leaving.left_m
        leaving.left_m = left
        passed = left > prev + 0.5 * lap  # what is left jumped up by most of a lap: passed between two looks
        if left > lead and not passed:  # not there yet: it may circle slower than assumed, in proportion
            if now > leaving.due + EXIT_LATE_S + EXIT_PACE_SLACK * leaving.exit.arc_m / speed:
                self._exit_missed(seq, leaving, left)  # far slower than planned: the route's timing is gone
            return
        if passed and lap - left > EXIT_LATE_S * speed:  # looked at too late (a starved loop): not flown late
            self._exit_missed(seq, leaving, left)
            return
        modes.exit = None
        blocked = self.rejoin.leg_blocked(seq, EXIT_CHECK_MARGIN_M)
        # on its way from the exit: it may roll out of the circle a little late, never a circle late
        if blocked is not None or not self.rejoin.clear_from(seq, np.array([0.0, RESUME_ROLL_OUT_S])):
            self.ctx.events.log("hold_exit_refused", seq=seq, obstacle=blocked and blocked[1],
                                clearance_m=blocked and round(blocked[0], 1))
            self._last_replan = -math.inf  # plan again from the circle at once
            return
        if state.current_seq != seq:  # someone moved it meanwhile: resume towards the item checked
            await self.swap.set_current(seq, then=modes.resume)
        else:
            await modes.resume()

    def _exit_missed(self, seq: int, leaving: Leaving, left: float) -> None:
        """The exit's time is gone: plan again from the circle at once."""
        self.ctx.events.log("hold_exit_missed", seq=seq, due=round(leaving.due, 1), left_m=round(left, 1))
        self.modes.exit = None
        self._last_replan = -math.inf

    async def _retry_from_hold(self, now: float, threats: Threats) -> None:
        """While holding: resume if the old route is clear again, else plan from here."""
        self._last_replan = now
        state, rejoin = self.state, self.rejoin
        conflicts = self._conflicts(now, threats) if len(threats) else []
        seq = rejoin.ahead_seq(max(state.current_seq, int(self.swap.route.seqs[0])))
        if not conflicts and (blocked := rejoin.leg_blocked(seq) or rejoin.route_blocked(seq)) is not None:
            # resuming would fly straight from here through an obstacle: a route from here first
            clearance, obstacle = blocked
            self.ctx.events.log("resume_blocked", seq=seq, obstacle=obstacle, clearance_m=round(clearance, 1))
            assert state.position is not None
            conflicts = [Conflict(f"static {obstacle}", now, clearance, tuple(state.position), 0, 0.0)]
        if not conflicts:
            self.ctx.events.log("threat_cleared", rejoin_s=float(self.modes.rejoin_delays()[-1]))
            if seq != state.current_seq:
                await self.swap.set_current(seq)
            await self.modes.resume()
            return
        await self.replan(conflicts[0], now, threats, lead_m=0.0)
