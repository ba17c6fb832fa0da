"""Spherical-vector PSO (SPEC §3, paper Tables 2, 3, 5) with the Table 3 ablation switches.

State lives in :class:`SwarmState`; :func:`pso_step` is the pure update (injectable r1, r2) so a test can
check one step by hand. :class:`SphericalPSO` runs the loop against a :class:`PlanningProblem`.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from planner.config import SPSOConfig
from planner.encoding import Encoding, make_encoding
from planner.problem import Evaluation, PlanningProblem
from planner.termination import AnyOf, Diversity, MaxIterations, Progress, Stagnation, WallClock

log = logging.getLogger(__name__)


def pso_step(
    x: np.ndarray, v: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, w: float | np.ndarray,
    c1: float, c2: float, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray, reflection: bool,
    r1: np.ndarray, r2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One velocity/position update per dimension (SPEC §3).

    v ← w v + c1 r1 (pbest − x) + c2 r2 (gbest − x), clipped to ±vmax; x ← x + v. A coordinate that
    leaves [lo, hi] is put on the bound; with ``reflection`` its velocity is negated, else kept (V4).
    Shapes: x, v, pbest, r1, r2 (P, n, 3); gbest, lo, hi, vmax (n, 3); w scalar or (P, 1, 1).
    """
    v = w * v + c1 * r1 * (pbest - x) + c2 * r2 * (gbest - x)
    v = np.clip(v, -vmax, vmax)
    x = x + v
    outside = (x < lo) | (x > hi)
    x = np.clip(x, lo, hi)
    if reflection:
        v = np.where(outside, -v, v)
    return x, v


@dataclass
class SwarmState:
    x: np.ndarray  # (P, n, 3) positions
    v: np.ndarray  # (P, n, 3) velocities
    f: np.ndarray  # (P,) current costs
    pbest_x: np.ndarray
    pbest_f: np.ndarray
    gbest_x: np.ndarray  # (n, 3)
    gbest_f: float
    gbest_eval: Evaluation  # breakdown of the gbest path (batch of one)
    w: float


@dataclass
class OptimiserResult:
    """Best path found and how the search went."""

    path: np.ndarray  # (n + 2, 3) ENU metres, start and goal included
    cost: float
    evaluation: Evaluation  # batch of one
    history: list[float]  # best cost after initialisation (index 0) and after each iteration
    iterations: int
    stop_reason: str
    time_s: float
    evaluations: int
    state: SwarmState | None = field(default=None, repr=False)


def inertia(cfg: SPSOConfig, it: int, f: np.ndarray, gbest_f: float) -> float | np.ndarray:
    """Inertia for iteration ``it`` (0-based): damped w0·w_damp^it, fixed w0 (damping off), or adaptive
    eq. 9 per particle ω = ω_max − (ω_max − ω_min)(t/T) exp(−(f − f_best)² / (2σ_f²))."""
    if not cfg.damping:
        return cfg.w0
    if cfg.inertia == "damped":
        return cfg.w0 * cfg.w_damp**it
    sigma = float(np.std(f))
    g = np.exp(-((f - gbest_f) ** 2) / (2 * sigma**2)) if sigma > 0 else np.ones_like(f)
    return (cfg.w_max - (cfg.w_max - cfg.w_min) * (it / cfg.max_iter) * g)[:, None, None]


def diversity(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """σ²(t) = mean ‖x_i − x̄‖² in coordinates normalised to [0, 1] by the bounds."""
    span = np.where(hi > lo, hi - lo, 1.0)
    u = (x - lo) / span
    return float(np.mean(np.sum((u - u.mean(axis=0)) ** 2, axis=(1, 2))))


class SphericalPSO:
    """SPSO optimiser; ``cfg.encoding = "cartesian"`` etc. give the Table 3 ablation variants."""

    def __init__(self, cfg: SPSOConfig) -> None:
        self.cfg = cfg

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        budget_s: float | None = None, encoding: Encoding | None = None,
        progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Optimise; ``initial_paths`` (k, n + 2, 3) replace the first k random particles (warm start)."""
        cfg = self.cfg
        t0 = time.perf_counter()
        stop = AnyOf([MaxIterations(cfg.max_iter), Stagnation(cfg.stagnation_iters),
                      Diversity(cfg.diversity_min)])  # its clock starts now: the budget counts init too
        enc = encoding or make_encoding(problem, cfg)
        vmax = cfg.velocity_limit * (enc.hi - enc.lo)
        x = enc.sample(rng, cfg.n_pop)
        if initial_paths is not None and len(initial_paths):
            seeds = enc.encode(np.asarray(initial_paths)[: cfg.n_pop])
            x[: len(seeds)] = seeds
        v = np.zeros_like(x)
        ev = problem.evaluate(enc.decode(x))
        f = ev.total
        ib = int(np.argmin(f))
        st = SwarmState(x, v, f, x.copy(), f.copy(), x[ib].copy(), float(f[ib]),
                        _take(ev, ib), cfg.w0)
        history = [st.gbest_f]
        if budget_s is not None:
            stop.criteria.append(WallClock(budget_s))
        stagnant = 0
        it = 0
        while True:
            w = inertia(cfg, it, st.f, st.gbest_f)
            r1 = rng.random(x.shape)
            r2 = rng.random(x.shape)
            st.x, st.v = pso_step(st.x, st.v, st.pbest_x, st.gbest_x, w, cfg.c1, cfg.c2,
                                  enc.lo, enc.hi, vmax, cfg.reflection, r1, r2)
            ev = problem.evaluate(enc.decode(st.x))
            st.f = ev.total
            better = st.f < st.pbest_f
            st.pbest_x[better] = st.x[better]
            st.pbest_f[better] = st.f[better]
            ib = int(np.argmin(st.f))
            if st.f[ib] < st.gbest_f:
                st.gbest_f = float(st.f[ib])
                st.gbest_x = st.x[ib].copy()
                st.gbest_eval = _take(ev, ib)
                stagnant = 0
            else:
                stagnant += 1
            st.w = float(np.mean(w))
            it += 1
            history.append(st.gbest_f)
            prog = Progress(it, st.gbest_f, stagnant, diversity(st.x, enc.lo, enc.hi), stop.elapsed())
            if progress is not None:
                progress(it, cfg.max_iter, st.gbest_f)
            if stop.done(prog):
                break
        log.debug("spso stopped after %d iterations (%s), cost %.3f", it, stop.fired, st.gbest_f)
        path = enc.decode(st.gbest_x[None])[0]
        return OptimiserResult(path, st.gbest_f, st.gbest_eval, history, it, stop.fired or "",
                               time.perf_counter() - t0, cfg.n_pop * (it + 1), st)


def _take(ev: Evaluation, i: int) -> Evaluation:
    """The i-th particle's breakdown as a batch of one."""
    sl = slice(i, i + 1)
    return Evaluation(ev.total[sl].copy(), {k: v[sl].copy() for k, v in ev.terms.items()},
                      ev.penalty[sl].copy(), {k: v[sl].copy() for k, v in ev.violations.items()})
