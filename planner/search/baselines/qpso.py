"""Quantum-behaved PSO (Sun, Feng & Xu 2004) on Cartesian waypoints: a baseline of the fusion comparison.

Particles have no velocity. Each iteration, per particle and dimension,

    mbest = mean of the personal bests over the swarm,
    p     = φ pbest + (1 − φ) gbest,                      φ ~ U(0, 1)   (local attractor)
    x     = p ± β |mbest − x| ln(1/u),                    u ~ U(0, 1], sign by a fair coin,

and x is clamped into the box. The contraction–expansion coefficient β falls linearly from
``beta_start`` at the first iteration to ``beta_end`` at the last (``max_iter``), see :func:`qpso_beta`.
The decision space is the Cartesian encoding of :func:`planner.search.encoding.make_encoding` (region box and
altitude band, initialised around the straight S→G line); the budget comes from :class:`SPSOConfig`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.encoding import make_encoding
from planner.search.swarm import OptimiserResult, SwarmState, initial_swarm, run_swarm
from planner.world.config import QPSOConfig, SPSOConfig


def qpso_beta(cfg: QPSOConfig, it: int, max_iter: int) -> float:
    """β for 0-based iteration ``it`` of ``max_iter``: beta_start at it = 0, beta_end at it = max_iter − 1."""
    frac = it / (max_iter - 1) if max_iter > 1 else 1.0
    return cfg.beta_start + (cfg.beta_end - cfg.beta_start) * min(frac, 1.0)


def qpso_step(
    x: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, beta: float, lo: np.ndarray, hi: np.ndarray,
    phi: np.ndarray, u: np.ndarray, coin: np.ndarray,
) -> np.ndarray:
    """One QPSO move. Shapes: x, pbest, phi, u, coin (P, n, 3); gbest, lo, hi (n, 3).

    ``phi`` ~ U(0, 1), ``u`` ~ U(0, 1] and ``coin`` ∈ {0, 1} (1 → +) are passed in so a test can check a
    step by hand.
    """
    mbest = pbest.mean(axis=0)
    p = phi * pbest + (1.0 - phi) * gbest
    sign = np.where(coin > 0, 1.0, -1.0)
    x = p + sign * beta * np.abs(mbest - x) * np.log(1.0 / u)
    return np.clip(x, lo, hi)


class QPSO:
    """Quantum-behaved PSO with the shared Table 6 budget."""

    def __init__(self, pso: SPSOConfig, cfg: QPSOConfig | None = None) -> None:
        self.pso = dataclasses.replace(pso, encoding="cartesian")
        self.cfg = cfg or QPSOConfig()

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Optimise; ``initial_paths`` (k, n + 2, 3) replace the first k random particles (warm start)."""
        pso, cfg = self.pso, self.cfg
        enc = make_encoding(problem, pso)
        x0 = initial_swarm(enc, rng, pso.n_pop, initial_paths)

        def step(it: int, st: SwarmState) -> np.ndarray:
            shape = st.x.shape
            phi = rng.random(shape)
            u = 1.0 - rng.random(shape)  # (0, 1]: ln(1/u) stays finite
            coin = rng.integers(0, 2, shape)
            return qpso_step(st.x, st.pbest_x, st.gbest_x, qpso_beta(cfg, it, pso.max_iter),
                             enc.lo, enc.hi, phi, u, coin)

        return run_swarm("qpso", problem, pso, enc, x0, step, deadline, progress)
