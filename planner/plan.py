"""One entry point: ``plan(problem, settings, rng)`` → :class:`PlanResult` with a status (STYLE: OMPL-like).

Runs the chosen optimiser, smooths the best path (SPEC §6), checks the smoothed trajectory (SPEC §7)
and computes the metrics. A plan whose best path still violates anything is ``infeasible``, never success.
"""

from __future__ import annotations

import enum
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner.alloc import tune_allocator
from planner.checks import (
    CheckResult,
    Trajectory,
    check_trajectory,
    convergence_iteration,
    robustness,
    smooth,
    smoothness,
)
from planner.config import PlannerSettings
from planner.problem import PlanningProblem
from planner.scenario import Scenario
from planner.spso import OptimiserResult, SphericalPSO


class PlanStatus(str, enum.Enum):
    EXACT = "exact"  # feasible, search ended on its own criteria
    APPROXIMATE = "approximate"  # feasible, but the time budget cut the search short
    INFEASIBLE = "infeasible"  # best path still violates a constraint
    TIMEOUT = "timeout"  # budget ran out before any feasible path was found


@dataclass
class PlanResult:
    status: PlanStatus
    algorithm: str
    seed: int | None
    waypoints: np.ndarray  # (N, 3) ENU metres, start and goal included
    trajectory: Trajectory
    check: CheckResult
    optimiser: OptimiserResult
    plan_time_s: float

    @property
    def feasible(self) -> bool:
        return self.status in (PlanStatus.EXACT, PlanStatus.APPROXIMATE)

    @property
    def cost(self) -> float:
        return self.optimiser.cost

    @property
    def violations(self) -> dict[str, int]:
        """Per category: what the trajectory check found, or the cost's count on the waypoint path if higher."""
        ev = self.optimiser.evaluation.violations
        return {k: max(self.check.counts.get(k, 0), int(ev.get(k, np.zeros(1))[0]))
                for k in self.check.counts}

    def metrics(self, d_safe: float) -> dict[str, float | int]:
        return {
            "length_m": self.trajectory.length,
            "waypoint_length_m": float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum()),
            "smoothness": smoothness(self.waypoints),
            "robustness": robustness(self.check.clearance, self.trajectory.curvature, d_safe),
            "min_clearance_m": self.check.min_clearance,
            "plan_time_s": self.plan_time_s,
            "convergence_iteration": convergence_iteration(self.optimiser.history),
            "iterations": self.optimiser.iterations,
            "evaluations": self.optimiser.evaluations,
        }


def problem_from_scenario(scenario: Scenario, start_time: float | None = None) -> PlanningProblem:
    """The scenario's start→goal problem; ``start_time`` (s) makes dynamic threats count (SPEC §4)."""
    if start_time is None and len(scenario.environment.threats):
        start_time = 0.0
    s = scenario.planner
    return PlanningProblem(scenario.environment, scenario.start, scenario.goal, scenario.vehicle,
                           scenario.hazard, s.weights, s.penalty, start_time)


def plan(
    problem: PlanningProblem, settings: PlannerSettings, rng: np.random.Generator,
    initial_paths: np.ndarray | None = None, budget_s: float | None = None, seed: int | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> PlanResult:
    """Plan a route; every random choice comes from ``rng``. ``budget_s`` bounds the search time."""
    tune_allocator()
    t0 = time.perf_counter()
    if settings.algorithm != "spso":
        raise ValueError(f"unknown algorithm {settings.algorithm!r}")
    opt = SphericalPSO(settings.pso).run(problem, rng, initial_paths=initial_paths, budget_s=budget_s,
                                         progress=progress)
    timed = problem.start_time is not None and len(problem.env.threats) > 0
    traj = smooth(opt.path, settings.sample_spacing, problem.vehicle.cruise_speed,
                  problem.start_time or 0.0)
    check = check_trajectory(traj, opt.path, problem.env, problem.hazard, problem.vehicle, timed)
    path_ok = int(opt.evaluation.n_violations[0]) == 0
    feasible = path_ok and check.feasible
    if opt.stop_reason == "timeout":
        status = PlanStatus.APPROXIMATE if feasible else PlanStatus.TIMEOUT
    else:
        status = PlanStatus.EXACT if feasible else PlanStatus.INFEASIBLE
    return PlanResult(status, settings.algorithm, seed, opt.path, traj, check, opt,
                      time.perf_counter() - t0)


def plan_to_json(result: PlanResult, scenario: Scenario) -> dict[str, Any]:
    """The PLAN.json document (see README, "PLAN.json")."""
    ev = result.optimiser.evaluation
    w = scenario.planner.weights
    weights = {"J1": w.length, "J2": w.hazard, "J3": w.altitude, "J4": w.smoothness, "J5": w.destination}
    traj = result.trajectory
    return {
        "format": "fuseplan-plan/1",
        "scenario": scenario.name,
        "status": result.status.value,
        "algorithm": result.algorithm,
        "seed": result.seed,
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
        "metrics": result.metrics(scenario.hazard.d_safe),
        "history": [float(h) for h in result.optimiser.history],
        "home": {"lat": scenario.home.lat, "lon": scenario.home.lon, "alt": scenario.home.alt},
        "vehicle": {"type": scenario.vehicle.type, "cruise_speed": scenario.vehicle.cruise_speed,
                    "min_turn_radius_m": scenario.vehicle.min_turn_radius},
        "hazard": {"d_safe": scenario.hazard.d_safe, "d_coll": scenario.hazard.d_coll},
    }
