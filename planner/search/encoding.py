"""Decision-space encodings of a path: spherical steps (docs/method.md §3.1) or Cartesian waypoints (ablation V2, §3.4).

A particle is an array (n, 3); a swarm (P, n, 3). ``decode`` turns a swarm into full paths
(P, n + 2, 3) with the start and goal attached, which is what :class:`PlanningProblem` scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from planner import kernel
from planner.problem import PlanningProblem
from planner.trajectory.smoothing import segment_samples
from planner.world.config import SPSOConfig
from planner.world.geometry import cartesian_to_spherical, spherical_to_cartesian


@dataclass(frozen=True, eq=False)
class Encoding:
    """Bounds ``lo``/``hi`` (n, 3) of the decision variables and the map to paths."""

    kind: str
    start: np.ndarray
    goal: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    cartesian_spread: float = 0.0

    @property
    def n(self) -> int:
        return self.lo.shape[0]

    def decode(self, x: np.ndarray) -> np.ndarray:
        """Swarm (P, n, 3) → paths (P, n + 2, 3) including start and goal."""
        if self.kind == "spherical" and kernel.chosen() == "compiled":
            return kernel.decode_spherical(x, self.start, self.goal)
        if self.kind == "spherical":
            pts = spherical_to_cartesian(self.start, x[..., 0], x[..., 1], x[..., 2])
        else:
            pts = x
        p = x.shape[0]
        s = np.broadcast_to(self.start, (p, 1, 3))
        g = np.broadcast_to(self.goal, (p, 1, 3))
        return np.concatenate([s, pts, g], axis=1)

    def encode(self, paths: np.ndarray) -> np.ndarray:
        """Paths (P, M, 3) with this encoding's start → swarm (P, n, 3), clipped into bounds.

        Used to seed a swarm with known routes (warm start); azimuths are unwrapped into the cone. A path
        with another number of points than n + 2 (a merged plan, an old route) is first resampled to n + 2
        points evenly spaced along its length, ends kept.
        """
        paths = np.asarray(paths, dtype=float)
        if paths.shape[1] != self.n + 2:
            paths = resample_paths(paths, self.n + 2)
        inner = paths[:, 1:-1]
        if self.kind == "cartesian":
            return np.clip(inner, self.lo, self.hi)
        r, psi, phi = cartesian_to_spherical(self.start, inner)
        mid = 0.5 * (self.lo[:, 2] + self.hi[:, 2])
        phi = mid + np.angle(np.exp(1j * (phi - mid)))  # nearest branch to the cone's centre
        return np.clip(np.stack([r, psi, phi], axis=-1), self.lo, self.hi)

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """Initial positions (count, n, 3): uniform in bounds (spherical) or around the line S→G (V2)."""
        if self.kind == "spherical":
            return self.lo + rng.random((count, *self.lo.shape)) * (self.hi - self.lo)
        frac = (np.arange(1, self.n + 1) / (self.n + 1))[:, None]
        line = self.start + frac * (self.goal - self.start)
        spread = self.cartesian_spread * float(np.linalg.norm(self.goal - self.start))
        x = line + rng.normal(0.0, spread, (count, self.n, 3)) * np.array([1.0, 1.0, 0.25])
        return np.clip(x, self.lo, self.hi)


def resample_paths(paths: np.ndarray, count: int) -> np.ndarray:
    """Paths (P, M, 3) → (P, count, 3): points evenly spaced by arc length, first and last kept."""
    seg = np.linalg.norm(np.diff(paths, axis=1), axis=-1)  # (P, M − 1)
    s = np.concatenate([np.zeros((len(paths), 1)), np.cumsum(seg, axis=1)], axis=1)
    target = s[:, -1:] * np.linspace(0.0, 1.0, count)  # (P, count)
    out = np.empty((len(paths), count, 3))
    for p in range(len(paths)):  # a handful of seed paths, once per plan: not a hot path
        for d in range(3):
            out[p, :, d] = np.interp(target[p], s[p], paths[p, :, d])
    return out


def resample_keeping_vertices(route: np.ndarray, count: int) -> np.ndarray:
    """Route (M, 3) → (count, 3) with every vertex kept (count ≥ M) and the extra points spread over the legs
    in proportion to their length (largest remainder), each leg split evenly: the corners of a guide survive,
    which even arc-length resampling would cut."""
    route = np.asarray(route, dtype=float)
    legs = len(route) - 1
    if count < len(route):
        raise ValueError(f"cannot keep {len(route)} vertices in {count} points")
    length = np.linalg.norm(np.diff(route, axis=0), axis=1)
    share = (count - 1 - legs) * length / max(length.sum(), 1e-12)
    parts = 1 + np.floor(share).astype(int)
    rest = count - 1 - parts.sum()
    parts[np.argsort(-(share - np.floor(share)), kind="stable")[:rest]] += 1
    leg, t = segment_samples(parts)
    return np.concatenate([route[leg] + t[:, None] * (route[leg + 1] - route[leg]), route[-1:]])


def guided_encoding(problem: PlanningProblem, cfg: SPSOConfig, guide: np.ndarray, n: int | None = None,
                    ) -> tuple[Encoding, np.ndarray]:
    """The spherical encoding around a guide route (docs/method.md §15.2) and the guide as n + 2 points.

    Step k's azimuth cone is centred on the bearing of the guide's own step k instead of the fixed start→goal
    bearing, and r ≤ max(2 L_guide / n, 1.5 × the guide's longest step): with the straight line as guide this
    is :func:`make_encoding` exactly, and the guide is always a particle inside the bounds. ``n`` defaults to
    the configured waypoints, more if the guide has more vertices."""
    guide = np.asarray(guide, dtype=float)
    n = max(cfg.n_waypoints if n is None else n, len(guide) - 2)
    pts = resample_keeping_vertices(guide, n + 2)
    steps = np.diff(pts[:-1], axis=0)  # the n encoded steps (the last leg to the goal is implied)
    length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    base = make_encoding(problem, replace(cfg, n_waypoints=n))
    r_max = max(2.0 * length / n, 1.5 * float(np.linalg.norm(steps, axis=1).max()))
    lo, hi = base.lo.copy(), base.hi.copy()
    lo[:, 0] = np.minimum(lo[:, 0], r_max)
    hi[:, 0] = r_max
    if cfg.direction == "cone":
        bearing = np.arctan2(steps[:, 1], steps[:, 0])
        half = math.radians(cfg.cone_half_deg)
        lo[:, 2], hi[:, 2] = bearing - half, bearing + half
    return Encoding("spherical", base.start, base.goal, lo, hi), pts


def make_encoding(problem: PlanningProblem, cfg: SPSOConfig) -> Encoding:
    """Bounds from docs/method.md §3.2: r ∈ [r_min, 2‖SG‖/n], ψ ∈ ±min(ψ_max, max climb), φ in the S→G cone."""
    n = cfg.n_waypoints
    s, g = problem.start, problem.goal
    env = problem.env
    if cfg.encoding == "cartesian":
        z_lo = env.z_min
        z_hi = env.z_max + (env.terrain.max_height if env.terrain is not None else 0.0)
        lo = np.tile([0.0, 0.0, z_lo], (n, 1))
        hi = np.tile([env.size_x, env.size_y, z_hi], (n, 1))
        return Encoding("cartesian", s, g, lo, hi, cfg.cartesian_spread)
    r_max = 2.0 * problem.direct_distance / n
    r_min = 0.0
    if cfg.flyability_bound:  # Property 4: r_min ≥ 2 R_min sin(α_max)
        r_min = min(2.0 * problem.vehicle.min_turn_radius * math.sin(problem.vehicle.max_turn), r_max)
    psi_max = min(math.radians(cfg.psi_max_deg), problem.vehicle.max_climb)
    if cfg.direction == "cone":
        phi0 = math.atan2(g[1] - s[1], g[0] - s[0])
        half = math.radians(cfg.cone_half_deg)
        phi_lo, phi_hi = phi0 - half, phi0 + half
    else:
        phi_lo, phi_hi = -math.pi, math.pi
    lo = np.tile([r_min, -psi_max, phi_lo], (n, 1))
    hi = np.tile([r_max, psi_max, phi_hi], (n, 1))
    return Encoding("spherical", s, g, lo, hi)
