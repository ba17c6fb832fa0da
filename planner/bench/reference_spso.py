"""A plain numpy SPSO after Phung & Ha (spherical-vector PSO, the method the paper builds on): the naive speed
reference of ``fuseplan bench speed`` (issue 16): "a plain numpy port takes X s; ours takes Y s".

Written from the method's description (the paper's §4.2 and docs/method.md §3, §4, §6), not from any published code.
It is deliberately the simple original, vectorised over the swarm and nothing more:

- a particle is n = 10 spherical vectors (r, ψ, φ), one per leg: P_k = P_{k−1} + r_k (cos ψ cos φ, cos ψ sin φ,
  sin ψ), P_0 = S; the path is S, P_1 … P_n, G (the last leg to the goal counts like any other). Waypoints are
  clamped into the map's x/y box when decoded;
- bounds r ∈ [0, 2‖SG‖/n], ψ ∈ [−π/4, π/4], φ ∈ φ0 ± π/4 (φ0 the bearing S→G); velocity ≤ 0.5 × each range;
  inertia w = 1 damped by 0.98 per iteration, c1 = c2 = 1.5; a coordinate leaving its bounds is put on the bound
  and its velocity negated;
- cost F = b1 J1 + b2 J2 + b3 J3 + b4 J4 with
  J1 = Σ leg lengths (m);
  J2 = Σ over legs × cylinders of T(d), d the horizontal distance from the leg to the cylinder's surface (the
  cylinders are unlimited in height): 0 for d ≥ d_safe, d_safe − d for d_coll ≤ d < d_safe, a collision below;
  J3 = Σ over waypoints P_1 … P_n of |z − (z_min + z_max)/2|, a violation outside [z_min, z_max];
  J4 = Σ over interior points of the horizontal turning angle and |Δ climb angle| (rad);
- the original's simple penalty: every violation (a leg × cylinder collision, a waypoint outside the band) adds
  one flat constant in place of its ∞ (finite, so costs stay comparable; no depth, so no direction out of it,
  which is what fuseplan's depth-scaled penalties add).

What it does not model, and fuseplan's cost does: spheres, radars, terrain, finite cylinder tops, moving threats,
the flown Bézier curve (its deviation, curvature and climb limits), the map bounds as a cost, the destination term.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from planner.world.scenario import Scenario

_ANGLE = np.pi / 4  # ψ and the φ cone half-width (the original's angle range)
_EPS = 1e-12


@dataclass(frozen=True)
class ReferenceWorld:
    """What the reference reads of a scenario: start, goal (3,) m; the map's x/y size (m); the altitude band (m);
    cylinders (K, 3) as x, y, radius (m); d_safe and d_coll (m from a cylinder's surface)."""

    start: np.ndarray
    goal: np.ndarray
    size_x: float
    size_y: float
    z_min: float
    z_max: float
    cylinders: np.ndarray
    d_safe: float
    d_coll: float

    @classmethod
    def of(cls, scenario: Scenario) -> ReferenceWorld:
        env = scenario.environment
        cyl = env.cylinders
        return cls(np.array(scenario.start, dtype=float), np.array(scenario.goal, dtype=float), env.size_x,
                   env.size_y, env.z_min, env.z_max, np.stack([cyl.x, cyl.y, cyl.radius], axis=1).astype(float),
                   scenario.hazard.d_safe, scenario.hazard.d_coll)


@dataclass(frozen=True)
class ReferenceConfig:
    """The original's settings; ``n_pop`` × ``max_iter`` as the paper's Table 6."""

    n_pop: int = 500
    max_iter: int = 200
    n_waypoints: int = 10
    w0: float = 1.0
    w_damp: float = 0.98
    c1: float = 1.5
    c2: float = 1.5
    velocity_share: float = 0.5  # |v_d| ≤ this × (max_d − min_d)
    weights: tuple[float, float, float, float] = (5.0, 1.0, 10.0, 1.0)  # b1…b4 (Phung & Ha's; ours: b4 = 5)
    penalty: float = 1e6  # per violation, flat: the original's ∞ made finite


@dataclass(frozen=True)
class ReferenceResult:
    path: np.ndarray  # (n + 2, 3) m, start and goal included
    cost: float
    terms: dict[str, float]  # J1…J4, unweighted
    violations: int  # leg × cylinder collisions + waypoints outside the band, of the best path
    history: np.ndarray  # (max_iter + 1,) best cost after initialisation and after each iteration
    evaluations: int
    time_s: float


def bounds(world: ReferenceWorld, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (n, 3) of (r m, ψ rad, φ rad) per leg."""
    d = world.goal - world.start
    phi0 = np.arctan2(d[1], d[0])
    lo = np.array([0.0, -_ANGLE, phi0 - _ANGLE])
    hi = np.array([2.0 * float(np.linalg.norm(d)) / n, _ANGLE, phi0 + _ANGLE])
    return np.broadcast_to(lo, (n, 3)).copy(), np.broadcast_to(hi, (n, 3)).copy()


def decode(x: np.ndarray, world: ReferenceWorld) -> np.ndarray:
    """Particles (P, n, 3) of (r, ψ, φ) → paths (P, n + 2, 3) m: S, the clamped waypoints, G."""
    r, psi, phi = x[..., 0], x[..., 1], x[..., 2]
    step = np.stack([r * np.cos(psi) * np.cos(phi), r * np.cos(psi) * np.sin(phi), r * np.sin(psi)], axis=-1)
    pts = world.start + np.cumsum(step, axis=1)
    pts[..., 0] = np.clip(pts[..., 0], 0.0, world.size_x)
    pts[..., 1] = np.clip(pts[..., 1], 0.0, world.size_y)
    p = len(x)
    return np.concatenate([np.broadcast_to(world.start, (p, 1, 3)), pts, np.broadcast_to(world.goal, (p, 1, 3))],
                          axis=1)


def terms(paths: np.ndarray, world: ReferenceWorld) -> tuple[np.ndarray, np.ndarray]:
    """Unweighted J1…J4 (P, 4) and violation counts (P,) of paths (P, N, 3) m."""
    a, b = paths[:, :-1], paths[:, 1:]
    seg = b - a  # (P, S, 3)
    j1 = np.sqrt((seg**2).sum(axis=-1)).sum(axis=1)
    # J2: horizontal distance from each leg to each cylinder's axis, less its radius → (P, S, K)
    cx, cy, cr = (world.cylinders[:, i] for i in range(3))
    dx, dy = seg[..., 0, None], seg[..., 1, None]
    wx, wy = cx - a[..., 0, None], cy - a[..., 1, None]
    dd = dx * dx + dy * dy
    t = np.clip((wx * dx + wy * dy) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    d = np.hypot(wx - t * dx, wy - t * dy) - cr
    hit = d < world.d_coll
    j2 = np.where(d < world.d_safe, world.d_safe - d, 0.0)
    j2 = np.where(hit, 0.0, j2).sum(axis=(1, 2))
    # J3: the interior waypoints' distance from mid-band
    z = paths[:, 1:-1, 2]
    out = (z < world.z_min) | (z > world.z_max)
    j3 = np.where(out, 0.0, np.abs(z - 0.5 * (world.z_min + world.z_max))).sum(axis=1)
    # J4: turning angle between consecutive legs' horizontal projections, and the change of climb angle
    h = np.hypot(seg[..., 0], seg[..., 1])
    cross = seg[:, :-1, 0] * seg[:, 1:, 1] - seg[:, :-1, 1] * seg[:, 1:, 0]
    dot = seg[:, :-1, 0] * seg[:, 1:, 0] + seg[:, :-1, 1] * seg[:, 1:, 1]
    turn = np.abs(np.arctan2(cross, dot))
    climb = np.arctan2(seg[..., 2], np.maximum(h, _EPS))
    j4 = (turn + np.abs(np.diff(climb, axis=1))).sum(axis=1)
    violations = hit.sum(axis=(1, 2)) + out.sum(axis=1)
    return np.stack([j1, j2, j3, j4], axis=1), violations


def cost(x: np.ndarray, world: ReferenceWorld, cfg: ReferenceConfig) -> np.ndarray:
    """F (P,) of particles (P, n, 3): weighted terms plus the flat penalty per violation."""
    j, v = terms(decode(x, world), world)
    return j @ np.asarray(cfg.weights) + cfg.penalty * v


def solve(world: ReferenceWorld, cfg: ReferenceConfig, rng: np.random.Generator) -> ReferenceResult:
    """Run the reference SPSO for ``cfg.max_iter`` iterations (no early stop); every random draw from ``rng``."""
    t0 = time.perf_counter()
    n = cfg.n_waypoints
    lo, hi = bounds(world, n)
    vmax = cfg.velocity_share * (hi - lo)
    shape = (cfg.n_pop, n, 3)
    x = lo + rng.random(shape) * (hi - lo)
    v = np.zeros(shape)
    f = cost(x, world, cfg)
    pbest, pbest_f = x.copy(), f.copy()
    g = int(np.argmin(f))
    gbest, gbest_f = x[g].copy(), float(f[g])
    history = [gbest_f]
    w = cfg.w0
    for _ in range(cfg.max_iter):
        r1, r2 = rng.random(shape), rng.random(shape)
        v = np.clip(w * v + cfg.c1 * r1 * (pbest - x) + cfg.c2 * r2 * (gbest - x), -vmax, vmax)
        x = x + v
        outside = (x < lo) | (x > hi)
        v = np.where(outside, -v, v)
        x = np.clip(x, lo, hi)
        f = cost(x, world, cfg)
        better = f < pbest_f
        pbest[better], pbest_f[better] = x[better], f[better]
        g = int(np.argmin(pbest_f))
        if pbest_f[g] < gbest_f:
            gbest, gbest_f = pbest[g].copy(), float(pbest_f[g])
        history.append(gbest_f)
        w *= cfg.w_damp
    path = decode(gbest[None], world)
    j, viol = terms(path, world)
    return ReferenceResult(path[0], gbest_f, dict(zip(("J1", "J2", "J3", "J4"), map(float, j[0]))), int(viol[0]),
                           np.array(history), cfg.n_pop * (cfg.max_iter + 1), time.perf_counter() - t0)
