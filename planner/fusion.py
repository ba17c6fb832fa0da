"""The fusion planner (SPEC §5, §P Algorithm 1): SPSO until its switch criterion fires, then GKDM-seeded
ant-colony refinement of its best route; the better of the two is the answer, so the fusion never
returns a higher cost than its own SPSO phase."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner.aco import AntColony
from planner.config import PlannerSettings
from planner.problem import PlanningProblem
from planner.spso import SphericalPSO
from planner.swarm import OptimiserResult


@dataclass
class PhaseRecord:
    best_cost: float
    iterations: int
    time_s: float
    evaluations: int
    stop_reason: str


@dataclass
class FusionResult(OptimiserResult):
    """An :class:`OptimiserResult` whose history is the PSO iterations then the ACO iterations (best so
    far), with a record per phase and which phase's route won."""

    phases: dict[str, PhaseRecord] = field(default_factory=dict)
    winner: str = "pso"


class Fusion:
    def __init__(self, settings: PlannerSettings) -> None:
        self.settings = settings

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        budget_s: float | None = None, progress: Callable[[int, int, float], None] | None = None,
    ) -> FusionResult:
        """Phase I SPSO (its stop criteria are the switch), phase II ACO on what budget is left."""
        t0 = time.perf_counter()
        s = self.settings
        pso = SphericalPSO(s.pso).run(problem, rng, initial_paths=initial_paths, budget_s=budget_s,
                                      progress=progress)
        left = None if budget_s is None else max(budget_s - (time.perf_counter() - t0), 0.0)
        aco = AntColony(s.aco).run(problem, rng, pso.path, pso.cost, budget_s=left)
        winner = aco if aco.cost < pso.cost else pso
        history = pso.history + [min(pso.cost, h) for h in aco.history]
        stop = "timeout" if "timeout" in (pso.stop_reason, aco.stop_reason) else pso.stop_reason
        phases = {name: PhaseRecord(r.cost, r.iterations, r.time_s, r.evaluations, r.stop_reason)
                  for name, r in (("pso", pso), ("aco", aco))}
        return FusionResult(winner.path, winner.cost, winner.evaluation, history,
                            pso.iterations + aco.iterations, stop, time.perf_counter() - t0,
                            pso.evaluations + aco.evaluations, pso.state, phases,
                            "aco" if winner is aco else "pso")
