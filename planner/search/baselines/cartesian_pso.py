"""Standard global-best PSO on Cartesian waypoints: the plain-PSO baseline of the fusion comparison
(docs/method.md §10.2).

It is :class:`planner.search.spso.SphericalPSO` with the ablation switches of docs/method.md §6.3 set to the
textbook algorithm, so this module only fixes those switches: ``encoding = "cartesian"`` (n independent (x, y, z)
waypoints in the region box and altitude band, initialised around the straight S→G line), ``reflection = off`` (a
coordinate leaving its bounds is clamped and keeps its velocity) and the damped inertia w0·w_damp^t
(``inertia = "damped"``, ``damping = on``; the adaptive eq. 9 inertia is SPSO's own and is not used).
w0, w_damp, c1, c2, velocity_limit and the budget (n_pop, max_iter, n_waypoints, stagnation_iters)
come from the shared :class:`SPSOConfig`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.spso import SphericalPSO
from planner.search.swarm import OptimiserResult
from planner.world.config import SPSOConfig


class CartesianPSO:
    """Global-best PSO over Cartesian waypoints with the shared Table 6 budget."""

    def __init__(self, pso: SPSOConfig) -> None:
        self.pso = dataclasses.replace(pso, encoding="cartesian", reflection=False, inertia="damped",
                                       damping=True)

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Optimise; ``initial_paths`` (k, n + 2, 3) replace the first k random particles (warm start)."""
        return SphericalPSO(self.pso).run(problem, rng, initial_paths, deadline, progress=progress)
