"""The fusion planner (docs/method.md §9, paper Algorithm 1): SPSO until its switch criterion fires, then
GKDM-seeded ant-colony refinement of its best route; the better of the two is the answer, so the fusion never
returns a higher cost than its own SPSO phase."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner.problem import PlanningProblem
from planner.search.aco import AntColony
from planner.search.spso import SphericalPSO
from planner.search.swarm import OptimiserResult
from planner.world.config import PlannerSettings


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


MIN_ACO_BUDGET_S = 0.005  # below this a colony cannot even build its lattice


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
        pso_budget = None if budget_s is None else budget_s * (1.0 - s.aco.budget_share)
        pso = SphericalPSO(s.pso).run(problem, rng, initial_paths=initial_paths, budget_s=pso_budget,
                                      progress=progress)
        left = None if budget_s is None else budget_s - (time.perf_counter() - t0)
        if left is not None and left < MIN_ACO_BUDGET_S:  # no time for a colony: SPSO's answer stands
            return self._finish(pso, None, t0)
        aco = AntColony(s.aco).run(problem, rng, pso.path, pso.cost, budget_s=left, progress=progress)
        return self._finish(pso, aco, t0)

    @staticmethod
    def _finish(pso: OptimiserResult, aco: OptimiserResult | None, t0: float) -> FusionResult:
        """Better of the two phases; ``aco`` None when the budget left no time for it."""
        done = [("pso", pso)] + ([("aco", aco)] if aco is not None else [])
        phases = {name: PhaseRecord(r.cost, r.iterations, r.time_s, r.evaluations, r.stop_reason) for name, r in done}
        phases.setdefault("aco", PhaseRecord(pso.cost, 0, 0.0, 0, "skipped: no time left"))
        winner = aco if aco is not None and aco.cost < pso.cost else pso
        history = pso.history + [min(pso.cost, h) for h in (aco.history if aco is not None else [])]
        stop = "timeout" if any(r.stop_reason == "timeout" for _, r in done) else pso.stop_reason
        return FusionResult(winner.path, winner.cost, winner.evaluation, history,
                            sum(r.iterations for _, r in done), stop, time.perf_counter() - t0,
                            sum(r.evaluations for _, r in done), pso.state, phases,
                            "aco" if winner is aco else "pso")
