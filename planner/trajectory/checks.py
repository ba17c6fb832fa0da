"""Constraint check and metrics on the smoothed, sampled trajectory (docs/method.md §12, §13).

This is the independent verdict on a plan: it samples the Bézier curve the vehicle will fly, point by
point, instead of the closed forms the cost uses, and counts violations per category.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from planner.trajectory.smoothing import climb_angle, peak_curvature, sample_trajectory
from planner.world.config import CATEGORIES, HazardConfig, VehicleLimits
from planner.world.environment import Environment, Prisms, Radars
from planner.world.geometry import cylinder_signed_distance, horizontal_turn, prism_signed_distance

_TOL_M = 1e-6  # metres of slack for samples exactly on a limit (start on the band floor, say)
_TOL_REL = 1e-6
MAX_REPORTED = 5
CHUNK_PAIRS = 2**21  # point × obstacle distances held at once (16 MB a temporary), however many there are


@dataclass
class Trajectory:
    """Smoothed samples of one path: points (M, 3), times (M,) s, arc length (M,) m, curvature (M,)."""

    points: np.ndarray
    times: np.ndarray
    s: np.ndarray
    curvature: np.ndarray
    tangent: np.ndarray

    @property
    def length(self) -> float:
        return float(self.s[-1])


def smooth(waypoints: np.ndarray, spacing: float, speed: float, t0: float = 0.0) -> Trajectory:
    """Bézier-smooth waypoints (N, 3) and sample them every ~``spacing`` m, timed at ``speed`` m/s."""
    smp = sample_trajectory(waypoints, spacing)
    return Trajectory(smp["points"], t0 + smp["s"] / speed, smp["s"], smp["curvature"], smp["tangent"])


@dataclass
class CheckResult:
    """Violation counts per category (runs of consecutive offending samples) and where they start."""

    counts: dict[str, int]
    locations: dict[str, list[list[float]]] = field(default_factory=dict)
    clearance: np.ndarray | None = None  # (M,) signed distance to the nearest obstacle surface, m

    @property
    def feasible(self) -> bool:
        return not any(self.counts.values())

    @property
    def min_clearance(self) -> float:
        return float(self.clearance.min()) if self.clearance is not None and self.clearance.size else np.inf


def obstacle_clearance(
    points: np.ndarray, times: np.ndarray | None, env: Environment, include_radars: bool = True
) -> np.ndarray:
    """Signed distance (M,) from each sample to the nearest obstacle or threat surface; radars count
    from their detection range. Threats only when ``times`` is given. Obstacles are taken CHUNK_PAIRS / M at a
    time (a minimum is exact in any grouping), so memory does not grow with their number."""
    m = len(points)
    parts = [np.full(m, np.inf)]
    cyl, sph = env.cylinders, env.spheres
    step = max(1, CHUNK_PAIRS // max(m, 1))
    col = (slice(None), None)
    for lo in range(0, len(cyl), step):
        k = slice(lo, lo + step)
        parts.append(cylinder_signed_distance(points[None], cyl.x[k][col], cyl.y[k][col],
                                              cyl.radius[k][col], cyl.top[k][col]).min(axis=0))
    for lo in range(0, len(sph), step):
        k = slice(lo, lo + step)
        d = np.linalg.norm(points[None] - sph.center[k][:, None], axis=-1)
        parts.append((d - sph.radius[k][:, None]).min(axis=0))
    pri = env.prisms
    step_p = max(1, CHUNK_PAIRS // max(m * pri.padded[0].shape[1], 1))  # point × edge distances at once
    for lo in range(0, len(pri), step_p):
        parts.append(prism_signed_distance(points, _some_prisms(pri, slice(lo, lo + step_p))).min(axis=0))
    if include_radars:
        parts.append(radar_clearance(points, env.radars))
    if len(env.threats) and times is not None:
        c = env.threats.positions(times)  # (k, M, 3)
        d = np.linalg.norm(points[None] - c, axis=-1) - env.threats.radii(times)
        parts.append(d.min(axis=0))
    return np.min(np.stack(parts), axis=0)


def _some_prisms(prisms: Prisms, k: slice) -> Prisms:
    """Prisms ``k`` of ``prisms`` (all of them when the slice covers them: no copy)."""
    if k.start == 0 and k.stop >= len(prisms):
        return prisms
    idx = np.arange(len(prisms))[k]
    return Prisms.from_polygons([prisms.polygon(i) for i in idx], prisms.floor[k], prisms.ceiling[k],
                                prisms.keep_in[k])


def obstacle_distances(points: np.ndarray, env: Environment) -> dict[str, np.ndarray]:
    """Signed distance (M,) from each point to each named static obstacle ("cylinders[i]", "spheres[j]",
    "prisms[k]")."""
    out: dict[str, np.ndarray] = {}
    cyl = env.cylinders
    if len(cyl) and len(points):
        col = (slice(None), None)
        d = cylinder_signed_distance(points[None], cyl.x[col], cyl.y[col], cyl.radius[col], cyl.top[col])
        out.update({f"cylinders[{i}]": d[i] for i in range(len(cyl))})
    if len(env.spheres) and len(points):
        d = np.linalg.norm(points[None] - env.spheres.center[:, None], axis=-1) - env.spheres.radius[:, None]
        out.update({f"spheres[{j}]": d[j] for j in range(len(env.spheres))})
    if len(env.prisms) and len(points):
        d = prism_signed_distance(points, env.prisms)
        out.update({f"prisms[{k}]": d[k] for k in range(len(env.prisms))})
    return out


def nearest_obstacle(points: np.ndarray, env: Environment) -> tuple[float, str | None]:
    """(signed clearance, name) of the static obstacle nearest any of ``points``; (inf, None) without one."""
    per = {k: float(v.min()) for k, v in obstacle_distances(points, env).items()}
    nearest = min(per, key=per.__getitem__, default=None)
    return (per[nearest] if nearest is not None else math.inf), nearest


def check_trajectory(
    traj: Trajectory, waypoints: np.ndarray, env: Environment, hazard: HazardConfig,
    vehicle: VehicleLimits, timed: bool = False, start_heading: np.ndarray | None = None,
) -> CheckResult:
    """Count violations of collision (clearance < d_coll; radars: inside detection range), altitude
    band above terrain, region bounds, turn (curvature > 1/R_min or a waypoint turn > max) and climb.
    ``start_heading``: the vehicle's direction at the start; the turn from it into the first leg is a waypoint
    turn too, and the first leg must be long enough to fly it (its Bézier's peak curvature, §11.2)."""
    p = traj.points
    times = traj.times if timed else None
    solid = obstacle_clearance(p, times, env, include_radars=False)
    radar = radar_clearance(p, env.radars)
    bad: dict[str, np.ndarray] = {}
    # obstacles are violated inside d_coll, radars inside their detection range
    bad["collision"] = (solid < hazard.d_coll - _TOL_M) | (radar < -_TOL_M)
    h = p[:, 2] - env.ground(p[:, 0], p[:, 1])
    bad["altitude"] = (h < env.z_min - _TOL_M) | (h > env.z_max + _TOL_M)
    if env.terrain is not None and len(p) > 1:  # between samples too: the chords, exactly over the terrain
        bad["altitude"][:-1] |= env.band_depth(p[:-1], p[1:]) > _TOL_M
    bad["bounds"] = ((p[:, 0] < -_TOL_M) | (p[:, 0] > env.size_x + _TOL_M)
                     | (p[:, 1] < -_TOL_M) | (p[:, 1] > env.size_y + _TOL_M))
    bad["turn"] = traj.curvature * vehicle.min_turn_radius > 1.0 + _TOL_REL
    bad["climb"] = np.abs(climb_angle(traj.tangent)) > vehicle.max_climb * (1.0 + _TOL_REL)
    counts = {c: _runs(bad[c]) for c in CATEGORIES}
    locations = {c: p[_run_starts(bad[c])][:MAX_REPORTED].round(1).tolist() for c in CATEGORIES}
    # waypoint turn angles beyond the vehicle's limit (horizontal heading change)
    seg = np.diff(np.asarray(waypoints, dtype=float), axis=0)
    sharp = np.flatnonzero(horizontal_turn(seg) > vehicle.max_turn * (1.0 + _TOL_REL))
    if start_heading is not None and len(seg):
        first = seg[0] / max(float(np.linalg.norm(seg[0])), 1e-9)
        tight = peak_curvature(float(np.linalg.norm(seg[0])), first @ start_heading) * vehicle.min_turn_radius
        if horizontal_turn(np.stack([start_heading, seg[0]]))[0] > vehicle.max_turn * (1.0 + _TOL_REL) \
                or tight > 1.0 + _TOL_REL:
            sharp = np.concatenate([[-1], sharp])  # the turn at the start (waypoint 0)
    counts["turn"] += len(sharp)
    locations["turn"] += np.asarray(waypoints)[sharp + 1][:MAX_REPORTED].round(1).tolist()
    return CheckResult(counts, {k: v for k, v in locations.items() if v}, np.minimum(solid, radar))


def radar_clearance(points: np.ndarray, radars: Radars) -> np.ndarray:
    """Distance (M,) from points (M, 3) to the nearest radar's detection range (negative inside; §2.4)."""
    if not len(radars):
        return np.full(len(points), np.inf)
    d = np.linalg.norm(points[None] - radars.center[:, None], axis=-1)
    return (d - radars.r_det[:, None]).min(axis=0)


def _run_starts(mask: np.ndarray) -> np.ndarray:
    return np.flatnonzero(mask & ~np.concatenate([[False], mask[:-1]]))


def _runs(mask: np.ndarray) -> int:
    return int(len(_run_starts(mask)))


# --- metrics (docs/method.md §13) ---------------------------------------------------------------------
def smoothness(waypoints: np.ndarray) -> float:
    """Σ of 3-D turning angles at interior waypoints, radians."""
    d = np.diff(np.asarray(waypoints, dtype=float), axis=0)
    u = d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    return float(np.arccos(np.clip(np.sum(u[:-1] * u[1:], axis=1), -1.0, 1.0)).sum())


def robustness(clearance: np.ndarray, curvature_: np.ndarray, d_safe: float) -> float:
    """R = mean over samples of clip((D_obs − D_safe)/D_safe, 0, 1) · 1/(1 + κ²) (paper §4.5, Eq. (52);
    docs/method.md §13.2)."""
    safety = np.clip((clearance - d_safe) / d_safe, 0.0, 1.0)
    return float(np.mean(safety / (1.0 + curvature_**2)))


def convergence_iteration(history: list[float] | np.ndarray) -> int:
    """First iteration reaching 90 % of the total reduction of the best cost (0 if it never fell)."""
    h = np.asarray(history, dtype=float)
    drop = h[0] - h[-1]
    if drop <= 0:
        return 0
    return int(np.argmax(h[0] - h >= 0.9 * drop))
