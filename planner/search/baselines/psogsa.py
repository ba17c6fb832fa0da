"""PSO–gravitational search hybrid PSOGSA (Mirjalili & Hashim 2010) on Cartesian waypoints: a baseline of
the fusion comparison.

Each particle has a mass from its current cost (lower cost → heavier); the gravitational search part
pulls every particle towards the heavy ones, the PSO part towards the global best:

    m_i = (f_i − worst) / (best − worst),   M = m / Σ m        (all 1/P when the swarm is flat)
    G(t) = g0 exp(−alpha t / T)
    a_i = Σ_j r_ij G M_j (x_j − x_i) / (R_ij + ε),            r_ij ~ U(0, 1), R_ij = ‖x_i − x_j‖
    v  ← w v + c1 r a + c2 r' (gbest − x),  |v_d| ≤ velocity_limit (hi_d − lo_d);  x ← clamp(x + v)

Positions are whole particles flattened to vectors (n·3 metres); R and a are computed with P×P matrix
products, on one BLAS thread: a multi-threaded product adds in another order, so its last bits (and, through
the search's chaos, the plan) would depend on the machine's core count, a process pool's or a dask worker's
thread setting (which pins BLAS to one thread).

The paper draws w at random; here w follows the shared damped schedule w0·w_damp^t of :class:`SPSOConfig`
(as SPSO and the Cartesian PSO baseline do), so the only difference between the PSO baselines is the
gravitational term, not the inertia. A coordinate leaving its bounds is clamped and keeps its velocity.
g0, alpha, c1, c2 come from :class:`PSOGSAConfig`; the budget from SPSOConfig.

The gravitational acceleration is computed on positions normalised to the search box ([0, 1] per
coordinate) and scaled back to metres. Mirjalili's G0 = 1 was set for benchmark functions on ranges of a
few hundred units; in metres on a 1 km map, |a| ≤ G ≤ 1 m per iteration would leave the GSA term
effectively off (measured: no better than G0 = 0), which would tune the baseline down.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from threadpoolctl import threadpool_limits

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.encoding import make_encoding
from planner.search.swarm import OptimiserResult, SwarmState, damped_inertia, initial_swarm, run_swarm
from planner.world.config import PSOGSAConfig, SPSOConfig

_EPS = 1e-9  # m, keeps a_i finite when two particles coincide (then x_j − x_i = 0 as well)


def gravity(cfg: PSOGSAConfig, it: int, max_iter: int) -> float:
    """G(t) = g0 exp(−alpha t / T) for iteration t = ``it``, T = ``max_iter``."""
    return cfg.g0 * math.exp(-cfg.alpha * it / max_iter)


def masses(f: np.ndarray) -> np.ndarray:
    """Normalised masses M (P,) from costs f (P,): best particle heaviest, worst 0, Σ M = 1."""
    best, worst = float(f.min()), float(f.max())
    if not worst > best:
        return np.full(len(f), 1.0 / len(f))
    m = (f - worst) / (best - worst)
    return m / m.sum()


def gsa_acceleration(x: np.ndarray, mass: np.ndarray, g: float, r: np.ndarray) -> np.ndarray:
    """a_i = Σ_j r_ij G M_j (x_j − x_i) / (R_ij + ε). Shapes: x (P, D), mass (P,), r (P, P) → (P, D)."""
    c = x - x.mean(axis=0)  # centred: x_j − x_i = c_j − c_i with less cancellation below
    sq = np.einsum("pd,pd->p", c, c)
    dist = np.sqrt(np.maximum(sq[:, None] + sq[None, :] - 2.0 * (c @ c.T), 0.0))
    k = r * (g * mass)[None, :] / (dist + _EPS)  # (P, P) pull of j on i per metre of separation
    np.fill_diagonal(k, 0.0)  # no self-pull (x_i − x_i = 0; k_ii ~ 1/ε would only add round-off)
    return k @ c - k.sum(axis=1)[:, None] * c


def psogsa_step(
    x: np.ndarray, v: np.ndarray, f: np.ndarray, gbest: np.ndarray, g: float, w: float, c1: float,
    c2: float, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray, r_pair: np.ndarray, r1: np.ndarray,
    r2: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One PSOGSA update. Shapes: x, v, r1, r2 (P, n, 3); f (P,); gbest, lo, hi, vmax (n, 3); r_pair (P, P)."""
    p = len(x)
    span = np.where(hi > lo, hi - lo, 1.0)  # gravity acts in box-normalised coordinates, see module doc
    a = gsa_acceleration(((x - lo) / span).reshape(p, -1), masses(f), g, r_pair).reshape(x.shape) * span
    v = w * v + c1 * r1 * a + c2 * r2 * (gbest - x)
    v = np.clip(v, -vmax, vmax)
    return np.clip(x + v, lo, hi), v


class PSOGSA:
    """PSO–GSA hybrid with the shared Table 6 budget."""

    def __init__(self, pso: SPSOConfig, cfg: PSOGSAConfig | None = None) -> None:
        self.pso = dataclasses.replace(pso, encoding="cartesian")
        self.cfg = cfg or PSOGSAConfig()

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Optimise; ``initial_paths`` (k, n + 2, 3) replace the first k random particles (warm start)."""
        pso, cfg = self.pso, self.cfg
        enc = make_encoding(problem, pso)
        vmax = pso.velocity_limit * (enc.hi - enc.lo)
        x0 = initial_swarm(enc, rng, pso.n_pop, initial_paths)

        def step(it: int, st: SwarmState) -> np.ndarray:
            p = len(st.x)
            r_pair = rng.random((p, p))
            r1 = rng.random(st.x.shape)
            r2 = rng.random(st.x.shape)
            st.w = damped_inertia(pso, it)
            v = st.v
            assert v is not None  # run_swarm gives the swarm its velocities (v0)
            x, st.v = psogsa_step(st.x, v, st.f, st.gbest_x, gravity(cfg, it, pso.max_iter), st.w,
                                  cfg.c1, cfg.c2, enc.lo, enc.hi, vmax, r_pair, r1, r2)
            return x

        with threadpool_limits(limits=1, user_api="blas"):  # same seed, same plan, wherever it runs
            return run_swarm("psogsa", problem, pso, enc, x0, step, deadline, progress, v0=np.zeros_like(x0))
