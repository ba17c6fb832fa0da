"""The replanner's planning (docs/design.md, "Live replanning"): the time budget, the commit point the new route
starts from, the problem handed to the planner process, and the verdict on what comes back."""

from __future__ import annotations

import asyncio
import math

import numpy as np

from companion.replanning.context import ReplanContext
from companion.replanning.guard import first_breach
from companion.replanning.modes import Leaving, ModeControl
from companion.replanning.motion import VehicleMotion
from companion.replanning.prediction import Prediction
from companion.replanning.rejoin import RESUME_MARGIN_M
from companion.replanning.replan import (
    CommitPoint,
    ReplanRecord,
    commit_point,
    replan_settings,
    tail_to,
    vias_ahead,
    warm_starts,
)
from companion.replanning.swap import MissionSwap
from companion.replanning.threats import Conflict
from companion.replanning.worker import PlanWorker, WorkerPlan
from planner.plan import PlanStatus
from planner.problem import PlanningProblem
from planner.replan import replan_problem
from planner.world.config import PlannerSettings
from planner.world.environment import Threats
from planner.world.scenario import MIN_ROUTE_LENGTH

BAND_INSET_M = 0.5  # a commit point is moved at least this far inside the altitude band
GOOD = (PlanStatus.EXACT.value, PlanStatus.APPROXIMATE.value)
FLOWN_CHECK_DT_S = 0.5  # vehicle seconds between the points of a plan's flown path


class ReplanPlanning:
    """Plans for the live replanner, in its planner process (:class:`PlanWorker`). ``seed`` makes the replans
    reproducible for a given picture."""

    def __init__(self, ctx: ReplanContext, motion: VehicleMotion, prediction: Prediction, modes: ModeControl,
                 swap: MissionSwap, seed: int) -> None:
        self.ctx, self.motion, self.prediction, self.modes, self.swap = ctx, motion, prediction, modes, swap
        self.seed = seed
        self.worker: PlanWorker | None = None
        self.failed_plans = 0  # plans in a row that were not safe enough to use (each next one gets more budget)

    # -- the planner process ------------------------------------------------------------------------
    def start_worker(self, started: PlanWorker | None = None) -> PlanWorker:
        """The planner process, warmed up on the whole route: ``started`` (a process already running) or a new one.
        A vehicle that holds on circles is also warmed with the wider margin its routes from a hold keep: that is
        another roadmap (its clearance is part of the graph), and building it at the first held plan made that plan
        0.07 s slower on an idle core, 0.1 s under load on SITL."""
        if self.worker is None:
            sc, route = self.ctx.scenario, self.swap.route
            settings = replan_settings(sc.planner, self.ctx.cfg)
            self.worker = started if started is not None else PlanWorker()
            for margin in (0.0, RESUME_MARGIN_M) if self.ctx.profile.hold_circles else (0.0,):
                self.worker.warm(replan_problem(sc, route.points[0], route.goal, sc.environment.threats, 0.0,
                                                static_margin=margin), settings)
        return self.worker

    async def ready(self) -> None:
        """Wait until the planner is warm (call before the flight starts: a replan made while the planner
        process is still starting takes seconds instead of its budget)."""
        if self.worker is None:
            return
        waited = await self.worker.ready()
        self.ctx.events.log("planner_ready", waited_s=round(waited, 3))

    async def aclose(self) -> None:
        """Stop the planner process (waits for a plan in progress to end, at most its budget)."""
        if self.worker is not None:
            await asyncio.to_thread(self.worker.close)

    # -- budget and commit point --------------------------------------------------------------------
    def budget(self, conflict: Conflict, now: float) -> float:
        """Wall seconds for this plan: the configured budget, doubled for each plan in a row that was not safe (a
        loaded machine gives the planner less of a core: under a CPU hog at 5x the simulated plane flew into an
        intruder after two 0.15 s plans timed out), up to ``max_budget_s`` and only while the commit lead it needs
        still fits in the first half of the way to the conflict. A vehicle that holds has checked time: the
        longest budget at once (under load, in ``fuseplan demo``, every 0.15 s plan from a hold with the resume's
        margin timed out and the plane held until the intruder had passed)."""
        cfg = self.ctx.cfg
        if self.modes.holding is not None:
            return max(cfg.max_budget_s, cfg.budget_s)
        budget = min(cfg.budget_s * 2.0 ** self.failed_plans, max(cfg.max_budget_s, cfg.budget_s))
        room = self._room_m(conflict, now)
        while budget > cfg.budget_s and self._short_lead_m(budget) > room:
            budget = max(budget / 2.0, cfg.budget_s)
        return budget

    def _short_lead_m(self, budget_s: float) -> float:
        """The commit lead that covers planning within ``budget_s``, the upload and the lead margin alone."""
        cfg, rate = self.ctx.cfg, self.ctx.state.clock.rate
        plan_s = (budget_s + cfg.check_interval_wall_s) * rate
        return (plan_s + self.swap.upload_wall_s * rate + cfg.lead_margin_s) * self.prediction.speed

    def _room_m(self, conflict: Conflict, now: float) -> float:
        """The first half of the way to the conflict: what a commit lead may take (the rest is the detour's)."""
        return (conflict.t - now) * self.prediction.speed * 0.5

    def commit_lead_m(self, conflict: Conflict, now: float, budget_s: float) -> float:
        """How far ahead of the vehicle the new route starts. Far enough that the vehicle, flying on while the
        plan is made, cannot reach the first new item before the upload is verified: the swap's guard then
        has no reason to hold it. A plane held in LOITER for a guard turns off its route for seconds (at SITL's
        speed-up, for every wall second of upload, ten), which spoils the timing the new route was planned for
        and starts the next conflict; so the lead covers the guard's own threshold and the early waypoint
        switching it counts. Shortened to the planning-and-upload time alone when the conflict is too close
        for that (the guard then holds if it must)."""
        cfg = self.ctx.cfg
        plan_s = (budget_s + cfg.check_interval_wall_s) * self.ctx.state.clock.rate
        full = (plan_s + self.swap.guard_threshold_s() + cfg.lead_margin_s) * self.prediction.speed \
            + self.motion.switch_m()
        short = self._short_lead_m(budget_s)
        return full if full <= self._room_m(conflict, now) else short

    def commit(self, now: float, budget_s: float, lead_m: float, departing: bool) -> CommitPoint:
        """Where the new route starts: ``lead_m`` ahead along the route; still climbing out (``departing``), the
        planned start, which stays as it is; held on a circle, where the plane leaves it flying its tangent (then
        ``modes.planning_exit``). Moved inside the altitude band (the vehicle's own height may sit a hair outside
        it)."""
        state, route, speed = self.ctx.state, self.swap.route, self.prediction.speed
        ahead, seqs = self.swap.remaining()
        if departing:
            start = route.points[0]
            cp = CommitPoint(start.copy(), 0.0, now + float(np.linalg.norm(start - ahead[0])) / speed,
                             int(route.seqs[0]) + 1, route.points.copy())
        else:
            cp = commit_point(ahead, seqs, max(state.current_seq, int(route.seqs[0])), lead_m, speed, now)
        ahead = self.vias_ahead(cp)  # the plane leaves its hold towards the first via it must still pass
        exit_ = self.modes.hold_exit(budget_s, ahead[0] if len(ahead) else route.goal, self.swap.upload_wall_s) \
            if self.modes.holding is not None and not departing else None
        self.modes.planning_exit = None
        if exit_ is not None:
            cp = CommitPoint(exit_.point.copy(), 0.0, now + exit_.arc_m / self.motion.flying_speed, cp.first_new_seq,
                             np.vstack([exit_.point, cp.old_tail[1:]]), exit_.heading)
            self.modes.planning_exit = Leaving(exit_, cp.t)
        env = self.ctx.scenario.environment
        ground = float(env.ground(cp.point[0], cp.point[1]))
        cp.point[2] = cp.old_tail[0, 2] = np.clip(cp.point[2], ground + env.z_min + BAND_INSET_M,
                                                  ground + env.z_max - BAND_INSET_M)
        return cp

    def start_heading(self, cp: CommitPoint) -> np.ndarray | None:
        """Unit (3,) direction the vehicle flies through the commit point: the old route's there, or its own
        velocity when the commit point is where it is (a replan from a hold); None while climbing out (a copter's
        too: it turns on the spot)."""
        if not self.ctx.profile.hold_circles:
            return None
        state = self.ctx.state
        here = state.position[:2] if state.position is not None else cp.point[:2]
        if float(np.linalg.norm(cp.point[:2] - here)) < 1.0 and float(np.linalg.norm(state.velocity)) > 1.0:
            v = np.array([*state.velocity, 0.0])
        elif cp.heading is not None:
            v = np.array(cp.heading, dtype=float)
            v[2] = 0.0
        else:
            return None
        n = float(np.linalg.norm(v))
        return v / n if n > 1e-6 else None

    def vias_ahead(self, cp: CommitPoint) -> np.ndarray:
        """The scenario's vias a route from ``cp`` must pass through (:func:`vias_ahead`): not yet passed, nor in
        the items kept before it."""
        return vias_ahead(self.swap.route, self.ctx.scenario.vias, cp.first_new_seq, cp.point, MIN_ROUTE_LENGTH)

    # -- the plan -----------------------------------------------------------------------------------
    def problem(self, cp: CommitPoint, threats: Threats) -> tuple[PlanningProblem, PlannerSettings]:
        """The replan from ``cp`` to the goal around ``threats``, and the settings it is planned with."""
        cfg = self.ctx.cfg
        # the way the vehicle will fly through the commit point (along the old route; held: its own track), so the
        # new route cannot begin with a turn it cannot fly (a hairpin there carried SITL's plane 29-38 m into a
        # cylinder); now that holds are checked, a plan that fails for it holds safely (docs/design.md)
        # held on a circle, the route is planned with the margin its resume will be checked with (leg_blocked):
        # planned with d_coll alone, every route from one circle was refused on resuming, for 197 replans
        resumed = RESUME_MARGIN_M if self.modes.holding is not None and self.ctx.profile.hold_circles else 0.0
        problem = replan_problem(self.ctx.scenario, cp.point, self.swap.route.goal, threats, cp.t,
                                 self.prediction.speed, heading=self.start_heading(cp), threat_margin=cfg.margin_m,
                                 static_margin=resumed)
        return problem, replan_settings(self.ctx.scenario.planner, cfg)

    def plan(self, problem: PlanningProblem, settings: PlannerSettings, cp: CommitPoint, budget_s: float,
             rec: ReplanRecord) -> asyncio.Task:
        """``problem`` planned within ``budget_s`` as a task in the planner process, through the vias still ahead
        (planner.legs), warm-started from the old route (to the first of them) and its bent copies."""
        vias = self.vias_ahead(cp)
        tail = tail_to(cp.old_tail, vias[0]) if len(vias) else cp.old_tail
        seeds = warm_starts(tail, self.ctx.cfg.detour_offsets_m, settings.pso.n_waypoints + 2)
        worker = self.start_worker()
        return asyncio.create_task(worker.plan(problem, settings, [self.seed, rec.n], seeds, budget_s,
                                               vias if len(vias) else None), name="replan-plan")

    def safe(self, job: WorkerPlan, cp: CommitPoint, conflict: Conflict, threats: Threats,
             rec: ReplanRecord) -> bool:
        """Whether the planned route may be flown: clear of the traffic by the margin, or safe (d_coll) and better
        than the route being flown; a route whose only fault is turns tighter than the vehicle's, judged by the
        path it will fly through them. Fills ``rec`` and counts the plans in a row that were not."""
        cfg, d_coll = self.ctx.cfg, self.ctx.d_coll
        new_route = job.waypoints.astype(float)
        after = self.prediction.closest(new_route, cp.t, threats)
        rec.sep_after_m = round(after.separation if after is not None else math.inf, 2)
        rec.new_route = new_route.round(1).tolist()
        # good: clear by the margin; else still used if it is safe and better than the route being flown
        safe = job.status in GOOD and (rec.sep_after_m >= d_coll + cfg.margin_m
                                       or rec.sep_after_m >= max(d_coll, conflict.separation))
        if not safe and job.violations and set(job.violations) <= {"turn"} and self.modes.holding is None:
            # turns tighter than the vehicle's: what matters is the path it will fly through them (the
            # waypoints are its mission items), checked as flown against the obstacles and the traffic; only for
            # a vehicle flying its route towards the commit point (one that is held joins from elsewhere: on SITL
            # such a plan joined from a hold overshot its tight turn 22.8 m into a cylinder)
            flown = self._flown_separation(cp, new_route, threats)
            if flown is not None:
                safe = flown >= d_coll + cfg.margin_m or flown >= max(d_coll, conflict.separation)
                self.ctx.events.log("replan_flown_check", n=rec.n, separation_m=round(flown, 1), used=safe)
        self.failed_plans = 0 if safe else self.failed_plans + 1
        return safe

    def _flown_separation(self, cp: CommitPoint, route: np.ndarray, threats: Threats) -> float | None:
        """The least traffic separation along ``route`` as the vehicle will fly it from the commit point (every
        path of :meth:`VehicleMotion.flown_paths` from its wide turn radius, to the route's end), or None when one of
        those paths comes within d_coll of a static obstacle."""
        heading = self.start_heading(cp)
        if heading is None:
            first = route[1] - route[0] if len(route) > 1 else np.array([0.0, 1.0, 0.0])
            heading = first / max(float(np.linalg.norm(first[:2])), 1e-6)
        speed = self.prediction.speed
        radius = self.motion.wide_turn_radius(speed) if self.ctx.profile.hold_circles else self.motion.turn_radius()
        length = float(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())
        # climbing as the old route does through the commit point: a plane behind its height demand stays behind
        climbing = 0.0 if cp.heading is None else \
            speed * float(cp.heading[2]) / max(float(np.linalg.norm(cp.heading[:2])), 1e-6)
        worst = math.inf
        for path in self.motion.flown_paths(route[0], heading[:2] * speed, route[0], route[1:], radius,
                                            min(length / speed + 10.0, self.ctx.cfg.horizon_s), dt=FLOWN_CHECK_DT_S,
                                            climbing=climbing):
            if first_breach(path, self.ctx.scenario.environment, self.ctx.d_coll) is not None:
                return None
            closest = self.prediction.closest(path[:, 1:4], cp.t, threats)
            worst = min(worst, closest.separation if closest is not None else math.inf)
        return worst
