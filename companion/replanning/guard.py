"""The flown-safety guard: where the vehicle itself will be in the next seconds, against the static world
(docs/design.md, "The flown-safety guard").

A route is checked when it is planned; the vehicle then flies it with its own path-follower, and a turn flown wider
than planned, a join from off the route or a plan that was never ours can still carry it into an obstacle. The
guard predicts the vehicle's own path a few seconds ahead from its measured position and velocity, turning towards
the items it will fly no faster than its turn radius allows, and reports the first point that comes within d_coll
of a static obstacle: the replanner then holds it on a checked pattern (or plans a static route from where it is)
before the breach, not after.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.trajectory.checks import obstacle_distances
from planner.world.environment import Environment

GUARD_HORIZON_S = 6.0  # vehicle seconds predicted
GUARD_DT_S = 0.25


@dataclass(frozen=True)
class Breach:
    """The predicted path comes ``clearance_m`` from ``obstacle`` in ``in_s`` vehicle seconds, at ``point``."""

    obstacle: str
    clearance_m: float
    in_s: float
    point: tuple[float, float, float]


def predict_own_path(position: np.ndarray, velocity: np.ndarray, origin: np.ndarray, targets: np.ndarray,
                     turn_radius: float, acceptance_m: float, horizon_s: float = GUARD_HORIZON_S,
                     dt: float = GUARD_DT_S, direct: bool = False, sense: int = 0, climb_rate: float = math.inf,
                     sink_rate: float = math.inf, height_lag_s: float = 0.0, climbing: float = 0.0) -> np.ndarray:
    """(K, 4) rows (t, x, y, z): from ``position`` with horizontal ``velocity`` (ENU m/s), following the legs
    ``origin`` → ``targets[0]`` → ``targets[1]`` … as a path-follower does (it steers at a point a turn radius ahead
    on the leg, at a turn rate of at most v / ``turn_radius``; 0: turns at once, a copter), taking the next leg
    within ``acceptance_m`` of a target or past the line through it square to the leg, climbing so as to reach each
    target's altitude on arrival. ``direct``: the first target is flown to straight from wherever the vehicle is,
    with no leg to hold to (ArduPlane entering AUTO: ``Mode::enter`` turns cross-tracking off for the first
    waypoint), so a vehicle that turns round first flies to it from where its turn ends. ``sense`` (+1 right, −1
    left, 0 the shorter way): the way it turns while its target is more than 90° off its heading. Its height follows
    the demanded one (each target's altitude on arrival) at most at ``climb_rate`` / ``sink_rate`` m/s, behind it by
    a first-order lag of ``height_lag_s`` (a plane's TECS: docs/design.md, "The flown-safety guard"), from a demand
    that has it climbing at ``climbing`` m/s now."""
    p = np.asarray(position, dtype=float).copy()
    v = np.asarray(velocity, dtype=float)[:2]
    speed = float(np.linalg.norm(v))
    heading = math.atan2(v[0], v[1]) if speed > 0.5 else None
    speed = max(speed, 1.0)
    targets = np.asarray(targets, dtype=float).reshape(-1, 3)
    prev = np.asarray(origin, dtype=float)
    k = 0
    rows = [(0.0, *p)]
    rate = speed / turn_radius if turn_radius > 0 else math.inf
    demand = float(p[2]) + climbing * height_lag_s  # the height the autopilot asks for; the vehicle's follows it
    follow = 1.0 - math.exp(-dt / height_lag_s) if height_lag_s > 0 else 1.0
    ahead = max(turn_radius, speed * dt)
    for i in range(1, round(horizon_s / dt) + 1):
        while k < len(targets) - 1:
            leg = targets[k, :2] - prev[:2]
            past = float(np.dot(p[:2] - targets[k, :2], leg)) > 0.0 and float(np.dot(leg, leg)) > 1.0
            if math.hypot(*(targets[k, :2] - p[:2])) > acceptance_m and not past:
                break
            prev, k = targets[k], k + 1
        if len(targets):
            leg = targets[k, :2] - prev[:2]
            n = float(np.linalg.norm(leg))
            if n > 1.0 and not (direct and k == 0):  # the carrot: ``ahead`` beyond the vehicle's projection on the leg
                along = float(np.clip(np.dot(p[:2] - prev[:2], leg) / n + ahead, 0.0, n))
                carrot = prev[:2] + leg * (along / n)
            else:
                carrot = targets[k, :2]
            to = carrot - p[:2]
            want = math.atan2(to[0], to[1])
            if heading is None:
                heading = want
            turn = (want - heading + math.pi) % (2 * math.pi) - math.pi
            if sense and abs(turn) > math.pi / 2 and turn * sense < 0:
                turn += 2 * math.pi * sense  # the long way round, as the vehicle already turns
            heading += max(-rate * dt, min(rate * dt, turn))
            dist = max(math.hypot(*(targets[k, :2] - p[:2])), 1e-6)
            demand += (targets[k, 2] - demand) * min(speed * dt / dist, 1.0)
            p[2] += float(np.clip((demand - p[2]) * follow, -sink_rate * dt, climb_rate * dt))
        elif heading is None:
            heading = 0.0
        p[0] += speed * dt * math.sin(heading)
        p[1] += speed * dt * math.cos(heading)
        rows.append((i * dt, *p))
    return np.array(rows)


def first_breach(path: np.ndarray, env: Environment, d_coll: float) -> Breach | None:
    """The first row of ``path`` (t, x, y, z) within ``d_coll`` of a static obstacle, or None."""
    per = obstacle_distances(path[:, 1:4], env)
    if not per:
        return None
    names = list(per)
    d = np.stack([per[n] for n in names])  # (obstacles, K)
    bad = np.flatnonzero(d.min(axis=0) < d_coll)
    if not bad.size:
        return None
    j = int(bad[0])
    o = int(np.argmin(d[:, j]))
    return Breach(names[o], float(d[o, j]), float(path[j, 0]),
                  (float(path[j, 1]), float(path[j, 2]), float(path[j, 3])))
