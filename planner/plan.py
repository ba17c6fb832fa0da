"""One entry point: ``plan(problem, settings, rng)`` → :class:`PlanResult` with a status (after OMPL's PlannerStatus).

Runs the chosen optimiser, smooths the best path (docs/method.md §11), checks the smoothed trajectory (§12)
and computes the metrics (§13). A plan whose best path still violates anything is ``infeasible``, never success
(the statuses: docs/method.md §5.3).
"""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np
import pymap3d

from planner.deadline import NEVER, Deadline
from planner.distribution import fuseplan_version
from planner.problem import Evaluation, PlanningProblem
from planner.search.alloc import tune_allocator
from planner.search.spso import SphericalPSO
from planner.search.swarm import OptimiserResult
from planner.trajectory.checks import (
    CheckResult,
    Trajectory,
    check_trajectory,
    convergence_iteration,
    robustness,
    smooth,
    smoothness,
)
from planner.workload import check_workload, post_reserve_s, uses_roadmap
from planner.world.config import PlannerSettings
from planner.world.scenario import Scenario

MERGE_TOLERANCE_M = 1.0
PAPER_MIN_S = 0.05  # the least search time the paper's fusion is run on after an infeasible pipeline route (§15.6)


class PlanStatus(str, enum.Enum):  # noqa: UP042 - StrEnum would change how a status prints (str(), f-strings)
    EXACT = "exact"  # feasible, search ended on its own criteria
    APPROXIMATE = "approximate"  # feasible, but the time budget cut the search short
    INFEASIBLE = "infeasible"  # best path still violates a constraint
    TIMEOUT = "timeout"  # budget ran out before any feasible path was found


@dataclass(frozen=True)
class LegRecord:
    """How one leg of a route through vias was planned (:mod:`planner.legs`)."""

    status: PlanStatus
    cost: float
    iterations: int
    time_s: float
    stop_reason: str


@dataclass
class PlanResult:
    status: PlanStatus
    algorithm: str
    seed: int | None
    waypoints: np.ndarray  # (N, 3) ENU metres, start and goal included
    evaluation: Evaluation  # cost of exactly these waypoints (batch of one)
    trajectory: Trajectory
    check: CheckResult
    optimiser: OptimiserResult
    plan_time_s: float
    legs: tuple[LegRecord, ...] = ()  # a route through vias: its legs, in order (planner.legs); else none

    @property
    def feasible(self) -> bool:
        return self.status in (PlanStatus.EXACT, PlanStatus.APPROXIMATE)

    @property
    def cost(self) -> float:
        return float(self.evaluation.total[0])

    @property
    def violations(self) -> dict[str, int]:
        """Per category: runs of offending samples on the smoothed trajectory (the checker's verdict)."""
        return dict(self.check.counts)

    @property
    def cost_violations(self) -> dict[str, int]:
        """Per category: violation terms the cost counted on the waypoint path (segment × obstacle pairs)."""
        return {k: int(v[0]) for k, v in self.evaluation.violations.items()}

    @property
    def _clearance(self) -> np.ndarray:
        clearance = self.check.clearance
        assert clearance is not None  # check_trajectory measures it
        return clearance

    def metrics(self, d_safe: float) -> dict[str, float | int]:
        return {
            "length_m": self.trajectory.length,
            "waypoint_length_m": float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum()),
            "smoothness": smoothness(self.waypoints),
            "robustness": robustness(self._clearance, self.trajectory.curvature, d_safe),
            "min_clearance_m": self.check.min_clearance,
            "plan_time_s": self.plan_time_s,
            "convergence_iteration": convergence_iteration(self.optimiser.history),
            "iterations": self.optimiser.iterations,
            "evaluations": self.optimiser.evaluations,
        }


def problem_from_scenario(scenario: Scenario, start_time: float | None = None) -> PlanningProblem:
    """The scenario's start→goal problem; ``start_time`` (s) makes dynamic threats count (docs/method.md §4.6)."""
    if start_time is None and len(scenario.environment.threats):
        start_time = 0.0
    s = scenario.planner
    return PlanningProblem(scenario.environment, scenario.start, scenario.goal, scenario.vehicle,
                           scenario.hazard, s.weights, s.penalty, start_time)


class Optimiser(Protocol):
    def run(self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = ...,
            *, deadline: Deadline = ..., progress: Callable[[int, int, float], None] | None = ...,
            ) -> OptimiserResult: ...  # deadline and progress by name: SphericalPSO takes an encoding between them


def make_optimiser(settings: PlannerSettings) -> Optimiser:
    """The optimiser named by ``settings.algorithm``, configured from ``settings``."""
    from planner.search.aco import ColdColony
    from planner.search.baselines.bpso import BPSO
    from planner.search.baselines.cartesian_pso import CartesianPSO
    from planner.search.baselines.psogsa import PSOGSA
    from planner.search.baselines.qpso import QPSO
    from planner.search.fusion import Fusion

    name = settings.algorithm
    factories: dict[str, Callable[[], Optimiser]] = {
        "fusion": lambda: Fusion(settings),
        # with the roadmap on, spso is the guided swarm with the roadmap's seeds (docs/method.md §15.3 steps 1–2)
        "spso": lambda: Fusion(settings, swarm_only=True) if uses_roadmap(settings) else SphericalPSO(settings.pso),
        "pso": lambda: CartesianPSO(settings.pso),
        "qpso": lambda: QPSO(settings.pso, settings.qpso),
        "psogsa": lambda: PSOGSA(settings.pso, settings.psogsa),
        "bpso": lambda: BPSO(settings.pso, settings.bpso),
        "aco": lambda: ColdColony(settings.aco, settings.pso.n_waypoints),  # cold colony, no PSO phase
    }
    if name not in factories:
        raise ValueError(f"unknown algorithm {name!r}")
    return factories[name]()


def plan(
    problem: PlanningProblem, settings: PlannerSettings, rng: np.random.Generator,
    initial_paths: np.ndarray | None = None, deadline: Deadline = NEVER, seed: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> PlanResult:
    """Plan a route; every random choice comes from ``rng``. ``deadline`` bounds the whole plan's wall time
    (a caller with a budget in seconds passes ``Deadline.after(seconds)``): the search gets it less
    :func:`post_reserve_s` (the smoothing and checks after it, :meth:`Deadline.minus`) and stops before an
    iteration that would overrun that (:class:`planner.search.termination.WallClock`); a search the deadline
    cut short ends ``approximate`` (or ``timeout`` when infeasible). Without a budget (:data:`NEVER`, the
    default) the search is never cut short. Settings that ask for more memory or time than any real job raise
    :class:`planner.workload.JobTooLarge` first."""
    # an impossible job fails here, in one line, before any allocation
    check_workload(problem, settings, budgeted=deadline.bounded)
    tune_allocator()
    t0 = time.perf_counter()
    reserve = post_reserve_s(problem, settings)
    opt = make_optimiser(settings).run(problem, rng, initial_paths=initial_paths, deadline=deadline.minus(reserve),
                                       progress=progress)
    waypoints, evaluation, traj, check, feasible = _verdict(problem, settings, opt)
    if not feasible and _paper_may_follow(settings, opt) and deadline.affords(reserve + PAPER_MIN_S):
        # the pipeline's best still fails: the paper's fusion in what is left, and the better route is kept, so on a
        # map the paper's planner solves the pipeline does not lose (docs/method.md §15.6)
        paper_settings = replace(settings, roadmap=replace(settings.roadmap, enabled=False))
        paper = make_optimiser(paper_settings).run(problem, rng, initial_paths=initial_paths,
                                                   deadline=deadline.minus(reserve), progress=progress)
        verdict = _verdict(problem, settings, paper)
        opt = _with_paper(opt, paper, verdict[4] or paper.cost < opt.cost)
        if opt.winner == "paper":
            waypoints, evaluation, traj, check, feasible = verdict
    if opt.stop_reason == "timeout":
        status = PlanStatus.APPROXIMATE if feasible else PlanStatus.TIMEOUT
    else:
        status = PlanStatus.EXACT if feasible else PlanStatus.INFEASIBLE
    return PlanResult(status, settings.algorithm, seed, waypoints, evaluation, traj, check, opt,
                      time.perf_counter() - t0)


def _verdict(problem: PlanningProblem, settings: PlannerSettings, opt: OptimiserResult,
             ) -> tuple[np.ndarray, Evaluation, Trajectory, CheckResult, bool]:
    """An optimiser's route as it is handed on: close waypoints merged, its cost, and :func:`assess`'s verdict."""
    waypoints = merge_close_waypoints(opt.path)
    evaluation = problem.evaluate(waypoints[None]) if len(waypoints) != len(opt.path) else opt.evaluation
    return (waypoints, evaluation, *assess(problem, settings, waypoints, evaluation))


def _paper_may_follow(settings: PlannerSettings, opt: OptimiserResult) -> bool:
    """True for a roadmap-pipeline fusion that did not already end in the paper's fusion (no roadmap route)."""
    phases = getattr(opt, "phases", None) or {}
    road = phases.get("roadmap")
    return uses_roadmap(settings) and settings.algorithm == "fusion" and road is not None and road.iterations > 0


def _with_paper(pipeline: Any, paper: Any, paper_wins: bool) -> Any:
    """The pipeline's FusionResult with the paper's fusion as one more phase (``paper``, its phases under
    ``paper/…``): the winner's route, the histories one after the other, the times and counts summed."""
    from planner.search.fusion import FusionResult, PhaseRecord

    phases = dict(pipeline.phases)
    phases.update({f"paper/{k}": v for k, v in paper.phases.items()})
    phases["paper"] = PhaseRecord(paper.cost, paper.iterations, paper.time_s, paper.evaluations, paper.stop_reason)
    win = paper if paper_wins else pipeline
    # each of the paper's iterations after its initial best; the best so far, unless the paper's route won on
    # feasibility at a higher cost (then its own, so that the history ends at the plan's cost)
    tail = paper.history[len(paper.history) - paper.iterations:]
    history = list(pipeline.history) + ([float(h) for h in tail] if paper_wins and paper.cost > pipeline.cost
                                        else [min(pipeline.history[-1], h) for h in tail])
    stop = "timeout" if "timeout" in (pipeline.stop_reason, paper.stop_reason) else win.stop_reason
    return FusionResult(win.path, win.cost, win.evaluation, history, pipeline.iterations + paper.iterations, stop,
                        pipeline.time_s + paper.time_s, pipeline.evaluations + paper.evaluations, pipeline.state,
                        phases, "paper" if paper_wins else pipeline.winner, pipeline.trace)


def assess(problem: PlanningProblem, settings: PlannerSettings, waypoints: np.ndarray,
           evaluation: Evaluation) -> tuple[Trajectory, CheckResult, bool]:
    """The verdict on a route (its waypoints and the cost's ``evaluation`` of them): the smoothed trajectory, the
    checker's result on it, and whether it is feasible (no cost violation terms and a clean check). A fresh plan
    and a PLAN.json read back (:mod:`planner.plan_file`) are judged by this one function."""
    traj = smooth(waypoints, settings.sample_spacing, problem.vehicle.cruise_speed, problem.start_time or 0.0)
    check = check_trajectory(traj, waypoints, problem.env, problem.hazard, problem.vehicle, problem.timed_threats,
                             problem.start_heading)
    return traj, check, int(evaluation.n_violations[0]) == 0 and check.feasible


def merge_close_waypoints(path: np.ndarray, tol: float = MERGE_TOLERANCE_M) -> np.ndarray:
    """Drop interior waypoints closer than ``tol`` metres to the previous kept one or to the goal.

    The destination term pulls P_n onto G, often to within micrometres; such a leg carries no route but
    its Bézier has numerically meaningless curvature, and a mission would get two items at one place.
    """
    keep = [path[0]]
    for p in path[1:-1]:  # a handful of waypoints: a loop is clearer than a mask here
        if np.linalg.norm(p - keep[-1]) >= tol and np.linalg.norm(path[-1] - p) >= tol:
            keep.append(p)
    keep.append(path[-1])
    return np.array(keep)


def json_safe(value: Any) -> Any:
    """Replace non-finite floats (an empty map's infinite clearance, say) by None, recursively, so the
    document is strict JSON."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def _phases(opt: OptimiserResult) -> dict[str, Any]:
    """PLAN.json's ``phases`` record for a two-phase (fusion) result; nothing for single-phase ones."""
    from planner.search.fusion import FusionResult

    if not isinstance(opt, FusionResult) or not opt.phases:  # only a fusion result has phases
        return {}
    phases = opt.phases
    doc: dict[str, Any] = {name: {"best_cost": r.best_cost, "iterations": r.iterations, "time_s": r.time_s,
                                  "evaluations": r.evaluations, "stop_reason": r.stop_reason}
                           for name, r in phases.items()}
    doc["winner"] = opt.winner
    return {"phases": doc}


def plan_to_json(result: PlanResult, scenario: Scenario, start_time: float | None = None) -> dict[str, Any]:
    """The PLAN.json document (see README, "PLAN.json"); strict JSON (non-finite numbers become null).
    ``start_time``: the mission time at the start the plan was made for (time-aware threats), if any."""
    ev = result.evaluation
    weights = scenario.planner.weights.by_term()
    traj = result.trajectory
    return json_safe({
        "format": "fuseplan-plan/1",
        "fuseplan_version": fuseplan_version(),  # the fuseplan that wrote it ("unknown" when not installed)
        "scenario": scenario.name,
        "scenario_file": str(scenario.source),
        "status": result.status.value,
        "algorithm": result.algorithm,
        "seed": result.seed,
        "start_time_s": start_time,
        "cost": float(result.cost),
        "cost_terms": {
            **{k: {"value": float(v[0]), "weight": weights[k], "weighted": float(v[0]) * weights[k]}
               for k, v in ev.terms.items()},
            "penalty": float(ev.penalty[0]),
        },
        "stop_reason": result.optimiser.stop_reason,
        "waypoints": result.waypoints.tolist(),
        "trajectory": {
            "spacing_m": scenario.planner.sample_spacing,
            "points": traj.points.tolist(),
            "t_s": traj.times.tolist(),
        },
        "violations": result.violations,
        "violation_locations": result.check.locations,
        "cost_violations": result.cost_violations,
        "metrics": result.metrics(scenario.hazard.d_safe),
        "history": [float(h) for h in result.optimiser.history],
        **_phases(result.optimiser),
        "home": {"lat": scenario.home.lat, "lon": scenario.home.lon, "alt": scenario.home.alt},
        # where the vehicle's home is in the frame (m east, north): the origin, but for a geographic scenario's region
        "launch": [float(v) for v in scenario.launch],
        "vehicle": {"type": scenario.vehicle.type, "cruise_speed": scenario.vehicle.cruise_speed,
                    "min_turn_radius_m": scenario.vehicle.min_turn_radius,
                    "turn_overshoot": scenario.vehicle.turn_overshoot},
        "hazard": {"d_safe": scenario.hazard.d_safe, "d_coll": scenario.hazard.d_coll},
        **_vias(result, scenario),
    })


def _vias(result: PlanResult, scenario: Scenario) -> dict[str, Any]:
    """PLAN.json's ``vias`` (each in the frame's metres and in latitude, longitude and metres above home) and
    ``legs`` records of a route through vias; nothing for a scenario without them."""
    if not len(scenario.vias):
        return {}
    h = scenario.home
    lat, lon, _ = pymap3d.enu2geodetic(scenario.vias[:, 0], scenario.vias[:, 1], 0.0, h.lat, h.lon, h.alt,
                                       ell=pymap3d.Ellipsoid.from_name("wgs84"))
    vias = [{"xyz": [float(v) for v in p], "lat": float(la), "lon": float(lo), "alt_above_home": float(p[2])}
            for p, la, lo in zip(scenario.vias, np.atleast_1d(lat), np.atleast_1d(lon), strict=True)]
    legs = [{"status": r.status.value, "cost": r.cost, "iterations": r.iterations, "time_s": r.time_s,
             "stop_reason": r.stop_reason} for r in result.legs]
    return {"vias": vias, **({"legs": legs} if legs else {})}
