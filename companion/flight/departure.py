"""The departure: from where the vehicle stands to the route's start, as the autopilot will fly it, checked like
any other leg before anything is uploaded (docs/design.md, "Departure").

ArduPlane takes off where it stands, straight ahead on its heading, and only after the take-off altitude turns
towards the first waypoint, as its path-follower (L1) turns. On SITL, from the region's corner, that
climb-out ran 270 m north before the turn; started 300 m east, it went straight through a no-fly cylinder. A
copter climbs vertically and then flies straight to the start. A VTOL (PX4's NAV_VTOL_TAKEOFF) climbs vertically
and then transitions on whatever heading it has at the top (the SIH standard VTOL yawed from 351° to 276° in its
climb), before it turns towards the start as a fixed-wing. Where the plane really climbs and turns is not known to
the metre, so the check covers an envelope: the steepest and the shallowest take-off climb, the tightest turn, and
the path-follower's turn after the roll-in; for a VTOL, the transition on every heading.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.mavlink.vehicle_limits import AutopilotLimits
from planner.trajectory.checks import nearest_obstacle
from planner.world.environment import Environment

PLANE_GROUND_ROLL_M = 30.0  # ArduPlane SITL: lift-off about 30 m down the runway
# ArduPlane's take-off climbs at full throttle to the take-off altitude, not at its TECS limit (SITL: 10 m/s at
# 27 m/s, 21.7°); the envelope spans 18-25° around that
PLANE_STEEPEST_CLIMB_DEG = 25.0
PLANE_SHALLOWEST_CLIMB_DEG = 18.0
PLANE_TAKEOFF_SPEED_M_S = 27.0  # ground speed in the take-off climb and the first turn (SITL)
PLANE_ROLL_IN_S = 2.0  # s flown straight on while the plane rolls into its first turn (the wide case)
VTOL_TRANSITION_RUN_M = 40.0  # flown straight on while a VTOL transitions (PX4 SIH: 2.0-2.7 s to 10 m/s)
VTOL_HEADINGS = 12  # transition headings checked, all round
DEPARTURE_MARGIN_M = 5.0  # beyond d_coll: the envelope is a model, not a measurement
SAMPLE_M = 5.0  # spacing of the checked points
REGION_TOLERANCE_M = 25.0  # a vehicle this close outside the region (GPS noise at a corner home) is inside
HOME_ALT_TOLERANCE_M = 10.0  # the autopilot's home this far above or below the scenario's: the altitudes are off


@dataclass(frozen=True)
class VehicleFix:
    """Where the vehicle is before the flight, in the scenario's ENU frame (z above the scenario's home)."""

    position: np.ndarray  # (3,)
    heading_deg: float | None  # compass, None when the autopilot does not say
    home: np.ndarray | None  # the autopilot's home (3,) in the same frame, None when it did not send one

    def summary(self) -> dict[str, object]:
        return {"position": np.round(self.position, 1).tolist(), "heading_deg": self.heading_deg,
                "home": None if self.home is None else np.round(self.home, 1).tolist()}


@dataclass(frozen=True)
class Departure:
    """The checked envelope: its paths (each (M, 3)), the least clearance over them, and why it is refused."""

    paths: list[np.ndarray]
    clearance_m: float
    nearest_obstacle: str | None
    refusal: str | None  # one line, or None when the vehicle can fly it
    # the turn onto the route's first leg (join_paths) comes closer than the departure's margin: one line. Advisory:
    # the model is not yet calibrated against SITL (on ArduPlane SITL at a 30° roll limit it foresaw cylinders[3]
    # 67 m in, the real track breached cylinders[0] elsewhere); the flown track's verdict stands
    join_warning: str | None = None

    def summary(self) -> dict[str, object]:
        return {"paths": len(self.paths), "clearance_m": round(self.clearance_m, 1) if math.isfinite(
            self.clearance_m) else None, "nearest_obstacle": self.nearest_obstacle, "refusal": self.refusal,
            "join_warning": self.join_warning}


def _compass(v: np.ndarray) -> float:
    """Compass degrees (0 north, 90 east) of a horizontal vector (east, north)."""
    return math.degrees(math.atan2(float(v[0]), float(v[1]))) % 360.0


def _unit(deg: float) -> np.ndarray:
    r = math.radians(deg)
    return np.array([math.sin(r), math.cos(r)])


def turn_then_straight(p: np.ndarray, heading: np.ndarray, target: np.ndarray, radius: float) -> np.ndarray:
    """Horizontal path (K, 2): from ``p`` on ``heading`` (unit), a turn of ``radius`` towards ``target`` until it
    points at it, then straight to it. A target inside the turn circle gets the whole circle first (the vehicle
    overshoots and comes round)."""
    to = target - p
    if radius <= 0 or float(np.linalg.norm(to)) < 1e-6:
        return np.stack([p, target])
    side = 1.0 if heading[0] * to[1] - heading[1] * to[0] < 0 else -1.0  # +1: turn right (clockwise)
    normal = side * np.array([heading[1], -heading[0]])  # towards the turn centre
    c = p + radius * normal
    d = float(np.linalg.norm(target - c))
    a0 = math.atan2(*(p - c)[::-1])
    if d <= radius:  # inside the circle: one full turn, then straight
        arc = np.linspace(0.0, 2 * math.pi, 73)
        ring = c + radius * np.stack([np.cos(a0 - side * arc), np.sin(a0 - side * arc)], axis=1)
        return np.vstack([ring, target])
    # tangent point from the target on the side the vehicle turns
    beta = math.atan2(*(target - c)[::-1])
    alpha = math.acos(radius / d)
    exit_angle = beta + side * alpha
    sweep = (a0 - exit_angle) * side % (2 * math.pi)  # clockwise turns sweep angles downwards
    n = max(int(sweep * radius / SAMPLE_M), 2)
    angles = a0 - side * np.linspace(0.0, sweep, n)
    arc = c + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return np.vstack([arc, target])


def _densify(path: np.ndarray, spacing: float = SAMPLE_M) -> np.ndarray:
    seg = np.diff(path, axis=0)
    out = [path[:1]]
    for a, s in zip(path[:-1], seg, strict=True):
        n = max(math.ceil(float(np.linalg.norm(s)) / spacing), 1)
        out.append(a + np.outer(np.arange(1, n + 1) / n, s))
    return np.vstack(out)


def _to_start(top: np.ndarray, heading: np.ndarray, start: np.ndarray, alt: float, radius: float) -> np.ndarray:
    """(M, 3) from just after ``top`` (2-D, at ``alt``) to ``start``: :func:`turn_then_straight` at ``alt``, the last
    point at the start's own altitude."""
    flat = turn_then_straight(top, heading, start[:2], radius)
    z = np.concatenate([[alt] * (len(flat) - 1), [start[2]]])
    return np.column_stack([flat, z])[1:]


def departure_paths(fix: VehicleFix, start: np.ndarray, takeoff_alt: float,
                    limits: AutopilotLimits) -> list[np.ndarray]:
    """The envelope of paths (M, 3) from the vehicle to the route's ``start``."""
    p0 = np.asarray(fix.position, dtype=float)
    start = np.asarray(start, dtype=float)
    alt = max(takeoff_alt, float(start[2]))
    up = np.array([p0[0], p0[1], alt])
    if limits.vertical_takeoff:
        paths = []
        for deg in np.arange(VTOL_HEADINGS) * 360.0 / VTOL_HEADINGS:
            heading = _unit(float(deg))
            top = p0[:2] + VTOL_TRANSITION_RUN_M * heading
            turn = _to_start(top, heading, start, alt, limits.wide_turn_radius())
            paths.append(_densify(np.vstack([p0, up, [*top, alt], turn])))
        return paths
    if limits.vehicle_type != "plane":
        return [_densify(np.stack([p0, up, start]))]
    heading = _unit(fix.heading_deg or 0.0)
    paths = []
    for climb_deg in (PLANE_STEEPEST_CLIMB_DEG, PLANE_SHALLOWEST_CLIMB_DEG):
        run = PLANE_GROUND_ROLL_M + alt / math.tan(math.radians(climb_deg))
        for radius, roll_in in ((limits.turn_radius, 0.0),
                                (limits.wide_turn_radius(PLANE_TAKEOFF_SPEED_M_S), PLANE_ROLL_IN_S)):
            top = p0[:2] + (run + roll_in * PLANE_TAKEOFF_SPEED_M_S) * heading
            climb = np.stack([p0, [*(p0[:2] + PLANE_GROUND_ROLL_M * heading), p0[2]], [*(p0[:2] + run * heading), alt],
                              [*top, alt]])
            paths.append(_densify(np.vstack([climb, _to_start(top, heading, start, alt, radius)])))
    return paths


def join_paths(paths: list[np.ndarray], onto: np.ndarray, limits: AutopilotLimits) -> list[tuple[int, np.ndarray]]:
    """The turns (M, 3) from each departure path's arrival at the route's start onto its first leg, towards
    ``onto`` (the route's next waypoint), with the index of the path each follows: a plane's path-follower turns
    from the heading it arrives on, at its tightest and at its wide (L1) radius, and may swing well past the start
    when the leg turns back. Only the turn: once it points at ``onto`` it flies the planned leg, which the plan
    checked. A copter turns on the spot (none)."""
    if limits.vehicle_type != "plane":
        return []
    out = []
    for k, path in enumerate(paths):
        start = path[-1]
        arrive = start[:2] - path[-2][:2]
        norm = float(np.linalg.norm(arrive))
        if norm < 1e-6:
            continue
        for radius in sorted({limits.turn_radius, limits.wide_turn_radius()}):
            flat = turn_then_straight(start[:2], arrive / norm, np.asarray(onto[:2], dtype=float), radius)[:-1]
            if len(flat) < 2:
                continue
            run = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(flat, axis=0), axis=1))])
            leg = max(float(np.linalg.norm(np.asarray(onto[:2]) - start[:2])), 1e-9)
            z = start[2] + (float(onto[2]) - start[2]) * np.minimum(run / leg, 1.0)
            out.append((k, _densify(np.column_stack([flat, z]))))
    return out


def check_departure(fix: VehicleFix, start: np.ndarray, takeoff_alt: float, limits: AutopilotLimits,
                    env: Environment, d_coll: float, on_ground: bool = True,
                    onto: np.ndarray | None = None) -> Departure:
    """The departure's verdict: refused (one line) when the vehicle is outside the region, its home's altitude
    is not the scenario's, or any path of the envelope comes within d_coll + :data:`DEPARTURE_MARGIN_M` of a
    static obstacle. An airborne vehicle flies straight to the start from where it is (checked the same way).
    ``onto``: the route's next waypoint; the turns from the envelope's arrival onto the first leg
    (:func:`join_paths`) are checked too, and one closer than the margin is a ``join_warning`` (not a refusal)."""
    p = np.asarray(fix.position, dtype=float)
    where = f"at ({p[0]:.0f}, {p[1]:.0f}) m"
    if fix.home is not None and abs(float(fix.home[2])) > HOME_ALT_TOLERANCE_M:
        return Departure([], math.nan, None, f"the autopilot's home is {fix.home[2]:+.0f} m from the scenario's "
                         "home altitude: every mission altitude would be off by that; set its home or the scenario's")
    tol = REGION_TOLERANCE_M
    if not (-tol <= p[0] <= env.size_x + tol and -tol <= p[1] <= env.size_y + tol):
        return Departure([], math.nan, None, f"the vehicle is {where}, outside the scenario's region "
                         f"(0..{env.size_x:g} × 0..{env.size_y:g} m): it cannot be flown from there")
    paths = departure_paths(fix, start, takeoff_alt, limits) if on_ground else [_densify(np.stack([p, start]))]
    joins = [] if onto is None else join_paths(paths, onto, limits)
    clearance, nearest = nearest_obstacle(np.vstack(paths), env)
    need = d_coll + DEPARTURE_MARGIN_M
    warning = None
    if joins:
        per = [nearest_obstacle(j, env) for _, j in joins]
        worst = int(np.argmin([c for c, _ in per]))
        join_clearance, join_nearest = per[worst]
        if join_clearance < need:
            came = paths[joins[worst][0]]
            warning = (f"the vehicle {where} may reach the route's start heading "
                       f"{_compass(came[-1][:2] - came[-2][:2]):.0f}° and its turn onto the first leg come "
                       + (f"{-join_clearance:.0f} m inside {join_nearest}" if join_clearance < 0
                          else f"{join_clearance:.0f} m from {join_nearest}")
                       + f" (the departure keeps {need:g} m)")
        paths = paths + [j for _, j in joins]
    if clearance < need:
        how = (f"take off on heading {fix.heading_deg or 0.0:.0f}° and climb out" if on_ground and
               limits.vehicle_type == "plane" else "climb out" if on_ground else "fly")
        return Departure(paths, clearance, nearest, (
            f"the vehicle {where} would {how} to the route's start "
            + (f"{-clearance:.0f} m inside {nearest}" if clearance < 0 else f"{clearance:.0f} m from {nearest}")
            + f" (needs {need:g} m): nothing uploaded; move the vehicle (or turn it) or start the route elsewhere"),
            warning)
    return Departure(paths, clearance, nearest, None, warning)
