"""The planning problem: evaluates batches of paths → cost J = Σ b_i J_i + violation penalties (SPEC §4).

Paths are arrays ``(P, N, 3)`` in ENU metres that include the start (index 0) and the goal (index N−1).
Everything broadcasts over particles, segments and obstacles at once: no Python loop over any of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from planner.config import CostWeights, HazardConfig, PenaltyConfig, VehicleLimits
from planner.environment import Environment
from planner.geometry import (
    segment_cylinder_clearance,
    segment_point_distance,
    segment_point_distance_2d,
)
from planner.smoothing import extrapolated_direction, peak_curvature

TERMS = ("J1", "J2", "J3", "J4", "J5")
CATEGORIES = ("collision", "altitude", "bounds", "turn", "climb")
_EPS = 1e-9
_TERRAIN_T = np.linspace(0.0, 1.0, 9)  # samples per segment for terrain clearance
_THREAT_T = np.linspace(0.0, 1.0, 6)[:-1]  # samples per segment for time-aware threats


def _per_particle(x: np.ndarray, axis: int) -> np.ndarray:
    """Sum an array over every axis but the particle axis."""
    others = tuple(i for i in range(x.ndim) if i != axis)
    return x.sum(axis=others) if others else x


@dataclass
class Evaluation:
    """Cost of a batch: ``total`` (P,), unweighted ``terms`` J1…J5 (P,) each, ``penalty`` (P,) and
    ``violations`` per category (P,) ints (SPEC §4)."""

    total: np.ndarray
    terms: dict[str, np.ndarray]
    penalty: np.ndarray
    violations: dict[str, np.ndarray]

    @property
    def n_violations(self) -> np.ndarray:
        return sum(self.violations.values())


@dataclass(frozen=True, eq=False)
class PlanningProblem:
    """Start, goal, environment, vehicle and cost weights; ``evaluate`` scores batches of paths.

    ``start_time`` (s) enables time-aware dynamic threats: the vehicle flies the path at cruise speed
    from that time, and each sample is compared with the threats' positions at the same time.
    """

    env: Environment
    start: np.ndarray
    goal: np.ndarray
    vehicle: VehicleLimits
    hazard: HazardConfig = field(default_factory=HazardConfig)
    weights: CostWeights = field(default_factory=CostWeights)
    penalty: PenaltyConfig = field(default_factory=PenaltyConfig)
    start_time: float | None = None

    def __post_init__(self) -> None:
        for name in ("start", "goal"):
            v = np.array(getattr(self, name), dtype=float).reshape(3)
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        cyl = self.env.cylinders
        unlimited = np.isinf(cyl.top)
        object.__setattr__(self, "_cyl_inf", np.flatnonzero(unlimited))
        object.__setattr__(self, "_cyl_fin", np.flatnonzero(~unlimited))

    @property
    def direct_distance(self) -> float:
        """‖G − S‖ in metres."""
        return float(np.linalg.norm(self.goal - self.start))

    # -- public -----------------------------------------------------------------------------------
    def evaluate(self, paths: np.ndarray) -> Evaluation:
        """Score paths (P, N, 3) → :class:`Evaluation` with arrays shaped (P,)."""
        paths = np.asarray(paths, dtype=float)
        if paths.ndim == 2:
            paths = paths[None]
        a = paths[:, :-1]
        b = paths[:, 1:]
        seg = b - a
        seg_len = np.linalg.norm(seg, axis=-1)  # (P, S)
        viol = {c: np.zeros(len(paths), dtype=np.int64) for c in CATEGORIES}
        pen = np.zeros(len(paths))

        def add(category: str, depth: np.ndarray, rate: float, axis: int = 0) -> None:
            """Add violations where depth > 0; ``axis`` of ``depth`` is the particle axis."""
            nonlocal pen
            hit = depth > 0.0
            viol[category] += _per_particle(hit, axis)
            pen = pen + _per_particle(np.where(hit, self.penalty.constant + rate * depth, 0.0), axis)

        per_m = self.penalty.per_metre
        j1 = seg_len.sum(axis=1)
        j2 = self._hazard(paths, a, b, seg_len, add)
        j3 = self._altitude(paths, a, b, add)
        j4 = self._smoothness(seg, seg_len, add)
        j5 = seg_len[:, -1] / max(self.direct_distance, _EPS)
        # bounds: waypoints stay in the region (segments between them then do too: it is convex)
        x, y = paths[..., 0], paths[..., 1]
        out = np.maximum.reduce([-x, x - self.env.size_x, -y, y - self.env.size_y, np.zeros_like(x)])
        add("bounds", out, per_m)

        terms = {"J1": j1, "J2": j2, "J3": j3, "J4": j4, "J5": j5}
        w = self.weights
        total = (w.length * j1 + w.hazard * j2 + w.altitude * j3 + w.smoothness * j4
                 + w.destination * j5 + pen)
        return Evaluation(total=total, terms=terms, penalty=pen, violations=viol)

    # -- terms ------------------------------------------------------------------------------------
    def _soft_and_violation(self, clearance: np.ndarray, add, axis: int) -> np.ndarray:  # noqa: ANN001
        """T_c(d) per particle; d < d_coll adds a violation of depth d_coll − d (SPEC §4)."""
        d_safe, d_coll = self.hazard.d_safe, self.hazard.d_coll
        gap = d_safe - np.maximum(clearance, d_coll)
        soft = np.maximum(gap, 0.0) ** 2 / d_safe
        add("collision", d_coll - clearance, self.penalty.per_metre, axis)
        return _per_particle(soft, axis)

    def _hazard(self, paths, a, b, seg_len, add) -> np.ndarray:  # noqa: ANN001
        """J2: obstacles by exact segment distances; radars; time-aware dynamic threats.

        Arrays are laid out (K obstacles, P particles, S segments) so the long axis stays innermost.
        """
        env = self.env
        total = np.zeros(len(paths))
        a3, b3 = a[None], b[None]  # (1, P, S, 3)
        cyl = env.cylinders
        if len(self._cyl_inf):
            i = self._cyl_inf
            col = (slice(None), None, None)
            c = segment_point_distance_2d(
                a[..., 0], a[..., 1], b[..., 0], b[..., 1], cyl.x[i][col], cyl.y[i][col]
            ) - cyl.radius[i][col]
            total += self._soft_and_violation(c, add, 1)
        if len(self._cyl_fin):
            i = self._cyl_fin
            c = segment_cylinder_clearance(a[..., None, :], b[..., None, :], cyl.x[i], cyl.y[i],
                                           cyl.radius[i], cyl.top[i])  # (P, S, K)
            total += self._soft_and_violation(c, add, 0)
        if len(env.spheres):
            c = segment_point_distance(a3, b3, env.spheres.center[:, None, None, :])
            c = c - env.spheres.radius[:, None, None]
            total += self._soft_and_violation(c, add, 1)
        if len(env.radars):
            rng = segment_point_distance(a3, b3, env.radars.center[:, None, None, :])  # (K, P, S)
            r_det = env.radars.r_det[:, None, None]
            add("collision", r_det - rng, self.penalty.per_metre, 1)
            soft = env.radars.soft_weight[:, None, None] * (r_det / np.maximum(rng, r_det)) ** 4
            total += _per_particle(soft, 1)
        if len(env.threats) and self.start_time is not None:
            pts, times = self._timed_samples(a, b, seg_len)
            centres = env.threats.positions(times)  # (k, P, M, 3)
            dist = np.linalg.norm(pts[None] - centres, axis=-1) - env.threats.radii(times)
            total += self._soft_and_violation(dist, add, 1)
        return total

    def _timed_samples(self, a, b, seg_len):  # noqa: ANN001, ANN202
        """Points along each segment and the times the vehicle reaches them at cruise speed."""
        pts = a[:, :, None, :] + _THREAT_T[:, None] * (b - a)[:, :, None, :]  # (P, S, m, 3)
        s0 = np.cumsum(seg_len, axis=1) - seg_len  # distance flown at each segment start
        s = s0[:, :, None] + _THREAT_T * seg_len[:, :, None]
        t = self.start_time + s / self.vehicle.cruise_speed
        p = len(a)
        return pts.reshape(p, -1, 3), t.reshape(p, -1)

    def _altitude(self, paths, a, b, add) -> np.ndarray:  # noqa: ANN001
        """J3: distance from mid-band over interior waypoints; band violations (with terrain)."""
        env = self.env
        z_lo, z_hi = env.z_min, env.z_max
        mid, half = 0.5 * (z_lo + z_hi), 0.5 * (z_hi - z_lo)
        wp = paths[:, 1:-1]
        h = wp[..., 2] - env.ground(wp[..., 0], wp[..., 1])
        j3 = (np.abs(h - mid) / half).sum(axis=1)
        if env.terrain is None:
            z = paths[..., 2]  # straight segments: extremes at their ends
        else:
            pts = a[:, :, None, :] + _TERRAIN_T[:, None] * (b - a)[:, :, None, :]
            z = pts[..., 2] - env.ground(pts[..., 0], pts[..., 1])
        add("altitude", np.maximum(z_lo - z, z - z_hi), self.penalty.per_metre)
        return j3

    def _smoothness(self, seg, seg_len, add) -> np.ndarray:  # noqa: ANN001
        """J4: turn and climb-change angles at interior waypoints; turn, curvature and climb limits."""
        veh = self.vehicle
        x, y, z = seg[..., 0], seg[..., 1], seg[..., 2]
        horiz = np.hypot(x, y)
        gamma = np.arctan2(z, horiz)  # climb angle of every segment
        cross = x[:, :-1] * y[:, 1:] - y[:, :-1] * x[:, 1:]
        dot_h = x[:, :-1] * x[:, 1:] + y[:, :-1] * y[:, 1:]
        turn = np.abs(np.arctan2(cross, dot_h))  # horizontal turn at each interior waypoint
        dgamma = np.abs(np.diff(gamma, axis=1))
        over = np.maximum(turn - veh.max_turn, 0.0)
        j4 = (turn + dgamma + over**2).sum(axis=1)
        add("turn", over, self.penalty.per_radian)
        # flyability of the smoothed curve (SPEC §6): curvature ≤ 1/R_min and its climb angle
        inv = 1.0 / np.maximum(seg_len, _EPS)
        ux, uy, uz = x * inv, y * inv, z * inv
        cos_turn = ux[:, :-1] * ux[:, 1:] + uy[:, :-1] * uy[:, 1:] + uz[:, :-1] * uz[:, 1:]
        kappa = peak_curvature(seg_len[:, :-1], cos_turn)  # the last segment stays straight
        add("turn", kappa * veh.min_turn_radius - 1.0, self.penalty.per_radian)
        w = extrapolated_direction(np.stack([ux, uy, uz])[:, :, :-1], np.stack([ux, uy, uz])[:, :, 1:])
        gamma_w = np.arctan2(w[2], np.hypot(w[0], w[1]))
        climb = np.abs(gamma)
        climb_peak = np.maximum(np.maximum(climb[:, :-1], climb[:, 1:]), np.abs(gamma_w))
        add("climb", np.concatenate([climb_peak, climb[:, -1:]], axis=1) - veh.max_climb,
            self.penalty.per_radian)
        return j4
