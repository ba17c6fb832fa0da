"""Routes through the operator's vias (issue 35): the route start → vias[0] → … → goal is planned as legs, each
with :func:`planner.plan.plan` on a problem whose start and goal are the leg's ends, then joined and judged whole.

Each leg gets its own child of the caller's Generator (same seed, same route) and, under a deadline, a share of
what is left in proportion to its straight-line length. A leg after the first starts at its via flying the way
the leg before arrived (the problem's ``start_heading``), so the turn there is held to the vehicle's limits. The
joined waypoints are smoothed and checked as one route by the same :func:`planner.plan.assess` a single plan
gets: a corner cut at a via that the checker refuses makes the route infeasible, whatever the legs said.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.plan import LegRecord, PlanResult, PlanStatus, assess, plan, problem_from_scenario
from planner.problem import PlanningProblem
from planner.search.swarm import OptimiserResult
from planner.workload import MAX_PLAN_S, JobTooLarge, check_workload, estimate_s, post_reserve_s
from planner.world.config import PlannerSettings
from planner.world.scenario import Scenario

# worst last: a route's status is the worst of its legs' and of the check of the whole route
_RANK = (PlanStatus.EXACT, PlanStatus.APPROXIMATE, PlanStatus.INFEASIBLE, PlanStatus.TIMEOUT)


def leg_problems(problem: PlanningProblem, vias: np.ndarray) -> list[PlanningProblem]:
    """``problem`` cut at ``vias`` (k, 3) into k + 1 legs; every leg after the first without a start time or
    heading yet (:func:`plan_through` sets them from the leg before)."""
    points = np.vstack([problem.start, np.asarray(vias, dtype=float).reshape(-1, 3), problem.goal])
    return [dataclasses.replace(problem, start=a, goal=b) if k == 0
            else dataclasses.replace(problem, start=a, goal=b, start_heading=None)
            for k, (a, b) in enumerate(zip(points[:-1], points[1:], strict=True))]


def check_legs_workload(problem: PlanningProblem, vias: np.ndarray, settings: PlannerSettings,
                        budgeted: bool = False, source: str | None = None) -> None:
    """:func:`check_workload` on every leg, and the legs' time estimates together held to :data:`MAX_PLAN_S`."""
    legs = leg_problems(problem, vias)
    for leg in legs:
        check_workload(leg, settings, budgeted, source)
    total = sum(estimate_s(leg, settings, budgeted) for leg in legs)
    if total > MAX_PLAN_S:
        where = f"{source}: " if source else ""
        raise JobTooLarge(f"{where}the {len(legs)} legs through route.vias would take up to {total:.0f} s on a "
                          f"2-core machine (limit {MAX_PLAN_S:.0f} s): fewer vias, or a smaller swarm")


def plan_through(problem: PlanningProblem, vias: np.ndarray, settings: PlannerSettings, rng: np.random.Generator,
                 deadline: Deadline = NEVER, seed: int | None = None,
                 progress: Callable[[int, int, float], None] | None = None,
                 initial_paths: np.ndarray | None = None) -> PlanResult:
    """The route from ``problem.start`` through every via (k, 3) in order to ``problem.goal``, as one
    :class:`PlanResult`: the legs' waypoints joined (each via once), the whole route's cost, smoothed trajectory and
    check, and the status the worst of the legs' and the whole check's. ``initial_paths`` seed the first leg's
    search (they end at the first via). Without vias this is :func:`plan` itself."""
    vias = np.asarray(vias, dtype=float).reshape(-1, 3)
    if not len(vias):
        return plan(problem, settings, rng, initial_paths=initial_paths, deadline=deadline, seed=seed,
                    progress=progress)
    t0 = time.perf_counter()
    legs = leg_problems(problem, vias)
    chords = np.array([leg.direct_distance for leg in legs])
    search = deadline.minus(sum(post_reserve_s(leg, settings) for leg in legs))  # the joined route is checked after
    results: list[PlanResult] = []
    for k, (leg, child) in enumerate(zip(legs, rng.spawn(len(legs)), strict=True)):
        if results:  # on from the via: the time the leg before arrives, flying the way it arrived
            before = results[-1]
            leg = dataclasses.replace(leg, start_heading=before.waypoints[-1] - before.waypoints[-2],
                                      start_time=None if problem.start_time is None
                                      else float(before.trajectory.times[-1]))
        share = search.share(float(chords[k] / chords[k:].sum()))
        results.append(plan(leg, settings, child, initial_paths=None if k else initial_paths, deadline=share,
                            seed=seed, progress=progress))
    return _joined(problem, settings, results, seed, t0)


def _joined(problem: PlanningProblem, settings: PlannerSettings, legs: Sequence[PlanResult],
            seed: int | None, t0: float) -> PlanResult:
    """One result for the legs: their waypoints with each joint once, judged as one route (``t0``: when the
    planning began, on ``time.perf_counter``)."""
    waypoints = np.vstack([legs[0].waypoints, *(r.waypoints[1:] for r in legs[1:])])
    joints = np.cumsum([len(r.waypoints) - 1 for r in legs[:-1]])  # the vias' indices in ``waypoints``
    waypoints, (evaluation, traj, check, feasible) = _eased(problem, settings, waypoints, joints)
    whole = PlanStatus.EXACT if feasible else PlanStatus.INFEASIBLE
    status = max((whole, *(r.status for r in legs)), key=_RANK.index)
    opts = [r.optimiser for r in legs]
    reasons = [o.stop_reason for o in opts]
    stop = "timeout" if "timeout" in reasons else f"{len(legs)} legs: " + "; ".join(reasons)
    # the legs' cost histories one after the other (each leg's own cost: the curve shows how each leg converged)
    opt = OptimiserResult(waypoints, float(evaluation.total[0]), evaluation, [h for o in opts for h in o.history],
                          sum(o.iterations for o in opts), stop, sum(o.time_s for o in opts),
                          sum(o.evaluations for o in opts))
    records = tuple(LegRecord(r.status, r.cost, r.optimiser.iterations, r.plan_time_s, r.optimiser.stop_reason)
                    for r in legs)
    return PlanResult(status, legs[0].algorithm, seed, waypoints, evaluation, traj, check, opt,
                      time.perf_counter() - t0, records)


MAX_EASED = 3  # waypoints before a via that may be dropped to widen the turn there


def _verdict(problem: PlanningProblem, settings: PlannerSettings, waypoints: np.ndarray) -> tuple:
    """(evaluation, trajectory, check, feasible) of a whole route, as :func:`planner.plan.plan` judges one."""
    evaluation = problem.evaluate(waypoints[None])
    return (evaluation, *assess(problem, settings, waypoints, evaluation))


def _faults(verdict: tuple) -> int:
    evaluation, _, check, _ = verdict
    return int(evaluation.n_violations[0]) + sum(check.counts.values())


def _eased(problem: PlanningProblem, settings: PlannerSettings, waypoints: np.ndarray,
           joints: np.ndarray) -> tuple[np.ndarray, tuple]:
    """The joined route, and its verdict, with the turns at its vias widened where that removes faults.

    Joined, a leg's last segment bends into the next leg's first (the smoothing turns on the segment before a
    waypoint, its curvature growing as the segment shortens), which neither leg was planned with. Where the whole
    route has faults, the waypoints just before a via are dropped one at a time, up to :data:`MAX_EASED` (a longer
    segment into the via, a gentler curve), each kept only when the checked route has fewer faults. Deterministic;
    the vias and the route's ends are never dropped."""
    verdict = _verdict(problem, settings, waypoints)
    fixed = set(int(j) for j in joints) | {0, len(waypoints) - 1}
    for via in sorted(fixed - {0, len(waypoints) - 1}, reverse=True):  # from the end: earlier indices stay valid
        for _ in range(MAX_EASED):
            if _faults(verdict) == 0 or via - 1 in fixed:
                break
            trial = np.delete(waypoints, via - 1, axis=0)
            tried = _verdict(problem, settings, trial)
            if _faults(tried) >= _faults(verdict):
                break
            waypoints, verdict = trial, tried
            fixed = {j - 1 if j >= via else j for j in fixed}
            via -= 1
    return waypoints, verdict


def plan_scenario(scenario: Scenario, settings: PlannerSettings, rng: np.random.Generator,
                  start_time: float | None = None, deadline: Deadline = NEVER, seed: int | None = None,
                  progress: Callable[[int, int, float], None] | None = None) -> PlanResult:
    """The scenario's route, through its vias when it has any (:func:`plan_through`); what ``plan``, ``export``
    and ``fly`` plan. ``start_time`` as for :func:`problem_from_scenario`."""
    return plan_through(problem_from_scenario(scenario, start_time), scenario.vias, settings, rng, deadline, seed,
                        progress)
