"""The planning problem: evaluates batches of paths → cost J = Σ b_i J_i + violation penalties (docs/method.md §4, §5).

Paths are arrays ``(P, N, 3)`` in ENU metres that include the start (index 0) and the goal (index N−1).
Everything broadcasts over particles, segments and obstacles at once: no Python loop over any of them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import Protocol

import numpy as np

from planner import kernel
from planner.trajectory.smoothing import (
    bezier_point,
    chord_sag,
    climb_angle,
    corner_cut_bound,
    cubic_range,
    flown_deviation,
    overshoot_bound,
    peak_climb,
    peak_curvature,
)
from planner.world.config import CATEGORIES, TERMS, CostWeights, HazardConfig, PenaltyConfig, VehicleLimits
from planner.world.environment import Environment
from planner.world.geometry import (
    horizontal_turn,
    segment_cylinder_clearance,
    segment_point_distance,
    segment_point_distance_2d,
    segment_prism_clearance,
    segment_sphere_clearance,
)

_EPS = 1e-9
_TERRAIN_T = np.linspace(0.0, 1.0, 17)  # samples per segment: the band is tested on the 16 chords between them
_TERRAIN_SAG = chord_sag(_TERRAIN_T)
_THREAT_T = np.linspace(0.0, 1.0, 11)  # samples per segment (ends included) for time-aware threats
THREAT_SAMPLES = len(_THREAT_T)


def _dot3(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Dot product over a last axis of length 3, component-wise (a reduction over 3 is slow in numpy)."""
    return p[..., 0] * q[..., 0] + p[..., 1] * q[..., 1] + p[..., 2] * q[..., 2]


class _Add(Protocol):
    """Evaluate's ``add``: violations where ``depth`` > 0 (``axis`` the particle axis), penalised at ``rate``."""

    def __call__(self, category: str, depth: np.ndarray, rate: float, axis: int = 0) -> None: ...


def _height_range(z0: np.ndarray, z1: np.ndarray, z2: np.ndarray, z3: np.ndarray,
                  env: Environment) -> tuple[np.ndarray, np.ndarray]:
    """Exact height range of each Bézier segment (P, S) from its control heights. The control hull
    bounds it, so the cubic's extremes are solved only where the hull reaches past the band."""
    lo = np.minimum(np.minimum(z0, z3), np.minimum(z1, z2))
    hi = np.maximum(np.maximum(z0, z3), np.maximum(z1, z2))
    need = (lo < env.z_min) | (hi > env.z_max)
    if need.any():
        lo_x, hi_x = cubic_range(z0[need], z1[need], z2[need], z3[need])
        lo = lo.copy()
        hi = hi.copy()
        lo[need] = lo_x
        hi[need] = hi_x
    return lo, hi


def _per_particle(x: np.ndarray, axis: int) -> np.ndarray:
    """Sum an array over every axis but the particle axis, in an order that does not depend on how
    many particles share the batch, so a path costs the same, bit for bit, alone or in any swarm.

    Leading (obstacle) axes are reduced first: with the segment axis still innermost numpy adds them
    element-wise in sequence. Trailing axes are then reduced row by row. (Reducing the segment axis
    first would leave (K, P) arrays whose sum over K is pairwise or sequential depending on P.)"""
    for _ in range(axis):
        x = np.add.reduce(x, axis=0)
    while x.ndim > 1:
        x = x.sum(axis=-1)
    return x


@dataclass
class Evaluation:
    """Cost of a batch: ``total`` (P,), unweighted ``terms`` J1…J5 (P,) each, ``penalty`` (P,) and
    ``violations`` per category (P,) ints (docs/method.md §5.2)."""

    total: np.ndarray
    terms: dict[str, np.ndarray]
    penalty: np.ndarray
    violations: dict[str, np.ndarray]

    @property
    def n_violations(self) -> np.ndarray:
        return sum(self.violations.values())  # type: ignore[return-value]  # 0 only if there were no categories


@dataclass(frozen=True, eq=False)
class PlanningProblem:
    """Start, goal, environment, vehicle and cost weights; ``evaluate`` scores batches of paths.

    ``start_time`` (s) enables time-aware dynamic threats: the vehicle flies the path at cruise speed
    from that time, and each sample is compared with the threats' positions at the same time.
    ``start_heading`` (3,): the direction the vehicle already flies at the start (a replan's commit point); the
    turn from it into the first leg is held to the vehicle's limits like any waypoint's (docs/method.md §4.8).
    """

    env: Environment
    start: np.ndarray
    goal: np.ndarray
    vehicle: VehicleLimits
    hazard: HazardConfig = field(default_factory=HazardConfig)
    weights: CostWeights = field(default_factory=CostWeights)
    penalty: PenaltyConfig = field(default_factory=PenaltyConfig)
    start_time: float | None = None
    start_heading: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("start", "goal"):
            v = np.array(getattr(self, name), dtype=float).reshape(3)
            v.setflags(write=False)
            object.__setattr__(self, name, v)
        if self.start_heading is not None:  # a unit vector; a zero one (no motion) means no heading
            h = np.array(self.start_heading, dtype=float).reshape(3)
            n = float(np.linalg.norm(h[:2]))
            unit = h / max(float(np.linalg.norm(h)), _EPS) if n > 1e-6 else None
            if unit is not None:
                unit.setflags(write=False)
            object.__setattr__(self, "start_heading", unit)

    @property
    def timed_threats(self) -> bool:
        """Moving threats that the cost meets in time (docs/method.md §4.6): some, and a start time."""
        return bool(len(self.env.threats)) and self.start_time is not None

    @property
    def direct_distance(self) -> float:
        """‖G − S‖ in metres."""
        return float(np.linalg.norm(self.goal - self.start))

    # cached_property writes the instance's __dict__ itself, so it caches on this frozen dataclass too
    @cached_property
    def kernel_inputs(self) -> kernel.KernelInputs:
        """What the compiled kernel reads of this problem, by name: built on the first compiled evaluation."""
        return kernel.KernelInputs.build(self.env, self.vehicle, self.hazard, self.penalty, self.weights,
                                         self.direct_distance, self.start_time if self.timed_threats else None,
                                         self.start_heading, _THREAT_T, _TERRAIN_T)

    @cached_property
    def _cyl_fin(self) -> np.ndarray:
        """Indices of the cylinders with a finite top."""
        return np.flatnonzero(np.isfinite(self.env.cylinders.top))

    # -- public -----------------------------------------------------------------------------------
    def evaluate(self, paths: np.ndarray) -> Evaluation:
        """Score paths (P, N, 3) → :class:`Evaluation` with arrays shaped (P,): the compiled kernel
        (planner/kernel/) unless FUSEPLAN_KERNEL=numpy picks this module's reference implementation."""
        paths = np.asarray(paths, dtype=float)
        if paths.ndim == 2:
            paths = paths[None]
        if kernel.chosen() == "compiled":
            return self._evaluate_compiled(paths)
        return self.evaluate_reference(paths)

    def _evaluate_compiled(self, paths: np.ndarray) -> Evaluation:
        j, pen, viol, total = kernel.evaluate(self.kernel_inputs, paths)  # total: the reference's order
        terms = {name: j[:, i] for i, name in enumerate(TERMS)}
        return Evaluation(total=total, terms=terms, penalty=pen,
                          violations={c: viol[:, i] for i, c in enumerate(CATEGORIES)})

    def evaluate_reference(self, paths: np.ndarray) -> Evaluation:
        """The numpy implementation of :meth:`evaluate` (paths (P, N, 3)), the reference the kernel is held to."""
        paths = np.asarray(paths, dtype=float)
        if paths.ndim == 2:
            paths = paths[None]
        a = paths[:, :-1]
        b = paths[:, 1:]
        seg = b - a
        seg_len = np.sqrt(_dot3(seg, seg))  # (P, S)
        viol = {c: np.zeros(len(paths), dtype=np.int64) for c in CATEGORIES}
        pen = np.zeros(len(paths))

        def add(category: str, depth: np.ndarray, rate: float, axis: int = 0) -> None:
            """Add violations where depth > 0; ``axis`` of ``depth`` is the particle axis."""
            nonlocal pen
            if depth.size == 0 or not depth.max() > 0.0:  # the usual case once feasible: one pass
                return
            hit = depth > 0.0
            viol[category] += _per_particle(hit, axis)
            pen = pen + _per_particle(np.where(hit, self.penalty.constant + rate * depth, 0.0), axis)

        per_m = self.penalty.per_metre
        # the smoothed curve the vehicle flies (docs/method.md §4.4, §11): unit directions, turn cosines,
        # chord deviation
        u = seg / np.maximum(seg_len, _EPS)[..., None]
        v = np.concatenate([u[:, 1:], u[:, -1:]], axis=1)  # next direction; the last segment stays straight
        cos_turn = _dot3(u, v)
        veh = self.vehicle
        dev = flown_deviation(seg_len, cos_turn, veh.acceptance_radius, veh.turn_overshoot)  # (P, S) m off each chord
        if self.start_heading is not None:  # the corner the autopilot cuts at the start, as at any waypoint
            c0 = _dot3(u[:, 0], self.start_heading)
            dev[:, 0] = np.maximum(dev[:, 0], np.maximum(corner_cut_bound(veh.acceptance_radius, c0),
                                                         overshoot_bound(veh.turn_overshoot, c0)))
        q2 = b - (seg_len / 3.0)[..., None] * v  # Q1 = a + seg/3 lies on the chord
        z_lo, z_hi = _height_range(a[..., 2], a[..., 2] + seg[..., 2] / 3.0, q2[..., 2], b[..., 2], self.env)

        j1 = seg_len.sum(axis=1)
        j2 = self._hazard(paths, a, b, seg_len, dev, add)
        j3 = self._altitude(paths, a, q2, b, z_lo, z_hi, add)
        j4 = self._smoothness(seg, seg_len, u, v, cos_turn, add)
        j5 = seg_len[:, -1] / max(self.direct_distance, _EPS)
        # bounds: the curve stays in the region; it lies in the hull of a, q1 (on the chord), q2 and b
        lo = np.minimum(np.minimum(a[..., :2], b[..., :2]), q2[..., :2])
        hi = np.maximum(np.maximum(a[..., :2], b[..., :2]), q2[..., :2])
        out = np.maximum.reduce([-lo[..., 0], hi[..., 0] - self.env.size_x, -lo[..., 1],
                                 hi[..., 1] - self.env.size_y])
        add("bounds", out, per_m)

        terms = dict(zip(TERMS, (j1, j2, j3, j4, j5)))
        total = pen
        for name, weight in self.weights.by_term().items():  # five named terms, not a hot loop
            total = total + weight * terms[name]
        return Evaluation(total=total, terms=terms, penalty=pen, violations=viol)

    # -- terms ------------------------------------------------------------------------------------
    def _soft_and_violation(self, clearance: np.ndarray, add: _Add, axis: int) -> np.ndarray:
        """T_c(d) per particle; d < d_coll adds a violation of depth d_coll − d (docs/method.md §4.3)."""
        d_safe, d_coll = self.hazard.d_safe, self.hazard.d_coll
        gap = d_safe - clearance  # how far inside d_safe; capped where the violation takes over
        add("collision", gap - (d_safe - d_coll), self.penalty.per_metre, axis)
        np.clip(gap, 0.0, d_safe - d_coll, out=gap)
        np.multiply(gap, gap, out=gap)
        return _per_particle(gap, axis) / d_safe

    def static_clearances(
        self, a: np.ndarray, b: np.ndarray, refine_below: float | np.ndarray = np.inf
    ) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """Exact clearances of segments a→b (..., 3) from the static obstacles, obstacle axis first:
        cylinders (K_c, ...) and spheres (K_s, ...) to their surfaces, radars (K_r, ...) distance to the
        site (None for an absent family). Finite cylinder tops are searched only where the 2-D bound
        (distance to the axis − R, exact for unlimited cylinders) is below ``refine_below``."""
        env = self.env
        lead = (slice(None),) + (None,) * (a.ndim - 1)
        cyl_c = sph_c = radar_d = None
        cyl = env.cylinders
        if len(cyl):
            cyl_c = segment_point_distance_2d(a[..., 0], a[..., 1], b[..., 0], b[..., 1],
                                              cyl.x[lead], cyl.y[lead])
            cyl_c -= cyl.radius[lead]
            if len(self._cyl_fin):
                need = np.isfinite(cyl.top)[lead] & (cyl_c < refine_below)
                idx = np.nonzero(need)
                k, rest = idx[0], idx[1:]
                cyl_c[idx] = segment_cylinder_clearance(a[rest], b[rest], cyl.x[k], cyl.y[k],
                                                        cyl.radius[k], cyl.top[k])
        if len(env.spheres):
            sph_c = segment_sphere_clearance(a[None], b[None], env.spheres.center[lead + (slice(None),)],
                                             env.spheres.radius[lead])
        if len(env.radars):
            radar_d = segment_point_distance(a[None], b[None], env.radars.center[lead + (slice(None),)])
        return cyl_c, sph_c, radar_d

    def prism_clearances(self, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """Exact signed clearances (K_p, ...) of segments a→b (..., 3) from the polygon prisms (docs/method.md §2.7),
        prism axis first; None without prisms."""
        if not len(self.env.prisms):
            return None
        return segment_prism_clearance(a, b, self.env.prisms)

    def segment_blocked(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """True where segment a→b (..., 3) passes within d_coll of a static obstacle (prisms included) or inside a
        radar's detection range (used to steer ant colonies away from hopeless edges)."""
        if kernel.chosen() == "compiled":
            return kernel.segment_blocked(self.kernel_inputs, a, b)
        return self.segment_blocked_reference(a, b)

    def segment_blocked_reference(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """The numpy implementation of :meth:`segment_blocked`, the reference the kernel is held to."""
        blocked = np.zeros(a.shape[:-1], dtype=bool)
        cyl_c, sph_c, radar_d = self.static_clearances(a, b, refine_below=self.hazard.d_coll)
        for c in (cyl_c, sph_c, self.prism_clearances(a, b)):
            if c is not None:
                blocked |= (c < self.hazard.d_coll).any(axis=0)
        if radar_d is not None:
            lead = (slice(None),) + (None,) * (a.ndim - 1)
            blocked |= (radar_d < self.env.radars.r_det[lead]).any(axis=0)
        return blocked

    def _hazard(self, paths: np.ndarray, a: np.ndarray, b: np.ndarray, seg_len: np.ndarray, dev: np.ndarray,
                add: _Add) -> np.ndarray:
        """J2: obstacles by exact segment distances; radars; time-aware dynamic threats.

        The clearance of the flown curve is bounded below by the segment's exact clearance minus
        ``dev``, the largest distance of its Bézier from the chord; that bound is what counts.
        Arrays are laid out (K obstacles, P particles, S segments) so the long axis stays innermost.
        """
        env = self.env
        total = np.zeros(len(paths))
        # refine finite cylinder tops only where the 2-D bound, less the deviation, is inside d_safe
        cyl_c, sph_c, radar_d = self.static_clearances(a, b, refine_below=self.hazard.d_safe + dev)
        if cyl_c is not None:
            cyl_c -= dev
            total += self._soft_and_violation(cyl_c, add, 1)
        if sph_c is not None:
            total += self._soft_and_violation(sph_c - dev, add, 1)
        if radar_d is not None:
            r_det = env.radars.r_det[:, None, None]
            add("collision", r_det - (radar_d - dev), self.penalty.per_metre, 1)
            soft = env.radars.soft_weight[:, None, None] * (r_det / np.maximum(radar_d, r_det)) ** 4
            total += _per_particle(soft, 1)
        if self.timed_threats:
            pts, times = self._timed_samples(a, b, seg_len)
            centres = env.threats.positions(times)  # (k, P, M, 3)
            dist = np.linalg.norm(pts[None] - centres, axis=-1) - env.threats.radii(times)
            # between two samples the vehicle is within half a gap of one of them and the threat
            # moves at most its speed for that time: subtract both, and the chord deviation
            gap = seg_len / (len(_THREAT_T) - 1)
            margin = dev + 0.5 * gap * (1.0 + env.threats.max_speed / self.vehicle.cruise_speed)
            dist = dist - np.repeat(margin, len(_THREAT_T), axis=1)
            total += self._soft_and_violation(dist, add, 1)
        pri_c = self.prism_clearances(a, b)  # last: a map without prisms adds nothing, not even a zero
        if pri_c is not None:
            total += self._soft_and_violation(pri_c - dev, add, 1)
        return total

    def _timed_samples(self, a: np.ndarray, b: np.ndarray, seg_len: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points along each segment and the times the vehicle reaches them at cruise speed."""
        pts = a[:, :, None, :] + _THREAT_T[:, None] * (b - a)[:, :, None, :]  # (P, S, m, 3)
        s0 = np.cumsum(seg_len, axis=1) - seg_len  # distance flown at each segment start
        s = s0[:, :, None] + _THREAT_T * seg_len[:, :, None]
        t = self.start_time + s / self.vehicle.cruise_speed
        p = len(a)
        return pts.reshape(p, -1, 3), t.reshape(p, -1)

    def _altitude(self, paths: np.ndarray, a: np.ndarray, q2: np.ndarray, b: np.ndarray, curve_lo: np.ndarray,
                  curve_hi: np.ndarray, add: _Add) -> np.ndarray:
        """J3: distance from mid-band over interior waypoints; band violations of the flown curve."""
        env = self.env
        z_lo, z_hi = env.z_min, env.z_max  # band above terrain
        mid, half = 0.5 * (z_lo + z_hi), 0.5 * (z_hi - z_lo)
        wp = paths[:, 1:-1]
        h = wp[..., 2] - env.ground(wp[..., 0], wp[..., 1])
        j3 = (np.abs(h - mid) / half).sum(axis=1)
        if env.terrain is None:  # exact height range of each Bézier segment
            depth = np.maximum(z_lo - curve_lo, curve_hi - z_hi)
        else:  # the chords between samples of the curve, each exactly over the ground (docs/method.md §15.1),
            # the band narrowed by how far the curve may stray from them (chord_sag)
            q1 = a + (b - a) / 3.0
            t = _TERRAIN_T[:, None]
            pts = bezier_point(a[:, :, None], q1[:, :, None], q2[:, :, None], b[:, :, None], t)  # (P, S, m, 3)
            lo, hi = env.height_range(pts[:, :, :-1].reshape(-1, 3), pts[:, :, 1:].reshape(-1, 3))
            shape = (pts.shape[0], pts.shape[1], pts.shape[2] - 1)
            d1, d2 = q2 - 2.0 * q1 + a, b - 2.0 * q2 + q1
            second = np.maximum(np.sqrt(_dot3(d1, d1)), np.sqrt(_dot3(d2, d2)))
            margin = (_TERRAIN_SAG * (1.0 + env.terrain.max_slope) * second)[..., None]
            depth = np.maximum(z_lo + margin - lo.reshape(shape), hi.reshape(shape) - (z_hi - margin))
        add("altitude", depth, self.penalty.per_metre)
        return j3

    def _smoothness(self, seg: np.ndarray, seg_len: np.ndarray, u: np.ndarray, v: np.ndarray, cos_turn: np.ndarray,
                    add: _Add) -> np.ndarray:
        """J4: turn and climb-change angles at interior waypoints; turn, curvature and climb limits."""
        veh = self.vehicle
        gamma = climb_angle(seg)  # climb angle of every segment
        turn = horizontal_turn(seg)  # horizontal turn at each interior waypoint
        dgamma = np.abs(np.diff(gamma, axis=1))
        over = np.maximum(turn - veh.max_turn, 0.0)
        j4 = (turn + dgamma + over**2).sum(axis=1)
        add("turn", over, self.penalty.per_radian)
        # flyability of the smoothed curve (docs/method.md §5.2, §11.2–11.3): curvature ≤ 1/R_min and its climb angle
        kappa = peak_curvature(seg_len, cos_turn)  # zero on the straight last segment
        add("turn", kappa * veh.min_turn_radius - 1.0, self.penalty.per_radian)
        add("climb", peak_climb(u, v) - veh.max_climb, self.penalty.per_radian)
        if self.start_heading is not None:  # the turn at the start, from the way the vehicle already flies
            h = np.broadcast_to(self.start_heading, seg[:, :1].shape)
            turn0 = horizontal_turn(np.concatenate([h, seg[:, :1]], axis=1))[:, 0]
            over0 = np.maximum(turn0 - veh.max_turn, 0.0)
            j4 = j4 + turn0 + over0**2
            add("turn", over0, self.penalty.per_radian)
            add("turn", peak_curvature(seg_len[:, 0], _dot3(u[:, 0], self.start_heading)) * veh.min_turn_radius
                - 1.0, self.penalty.per_radian)
        return j4
