"""Local repair of a nearly flyable route (docs/method.md §15.5): a roadmap guide usually misses by one or two
local faults (a leg a little short for the turn at its end, a corner grazing an obstacle). A swarm on a replan
budget gets a handful of iterations, which move every waypoint at once and rarely fix that; here each fault's own
waypoints are moved, many candidates at a time (one batched cost evaluation), and a candidate is kept only when
the whole route's cost falls."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.termination import WallClock

WINDOW = 4  # points per locating window: the middle segment sees its neighbours' turns on both sides


@dataclass(frozen=True)
class RepairResult:
    path: np.ndarray  # (N, 3), the same number of points as the input
    cost: float
    violations: int
    rounds: int
    evaluations: int


def fault_windows(problem: PlanningProblem, path: np.ndarray) -> np.ndarray:
    """First indices j of the 4-point windows path[j : j + 4] that have a static violation (collision, band,
    turn, climb, bounds): where a fault of the route lies. Moving threats are not located (their times depend
    on the whole route before the window)."""
    n = len(path)
    if n < WINDOW:  # too short to locate anything: the caller moves every interior point
        return np.zeros(0, dtype=int)
    j = np.arange(n - WINDOW + 1)
    windows = path[j[:, None] + np.arange(WINDOW)]
    static = replace(problem, start_time=None, start_heading=None)  # a window's start is not the route's
    bad = static.evaluate(windows).n_violations > 0
    if problem.start_heading is not None:  # the first window starts where the vehicle arrives with its heading
        bad[0] |= replace(problem, start_time=None).evaluate(windows[:1]).n_violations[0] > 0
    return j[bad]


def repair(problem: PlanningProblem, path: np.ndarray, rng: np.random.Generator, deadline: Deadline = NEVER,
           rounds: int = 8, candidates: int = 48) -> RepairResult:
    """Move the waypoints of each faulty window of ``path`` (N, 3; the ends stay) until the route has no
    violation, ``rounds`` rounds pass or ``deadline`` is reached: each step (locating the faults, or one window's
    candidates) starts only if it is predicted to end by then, as long as the longest recent step
    (:class:`planner.search.termination.WallClock`). Per window and round,
    ``candidates`` routes with that window's interior points displaced (Gaussian, a third of the shorter
    neighbouring leg horizontally, a quarter of that vertically; the scale halves after a round without
    gain) are scored by the cost of the stretch they change (every other term of the route's cost is the same
    for all of them; with moving threats, the whole route), and the cheapest replaces the route when it is
    cheaper. Without a located fault (a moving threat) every interior point may move."""
    best = np.array(path, dtype=float)
    t = deadline.clock()
    ev = problem.evaluate(best)
    cost, viol = float(ev.total[0]), int(ev.n_violations[0])
    n = len(best)
    legs = np.linalg.norm(np.diff(best[:, :2], axis=0), axis=1)
    scale = np.full(n, 1.0 / 3.0)
    timed = problem.timed_threats
    evaluations = used = 1
    # the first step is predicted from the route's own evaluation
    wall = WallClock(deadline, first_s=deadline.clock() - t)
    while used <= rounds and viol and n > 2 and not wall.done():
        starts = fault_windows(problem, best)
        evaluations += max(n - WINDOW + 1, 0)  # the windows scored
        wall.lap()
        for idx in [np.arange(j, j + WINDOW) for j in starts] or [np.arange(n)]:  # a route's few faults
            idx = idx[(idx > 0) & (idx < n - 1)]
            if not len(idx) or wall.done():
                continue
            reach = np.minimum(legs[idx - 1], legs[idx]) * scale[idx]  # interior: both legs exist
            step = rng.standard_normal((candidates, len(idx), 3)) * reach[None, :, None]
            step[..., 2] *= 0.25
            # the stretch whose cost the moved points change (their segments, the turns at their ends, the
            # corner cuts after them); with moving threats every later time changes, so the whole route
            lo, hi = (0, n) if timed else (max(int(idx[0]) - 3, 0), min(int(idx[-1]) + 4, n))
            trial = np.repeat(best[None, lo:hi], candidates + 1, axis=0)
            trial[1:, idx - lo] += step
            ev = problem.evaluate(trial)  # row 0: as it is
            evaluations += candidates + 1
            k = 1 + int(np.argmin(ev.total[1:]))
            if ev.total[k] < ev.total[0]:
                best[lo:hi] = trial[k]
                ev = problem.evaluate(best)
                cost, viol = float(ev.total[0]), int(ev.n_violations[0])
                evaluations += 1
                legs = np.linalg.norm(np.diff(best[:, :2], axis=0), axis=1)
            else:
                scale[idx] *= 0.5
            wall.lap()
            if not viol:
                break
        used += 1
    return RepairResult(best, cost, viol, used - 1, evaluations)
