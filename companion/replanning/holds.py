"""Hold patterns checked like routes (docs/design.md, "Checked holds").

ArduPlane's LOITER circles the point where it was when the mode changed, at WP_LOITER_RAD: entered 60 m from a
no-fly cylinder on SITL, the 80 m circle ran 40–64 m into it. So a plane's hold is a circle we choose: a centre
and radius whose approach and circle clear every static obstacle by d_coll plus a tracking margin and keep known
traffic at d_coll over the time it may circle, commanded with MAV_CMD_DO_REPOSITION (GUIDED, its own radius).
Candidates start with the circle tangent to the vehicle's track (it turns straight onto it) on either side, then
centres further along the track. A copter brakes and hovers; its stopping distance is checked the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.trajectory.checks import nearest_obstacle
from planner.world.environment import Environment, Threats

HOLD_MARGIN_M = 10.0  # beyond d_coll: the path-follower captures the circle a little wide
TIGHT_HOLD_MARGIN_M = 5.0  # beyond d_coll: the least a hold circle may keep when none keeps HOLD_MARGIN_M
# ArduPlane flies its circles wider than asked (SITL: 80 m flown at 96.7 m, 120 m at 135.5 m;
# tests/conformance/test_hold_turn.py): the check covers the ring out to this much beyond the radius
FLOWN_WIDER_M = 20.0
CIRCLE_POINTS = 72
AHEAD_STEP_M = 40.0  # centres tried this far apart along the track
AHEAD_STEPS = 8
HOLD_HORIZON_S = 60.0  # vehicle seconds of circling checked against traffic
TRAFFIC_DT_S = 1.0
# an exit whose route turns this much more than the best-aligned one's is taken if it comes sooner (circling on for
# the best one takes up to a whole circle, 35 s on SITL). With 30°, a plane on the simulator resumed into a 38° turn
# at the exit and swung 11.4 m from a cylinder its route had passed at d_coll + 10 m and its swing
EXIT_TURN_DEG = 15.0


@dataclass(frozen=True)
class HoldPattern:
    """A checked hold. ``kind``: "circle" (plane: centre, radius, clockwise) or "brake" (copter). ``path`` is what was
    checked (approach and one circle, or the stopping run); clearances are from its worst point."""

    kind: str
    centre: np.ndarray
    radius: float
    clockwise: bool
    path: np.ndarray
    clearance_m: float
    nearest_obstacle: str | None
    traffic_separation_m: float

    def summary(self) -> dict[str, object]:
        return {"kind": self.kind, "centre": np.round(self.centre, 1).tolist(), "radius_m": round(self.radius, 1),
                "clockwise": self.clockwise, "clearance_m": round(self.clearance_m, 1),
                "nearest_obstacle": self.nearest_obstacle,
                "traffic_separation_m": None if not math.isfinite(self.traffic_separation_m)
                else round(self.traffic_separation_m, 1)}


def _circle_path(p: np.ndarray, centre: np.ndarray, radius: float, clockwise: bool) -> np.ndarray:
    """The approach from ``p`` (straight towards the circle, as the path-follower captures it) and one whole circle,
    (M, 3) at the vehicle's altitude, in flying order."""
    c2, p2 = centre[:2], p[:2]
    d = float(np.linalg.norm(p2 - c2))
    a0 = circle_angle(p2, c2) if d > 1e-6 else 0.0
    entry = c2 + radius * np.array([math.cos(a0), math.sin(a0)])
    approach = np.linspace(p2, entry, max(int(abs(d - radius) / 5.0), 1) + 1)
    sign = -1.0 if clockwise else 1.0  # counter-clockwise is increasing angle
    ang = a0 + sign * np.linspace(0.0, 2 * math.pi, CIRCLE_POINTS + 1)
    ring = c2 + radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    flat = np.vstack([approach, ring[1:]])
    return np.column_stack([flat, np.full(len(flat), p[2])])


def _circle_paths(p: np.ndarray, centre: np.ndarray, radius: float, clockwise: bool) -> tuple[np.ndarray, np.ndarray]:
    """(:func:`_circle_path` of the circle asked, the same of the circle flown, :data:`FLOWN_WIDER_M` wider)."""
    return _circle_path(p, centre, radius, clockwise), _circle_path(p, centre, radius + FLOWN_WIDER_M, clockwise)


def ring(centre: np.ndarray, radius: float, z: float) -> np.ndarray:
    """(CIRCLE_POINTS + 1, 3) points of the circle of ``radius`` round ``centre`` (x, y) at altitude ``z``."""
    a = np.linspace(0.0, 2 * math.pi, CIRCLE_POINTS + 1)
    return np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), np.full(a.size, z)], axis=1)


def flown_ring(centre: np.ndarray, radius: float, z: float) -> np.ndarray:
    """The circle as the autopilot will fly it, :data:`FLOWN_WIDER_M` wider than asked."""
    return ring(centre, radius + FLOWN_WIDER_M, z)


def _flown_at(path: np.ndarray, speed: float, times: np.ndarray) -> np.ndarray:
    """(T, 3) where a vehicle flying ``path`` (an approach then one circle, :func:`_circle_path`) at ``speed`` is
    at ``times``, round and round the circle (its last point back to the circle's start)."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    along = np.minimum(times * max(speed, 0.1), s[-1])
    if s[-1] > 0:  # the circle repeats: wrap the arc length past the end back over the circle part
        approach_len = s[max(len(path) - CIRCLE_POINTS - 1, 0)]
        lap = s[-1] - approach_len
        over = times * max(speed, 0.1) - approach_len
        along = np.where(over > 0, approach_len + np.mod(over, max(lap, 1e-6)), times * max(speed, 0.1))
    return np.stack([np.interp(along, s, path[:, k]) for k in range(3)], axis=1)


def _traffic_separation(paths: tuple[np.ndarray, ...], speed: float, t0: float, threats: Threats | None,
                        horizon_s: float) -> float:
    """Least separation (distance − radius) from ``threats`` while flying any of ``paths`` (:func:`_flown_at`)
    from time ``t0`` at ``speed`` for ``horizon_s``; the threats' positions are predicted once for all."""
    if threats is None or not len(threats) or any(len(p) < 2 for p in paths):
        return math.inf
    times = np.arange(0.0, horizon_s + TRAFFIC_DT_S, TRAFFIC_DT_S)
    centres = threats.positions(t0 + times)  # (k, T, 3)
    radii = threats.radii(t0 + times)
    return min(float((np.linalg.norm(centres - _flown_at(p, speed, times)[None], axis=-1) - radii).min())
               for p in paths)


def plane_hold(position: np.ndarray, velocity: np.ndarray, radius: float, env: Environment, d_coll: float,
               speed: float, threats: Threats | None = None, t_now: float = 0.0,
               min_radius: float | None = None, turn_radius: float = 0.0, lag_m: float = 0.0) -> HoldPattern | None:
    """The first circle of ``radius`` (tangent to the track on the right, then the left, then centres further
    along the track) whose approach and circle clear every static obstacle by d_coll + :data:`HOLD_MARGIN_M` and
    keep ``threats`` (timed from ``t_now``) at d_coll + the same margin for :data:`HOLD_HORIZON_S`, else the one of
    that radius that keeps them furthest beyond d_coll; then the same with smaller circles, down to ``min_radius``
    (the radius is ours to command); None when there is none. The centre stays inside the region and the altitude
    is the vehicle's own (it holds its altitude). ``turn_radius``: the widest the plane may turn onto the circle,
    ``lag_m`` how far it may fly on straight before it starts turning; the circle it sweeps turning so from its
    track (on the circle's side) must clear the obstacles too."""
    radii = [radius]
    if min_radius is not None:
        radii += [r for r in (0.75 * radius, 0.5 * radius, min_radius) if min_radius <= r < radius]
    tight: list[HoldPattern] = []
    for r in radii:
        found, close = _plane_hold(position, velocity, r, env, d_coll, speed, threats, t_now, turn_radius, lag_m)
        if found is not None:
            return found
        tight += close
    # none with the whole margin: the circle that clears the obstacles furthest, if by TIGHT_HOLD_MARGIN_M (on the
    # simulator, with the plan late and an intruder 18 s ahead, the best circle cleared a cylinder by 19.4 m
    # against the 20 asked; refused, the plane flew on into the intruder: −4 m)
    return max(tight, key=lambda h: h.clearance_m, default=None)


def _plane_hold(position: np.ndarray, velocity: np.ndarray, radius: float, env: Environment, d_coll: float,
                speed: float, threats: Threats | None, t_now: float, turn_radius: float = 0.0,
                lag_m: float = 0.0) -> tuple[HoldPattern | None, list[HoldPattern]]:
    """(the pattern :func:`plane_hold` takes at this radius, else None; the circles that keep the traffic by the
    margin but clear the obstacles only by d_coll + :data:`TIGHT_HOLD_MARGIN_M`)."""
    p = np.asarray(position, dtype=float)
    v = np.asarray(velocity, dtype=float)[:2]
    heading = v / n if (n := float(np.linalg.norm(v))) > 0.5 else np.array([0.0, 1.0])
    right = np.array([heading[1], -heading[0]])
    need = d_coll + HOLD_MARGIN_M
    best: HoldPattern | None = None  # clear of the traffic by d_coll, not yet by the margin
    tight: list[HoldPattern] = []
    for k in range(AHEAD_STEPS + 1):
        base = p[:2] + k * AHEAD_STEP_M * heading
        for side, clockwise in ((right, True), (-right, False)):
            centre2 = base + radius * side
            if not (0.0 <= centre2[0] <= env.size_x and 0.0 <= centre2[1] <= env.size_y):  # (the region's edge
                # is the planner's, not a hazard: a circle may cross it; its obstacles are what it must clear)
                continue
            centre = np.array([*centre2, p[2]])
            paths = _circle_paths(p, centre, radius, clockwise)
            path = paths[0]
            # the turn onto it, begun late and wider than the circle (ArduPlane SITL at 23.8 m/s flew on straight
            # for ~2 s after the command, then turned onto a 50 m circle at ~60 m: 3.0 m from a cylinder that
            # circle cleared by 27.9 m), sweeps this one
            turn = max(turn_radius, radius)
            entry = ring(base + lag_m * heading + turn * side, turn, p[2])
            clearance, nearest = nearest_obstacle(np.vstack([path, flown_ring(centre, radius, p[2]), entry]), env)
            if clearance < d_coll + TIGHT_HOLD_MARGIN_M:
                continue
            sep = _traffic_separation(paths, speed, t_now, threats, HOLD_HORIZON_S)
            pattern = HoldPattern("circle", centre, radius, clockwise, path, clearance, nearest, sep)
            if clearance < need:
                if sep >= d_coll + HOLD_MARGIN_M:
                    tight.append(pattern)
                continue
            if sep >= d_coll + HOLD_MARGIN_M:
                return pattern, tight
            if sep >= d_coll and (best is None or sep > best.traffic_separation_m):
                best = pattern
    return best, tight


def circle_traffic_separation(position: np.ndarray, centre: np.ndarray, radius: float, clockwise: bool,
                              speed: float, t_now: float, threats: Threats | None) -> float:
    """Least separation from ``threats`` of a plane circling ``centre`` from ``position`` for
    :data:`HOLD_HORIZON_S`: on the circle asked and on the one flown (:data:`FLOWN_WIDER_M` wider; on CI's loaded
    simulator a hold checked at 13.3 m on the circle asked came −8.6 m from a crossing aircraft)."""
    paths = _circle_paths(np.asarray(position, dtype=float), centre, radius, clockwise)
    return _traffic_separation(paths, speed, t_now, threats, HOLD_HORIZON_S)


def copter_hold(position: np.ndarray, velocity: np.ndarray, stopping_distance: float, env: Environment,
                d_coll: float) -> HoldPattern:
    """A copter's brake-and-hover: the run from ``position`` along its ``velocity`` to where it stops (at least
    ``stopping_distance`` scaled to its speed), checked against the static world (it is flown whatever the
    verdict: stopping is a copter's safest move; the clearance says whether it was clear)."""
    p = np.asarray(position, dtype=float)
    v2 = np.asarray(velocity, dtype=float)[:2]
    n = float(np.linalg.norm(v2))
    direction = np.array([*(v2 / n), 0.0]) if n > 0.1 else np.zeros(3)
    run = np.linspace(p, p + direction * stopping_distance, 20)
    clearance, nearest = nearest_obstacle(run, env)
    return HoldPattern("brake", run[-1], 0.0, True, run, clearance, nearest, math.inf)


@dataclass(frozen=True)
class CircleExit:
    """Where a plane circling a hold leaves it for a new route: ``point`` on the circle it flies, the unit
    ``heading`` it flies there (the circle's tangent), and the ``arc_m`` it still circles to get there."""

    point: np.ndarray
    heading: np.ndarray
    arc_m: float


def circle_angle(p: np.ndarray, centre: np.ndarray) -> float:
    """The angle (rad, from east, counter-clockwise) of ``p`` seen from ``centre``."""
    return math.atan2(float(p[1] - centre[1]), float(p[0] - centre[0]))


def arc_to(position: np.ndarray, centre: np.ndarray, clockwise: bool, point: np.ndarray) -> float:
    """The angle (rad, in [0, 2π)) still to circle from ``position`` to ``point``, seen from ``centre``."""
    turn = circle_angle(position, centre) - circle_angle(point, centre)
    return (turn if clockwise else -turn) % (2.0 * math.pi)


def circle_exit(position: np.ndarray, centre: np.ndarray, clockwise: bool, toward: np.ndarray,
                min_arc_m: float) -> CircleExit:
    """The exit from a hold circle (docs/design.md, "Leaving a hold"): the point, at least ``min_arc_m`` of
    circling ahead of ``position``, whose tangent points most nearly at ``toward`` (the goal). The circle is the
    one flown (its radius is the vehicle's distance from ``centre``: ArduPlane circles wider than asked), so the
    new route starts where the plane will be, flying the way it will fly, and it is planned without a turn
    the plane cannot make from its circle."""
    r = max(float(np.linalg.norm(position[:2] - centre[:2])), 1.0)
    sense = -1.0 if clockwise else 1.0
    a0 = circle_angle(position, centre)
    turns = np.linspace(0.0, 2.0 * math.pi, CIRCLE_POINTS, endpoint=False)
    angles = a0 + sense * (min_arc_m / r + turns)
    pts = centre[:2] + r * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    tangents = sense * np.stack([-np.sin(angles), np.cos(angles)], axis=1)
    to = toward[:2] - pts
    cos = np.einsum("ij,ij->i", tangents, to) / np.maximum(np.linalg.norm(to, axis=1), 1e-6)
    off = np.arccos(np.clip(cos, -1.0, 1.0))
    k = int(np.flatnonzero(off <= off.min() + math.radians(EXIT_TURN_DEG))[0])  # the nearest of the best-aligned
    point = np.array([pts[k, 0], pts[k, 1], float(position[2])])
    return CircleExit(point, np.array([tangents[k, 0], tangents[k, 1], 0.0]), min_arc_m + r * float(turns[k]))
