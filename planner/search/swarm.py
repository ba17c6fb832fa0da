"""What every swarm optimiser shares: the personal/global-best memory, the loop with its stop criteria,
and the result it returns.

An optimiser supplies a decision space (an object with ``sample``, ``encode``, ``decode``, ``lo`` and
``hi``, like :class:`planner.search.encoding.Encoding`) and a *step*: a function ``(it, state) → new positions``
that moves the swarm once (it may keep velocities in ``state.v``). :func:`run_swarm` evaluates, updates
the bests, records the history and stops on ``max_iterations``, ``stagnation``, ``diversity`` or
``timeout`` (:mod:`planner.search.termination`; the deadline is checked before each iteration, against its
predicted duration). Used by SPSO and all four baselines, so they stop and report alike.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import Evaluation, PlanningProblem
from planner.search.termination import (
    AnyOf,
    Diversity,
    MaxIterations,
    Progress,
    Settled,
    Stagnation,
    WallClock,
)
from planner.world.config import SPSOConfig

log = logging.getLogger(__name__)


class DecisionSpace(Protocol):
    """A swarm lives in a box ``lo``/``hi`` (shape of one particle); ``decode`` gives full paths."""

    @property
    def lo(self) -> np.ndarray: ...  # read-only: the spaces are frozen dataclasses

    @property
    def hi(self) -> np.ndarray: ...

    def decode(self, x: np.ndarray) -> np.ndarray: ...  # (P, …) → paths (P, n + 2, 3)

    def encode(self, paths: np.ndarray) -> np.ndarray: ...  # paths (k, n + 2, 3) → (k, …)

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray: ...  # → (count, …)


@dataclass
class SwarmState:
    """Positions, costs and best-so-far memory of a swarm; arrays (P, …) in the decision space."""

    x: np.ndarray  # (P, …) positions
    f: np.ndarray  # (P,) current costs
    pbest_x: np.ndarray
    pbest_f: np.ndarray
    gbest_x: np.ndarray  # (…) one particle
    gbest_f: float
    gbest_eval: Evaluation  # breakdown of the gbest path (batch of one)
    v: np.ndarray | None = None  # (P, …) velocities, for the optimisers that have them
    w: float = math.nan  # inertia of the last step (mean over particles if per particle)
    stagnant: int = 0  # iterations since gbest last improved
    tol: float = 0.0  # relative improvement below which an iteration counts as stagnant
    feasible: int = 0  # iterations since gbest became feasible (0: it is not)

    @classmethod
    def start(cls, x: np.ndarray, ev: Evaluation) -> SwarmState:
        """Memory of a freshly evaluated swarm: pbest = x, gbest = its best particle."""
        f = ev.total
        ib = int(np.argmin(f))
        return cls(x, f, x.copy(), f.copy(), x[ib].copy(), float(f[ib]), take(ev, ib))

    def observe(self, x: np.ndarray, ev: Evaluation) -> None:
        """Move to positions ``x`` with costs ``ev``; update pbests, gbest and the stagnation count."""
        self.x = x
        self.f = ev.total
        better = self.f < self.pbest_f
        np.copyto(self.pbest_x, x, where=better.reshape(-1, *(1,) * (x.ndim - 1)))
        np.copyto(self.pbest_f, self.f, where=better)
        ib = int(np.argmin(self.f))
        if self.f[ib] < self.gbest_f:
            # once feasible, an improvement by less than ``tol`` of the cost still counts as stagnation
            small = self.gbest_f - self.f[ib] < self.tol * abs(self.gbest_f) and ev.penalty[ib] == 0.0
            self.gbest_f = float(self.f[ib])
            self.gbest_x = x[ib].copy()
            self.gbest_eval = take(ev, ib)
            self.stagnant = self.stagnant + 1 if small else 0
        else:
            self.stagnant += 1
        self.feasible = self.feasible + 1 if int(self.gbest_eval.n_violations[0]) == 0 else 0


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


Step = Callable[[int, SwarmState], np.ndarray]  # (0-based iteration, state) → new positions (P, …)


def initial_swarm(space: DecisionSpace, rng: np.random.Generator, n_pop: int,
                  initial_paths: np.ndarray | None = None) -> np.ndarray:
    """``n_pop`` sampled particles; ``initial_paths`` (k, n + 2, 3) replace the first k (warm start)."""
    x = space.sample(rng, n_pop)
    if initial_paths is not None and len(initial_paths):
        seeds = space.encode(np.asarray(initial_paths, dtype=float)[:n_pop])
        x[: len(seeds)] = seeds
    return x


def diversity(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """σ²(t) = mean ‖x_i − x̄‖² in coordinates normalised to [0, 1] by the bounds."""
    span = np.where(hi > lo, hi - lo, 1.0)
    u = (x - lo) / span
    return float(np.mean(np.sum((u - u.mean(axis=0)) ** 2, axis=tuple(range(1, u.ndim)))))


def run_swarm(
    name: str, problem: PlanningProblem, budget: SPSOConfig, space: DecisionSpace, x0: np.ndarray,
    step: Step, deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    v0: np.ndarray | None = None,
) -> OptimiserResult:
    """Evaluate ``x0``, then apply ``step`` until a stop criterion fires.

    ``budget`` gives max_iter, stagnation_iters and diversity_min (the shared Table 6 budget);
    ``deadline`` adds a wall-clock limit that counts the initial evaluation too and is kept *before* each
    iteration: the search stops when the next iteration, predicted from the ones measured so far (the initial
    evaluation standing in for the first), would end after it (:class:`WallClock`), so a budgeted search ends
    within it unless its initial evaluation alone does not fit. Without a budget (:data:`planner.deadline.NEVER`)
    the deadline never fires and the search is exactly the unbudgeted one. ``progress(it, max_iter, best)`` is
    called after every iteration. ``time_s`` is measured on the deadline's clock (tests inject a fake).
    Evaluations = n_pop × (iterations + 1).
    """
    clock = deadline.clock
    t0 = clock()
    wall = WallClock(deadline)  # its laps start now: the first one is the initial evaluation
    stop = AnyOf([MaxIterations(budget.max_iter), Stagnation(budget.stagnation_iters),
                  Diversity(budget.diversity_min), Settled(budget.feasible_iters), wall])
    st = SwarmState.start(x0, problem.evaluate(space.decode(x0)))
    st.v = v0
    st.tol = budget.stagnation_tol
    history = [st.gbest_f]
    it = 0
    wall.lap()  # the initial evaluation: the first guess at what an iteration costs
    if wall.done():  # not even one iteration fits
        stop.fired = wall.name
    else:
        while True:
            x = step(it, st)
            st.observe(x, problem.evaluate(space.decode(x)))
            it += 1
            history.append(st.gbest_f)
            # σ² costs a pass over the swarm; only the diversity criterion reads it
            div = diversity(st.x, space.lo, space.hi) if budget.diversity_min > 0 else math.nan
            prog = Progress(it, st.gbest_f, st.stagnant, div, stop.elapsed(), st.feasible)
            if progress is not None:
                progress(it, budget.max_iter, st.gbest_f)
            wall.lap()
            if stop.done(prog):
                break
    log.debug("%s stopped after %d iterations (%s), cost %.3f", name, it, stop.fired, st.gbest_f)
    path = space.decode(st.gbest_x[None])[0]
    return OptimiserResult(path, st.gbest_f, st.gbest_eval, history, it, stop.fired or "",
                           clock() - t0, len(x0) * (it + 1), st)


def take(ev: Evaluation, i: int) -> Evaluation:
    """The i-th particle's breakdown as a batch of one."""
    sl = slice(i, i + 1)
    return Evaluation(ev.total[sl].copy(), {k: v[sl].copy() for k, v in ev.terms.items()},
                      ev.penalty[sl].copy(), {k: v[sl].copy() for k, v in ev.violations.items()})


def damped_inertia(cfg: SPSOConfig, it: int) -> float:
    """w = w0 · w_damp^it for 0-based iteration ``it`` (Table 5)."""
    return cfg.w0 * cfg.w_damp**it

