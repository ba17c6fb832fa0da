"""Spherical-vector PSO (docs/method.md §6, paper Tables 2, 3, 5) with the Table 3 ablation switches.

:func:`pso_step` is the pure update (injectable r1, r2) so a test can check one step by hand.
:class:`SphericalPSO` runs it through the shared swarm loop (:func:`planner.search.swarm.run_swarm`), which
keeps the bests in a :class:`SwarmState` and stops on the termination criteria.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from planner import kernel
from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.encoding import Encoding, make_encoding
from planner.search.swarm import (  # noqa: F401  (re-exported: the result types used to live here)
    OptimiserResult,
    SwarmState,
    damped_inertia,
    diversity,
    initial_swarm,
    run_swarm,
)
from planner.world.config import SPSOConfig


def pso_velocity(
    x: np.ndarray, v: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, w: float | np.ndarray, c1: float,
    c2: float, vmax: float | np.ndarray, r1: np.ndarray, r2: np.ndarray,
) -> np.ndarray:
    """v ← w v + c1 r1 (pbest − x) + c2 r2 (gbest − x), clipped to ±vmax (docs/method.md §6.1); shapes broadcast."""
    return np.clip(w * v + c1 * r1 * (pbest - x) + c2 * r2 * (gbest - x), -vmax, vmax)


def pso_step(
    x: np.ndarray, v: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, w: float | np.ndarray,
    c1: float, c2: float, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray, reflection: bool,
    r1: np.ndarray, r2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One velocity/position update per dimension (docs/method.md §6.1).

    v ← w v + c1 r1 (pbest − x) + c2 r2 (gbest − x), clipped to ±vmax; x ← x + v. A coordinate that
    leaves [lo, hi] is put on the bound; with ``reflection`` its velocity is negated, else kept (V4).
    Shapes: x, v, pbest, r1, r2 (P, n, 3); gbest, lo, hi, vmax (n, 3); w scalar or (P, 1, 1).
    """
    if kernel.chosen() == "compiled":  # the same arithmetic in one compiled pass (planner/kernel/swarm.py)
        return kernel.pso_step(x, v, pbest, gbest, w, c1, c2, lo, hi, vmax, reflection, r1, r2)
    v = pso_velocity(x, v, pbest, gbest, w, c1, c2, vmax, r1, r2)
    x = x + v
    outside = (x < lo) | (x > hi)
    x = np.clip(x, lo, hi)
    if reflection:
        v = np.where(outside, -v, v)
    return x, v


def inertia(cfg: SPSOConfig, it: int, f: np.ndarray, gbest_f: float) -> float | np.ndarray:
    """Inertia for iteration ``it`` (0-based): damped w0·w_damp^it, fixed w0 (damping off), or adaptive
    eq. 9 per particle ω = ω_max − (ω_max − ω_min)(t/T) exp(−(f − f_best)² / (2σ_f²))."""
    if not cfg.damping:
        return cfg.w0
    if cfg.inertia == "damped":
        return damped_inertia(cfg, it)
    sigma = float(np.std(f))
    g = np.exp(-((f - gbest_f) ** 2) / (2 * sigma**2)) if sigma > 0 else np.ones_like(f)
    return (cfg.w_max - (cfg.w_max - cfg.w_min) * (it / cfg.max_iter) * g)[:, None, None]


class SphericalPSO:
    """SPSO optimiser; ``cfg.encoding = "cartesian"`` etc. give the Table 3 ablation variants."""

    def __init__(self, cfg: SPSOConfig) -> None:
        self.cfg = cfg

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, encoding: Encoding | None = None,
        progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Optimise; ``initial_paths`` (k, n + 2, 3) replace the first k random particles (warm start)."""
        cfg = self.cfg
        enc = encoding or make_encoding(problem, cfg)
        vmax = cfg.velocity_limit * (enc.hi - enc.lo)
        x0 = initial_swarm(enc, rng, cfg.n_pop, initial_paths)

        def step(it: int, st: SwarmState) -> np.ndarray:
            w = inertia(cfg, it, st.f, st.gbest_f)
            r1 = rng.random(st.x.shape)
            r2 = rng.random(st.x.shape)
            v = st.v
            assert v is not None  # run_swarm gives the swarm its velocities (v0)
            x, st.v = pso_step(st.x, v, st.pbest_x, st.gbest_x, w, cfg.c1, cfg.c2,
                               enc.lo, enc.hi, vmax, cfg.reflection, r1, r2)
            st.w = float(np.mean(w))
            return x

        return run_swarm("spso", problem, cfg, enc, x0, step, deadline, progress, v0=np.zeros_like(x0))
