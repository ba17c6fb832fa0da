"""Mission builder: planned route (ENU) → MAVLink mission and fence items (docs/design.md, "Companion" and
"Autopilot profiles"; what the autopilots do with the items: docs/autopilots.md §3–5, §7.2, §11.2).

Mission layout (``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``, altitude = ENU z = metres above home):

    [ArduPilot only] 0  NAV_WAYPOINT at home, frame GLOBAL, AMSL alt   (the layout's ``home_item``)
                        NAV_TAKEOFF at the start, z = max(takeoff_alt, start z)
                        DO_CHANGE_SPEED (airspeed for planes, ground speed for copters)
                        NAV_WAYPOINT × route (waypoints after the start, or trajectory samples if densified)
                        end action: NAV_LOITER_UNLIM / NAV_RETURN_TO_LAUNCH / NAV_LAND at the goal

The layout key (``"ardupilot"``, ``"px4"``, ``"px4-vtol"``; :data:`companion.mavlink.profiles.LAYOUTS`) says what
differs: the home item (PX4 has none, so its first item is the takeoff at seq 0), the yaw of NAV commands, the
acceptance radius, and for a VTOL NAV_VTOL_TAKEOFF and NAV_VTOL_LAND in place of NAV_TAKEOFF and NAV_LAND (the
vertical climb, then the transition towards the take-off item's position, the start; PX4 does the transitions).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import (
    FENCE,
    FRAME_GLOBAL,
    FRAME_GLOBAL_INT,
    FRAME_MISSION,
    FRAME_REL_ALT,
    FRAME_REL_ALT_INT,
    MissionItem,
    normalise_frame,
)
from companion.mavlink.profiles import LayoutKey, MissionLayout, mission_layout
from companion.mission.geo import Circle, as_circles, enu_to_geodetic, geodetic_to_enu, to_int_e7
from planner.trajectory.smoothing import sample_trajectory
from planner.world.config import VehicleLimits
from planner.world.environment import Cylinders, Prisms
from planner.world.home import Home
from planner.world.scenario import Scenario

logger = logging.getLogger(__name__)

Autopilot = LayoutKey  # "ardupilot", "px4", "px4-vtol": the mission layout's key

TAKEOFF_MIN_PITCH_DEG = 10.0  # plane NAV_TAKEOFF param1 (ArduPilot reads 0 as 4°)
SPEED_TYPE_AIRSPEED = 0.0
SPEED_TYPE_GROUNDSPEED = 1.0
NO_CHANGE = -1.0  # DO_CHANGE_SPEED param3: throttle unchanged
DENSIFY_SAMPLE_M = 2.0  # arc-length resolution used when the builder samples the trajectory itself
MATCH_TOLERANCE_M = 0.5  # an item this close to a planned waypoint is that waypoint (encoding error is ~1 cm)

CMD_WAYPOINT = mavlink.MAV_CMD_NAV_WAYPOINT
CMD_TAKEOFF = mavlink.MAV_CMD_NAV_TAKEOFF
CMD_LOITER_UNLIM = mavlink.MAV_CMD_NAV_LOITER_UNLIM
CMD_RTL = mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH
CMD_LAND = mavlink.MAV_CMD_NAV_LAND
CMD_VTOL_TAKEOFF = mavlink.MAV_CMD_NAV_VTOL_TAKEOFF
CMD_VTOL_LAND = mavlink.MAV_CMD_NAV_VTOL_LAND
TAKEOFF_COMMANDS = frozenset({CMD_TAKEOFF, CMD_VTOL_TAKEOFF})
CMD_CHANGE_SPEED = mavlink.MAV_CMD_DO_CHANGE_SPEED
CMD_FENCE_CIRCLE_EXCLUSION = mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION
CMD_FENCE_POLYGON_INCLUSION = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
CMD_FENCE_POLYGON_EXCLUSION = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
LOCATION_COMMANDS = TAKEOFF_COMMANDS | {CMD_WAYPOINT, CMD_LOITER_UNLIM, CMD_LAND, CMD_VTOL_LAND}


@dataclass(frozen=True)
class MissionSpec:
    """How to turn a route into items: target autopilot, vehicle conventions, ENU origin, densification.

    ``fly_to_start`` adds a NAV_WAYPOINT at the planned start (the route's index 0) right after the takeoff,
    so the vehicle joins the planned route where the planner's checks begin (without it the first leg runs
    from wherever the takeoff ends straight to P_1, a leg nobody planned). The climb-out from home to the
    start is not part of the plan: choose the start so that leg is clear.
    """

    autopilot: Autopilot
    vehicle: VehicleLimits
    home: Home  # the frame's origin: every ENU point is converted from it
    densify: bool = False
    densify_spacing_m: float = 50.0
    fly_to_start: bool = True
    # the vehicle's home, when it is not the origin (a geographic scenario's region): ArduPilot's item 0 and a
    # plan's planned home
    launch: Home | None = None

    @property
    def planned_home(self) -> Home:
        """Where the vehicle takes off: the home item and a .plan's plannedHomePosition."""
        return self.launch if self.launch is not None else self.home

    def __post_init__(self) -> None:
        mission_layout(self.autopilot)  # ValueError for an unknown key
        if not self.densify_spacing_m > 0:
            raise ValueError(f"densify_spacing_m must be positive, got {self.densify_spacing_m!r}")

    @property
    def layout(self) -> MissionLayout:
        return mission_layout(self.autopilot)

    @property
    def yaw_param(self) -> float:
        """param4 of NAV commands (the layout's ``nav_yaw``)."""
        return self.layout.nav_yaw


COPTER_CLIMB_RATE_M_S = 2.5  # ArduCopter WPNAV_SPEED_UP default (250 cm/s)


def time_to_start(scenario: Scenario) -> float:
    """Estimated mission seconds from MISSION_START to the route's start: the takeoff (a plane climbs
    straight ahead at its climb limit and cruise speed, a copter straight up) and the leg to the start.
    Dynamic threats run on mission time, so a flight plan is timed from here (the estimate is within a
    second of the simulator on rescue_dynamic; replanning absorbs the rest)."""
    v = scenario.vehicle
    start = np.asarray(scenario.start, dtype=float)
    alt = max(v.takeoff_alt, float(start[2]))
    horizontal = float(np.hypot(start[0] - scenario.launch[0], start[1] - scenario.launch[1]))
    if v.type == "plane":
        climb = alt / (v.cruise_speed * math.sin(v.max_climb))
        covered = alt / math.tan(v.max_climb)
    else:
        climb, covered = alt / COPTER_CLIMB_RATE_M_S, 0.0
    return climb + max(horizontal - covered, 0.0) / v.cruise_speed


def is_home_item(item: MissionItem) -> bool:
    """True for ArduPilot's item 0 (home: NAV_WAYPOINT at seq 0 in an absolute GLOBAL frame)."""
    return item.seq == 0 and item.command == CMD_WAYPOINT and normalise_frame(item.frame) == FRAME_GLOBAL


def build_mission(waypoints_enu: ArrayLike, spec: MissionSpec, trajectory: Any = None) -> list[MissionItem]:
    """Mission items for a planned route.

    waypoints_enu (N, 3) ENU m, start and goal included (N ≥ 2). ``trajectory`` is the smoothed trajectory
    the route was checked on — (M, 3) ENU points, a ``planner.trajectory.checks.Trajectory`` or PLAN.json's
    ``{"points": ...}`` — used only when ``spec.densify``; without it the builder samples the same Bézier
    smoothing itself. Waypoints (and samples) within the acceptance radius of the previous kept one are dropped,
    the goal never is. Returns items with consecutive seq from 0.
    """
    wps = np.asarray(waypoints_enu, dtype=float)
    if wps.ndim != 2 or wps.shape[1] != 3 or len(wps) < 2:
        raise ValueError(f"waypoints must be (N >= 2, 3) ENU metres, got shape {wps.shape}")
    if not np.isfinite(wps).all():
        raise ValueError("waypoints contain non-finite coordinates")
    vehicle, home = spec.vehicle, spec.home
    route = _route_points(wps, spec, trajectory)
    lat, lon, _ = enu_to_geodetic(np.vstack([wps[:1], route]), home)
    x = [to_int_e7(v) for v in lat]
    y = [to_int_e7(v) for v in lon]
    yaw = spec.yaw_param
    plane = vehicle.type == "plane"

    items: list[MissionItem] = []
    if spec.layout.home_item:
        planned = spec.planned_home
        items.append(MissionItem(0, FRAME_GLOBAL, CMD_WAYPOINT, x=to_int_e7(planned.lat), y=to_int_e7(planned.lon),
                                 z=float(planned.alt)))
    takeoff_alt = max(vehicle.takeoff_alt, float(wps[0, 2]))
    vtol = spec.layout.vtol  # VTOL_TAKEOFF's param1 0: PX4's transition heading, towards the item's position
    items.append(MissionItem(0, FRAME_REL_ALT_INT, CMD_VTOL_TAKEOFF if vtol else CMD_TAKEOFF,
                             param1=TAKEOFF_MIN_PITCH_DEG if plane and not vtol else 0.0, param4=yaw, x=x[0], y=y[0],
                             z=takeoff_alt))
    items.append(MissionItem(0, FRAME_MISSION, CMD_CHANGE_SPEED,
                             param1=SPEED_TYPE_AIRSPEED if plane else SPEED_TYPE_GROUNDSPEED,
                             param2=float(vehicle.cruise_speed), param3=NO_CHANGE))
    items.extend(waypoint_items(route, spec))
    gx, gy, gz = x[-1], y[-1], float(route[-1, 2])
    if vehicle.end_action == "loiter":
        items.append(MissionItem(0, FRAME_REL_ALT_INT, CMD_LOITER_UNLIM, param4=yaw, x=gx, y=gy, z=gz))
    elif vehicle.end_action == "rtl":
        items.append(MissionItem(0, FRAME_MISSION, CMD_RTL))  # no position (PX4 refuses any other frame)
    elif vehicle.end_action == "land":
        items.append(MissionItem(0, FRAME_REL_ALT_INT, CMD_VTOL_LAND if vtol else CMD_LAND, param4=yaw, x=gx, y=gy,
                                 z=0.0))
    else:  # VehicleLimits is validated at the scenario boundary; this guards hand-made ones
        raise ValueError(f"unknown end action {vehicle.end_action!r}")
    return [item.with_seq(seq) for seq, item in enumerate(items)]


def waypoint_items(points_enu: np.ndarray, spec: MissionSpec) -> list[MissionItem]:
    """NAV_WAYPOINT items (seq 0, renumber when placing them) for ENU points (K, 3), z = metres above home.

    The one place a route point becomes an item: the mission builder and the live replanner's splice use it.
    """
    pts = np.asarray(points_enu, dtype=float).reshape(-1, 3)
    lat, lon, _ = enu_to_geodetic(pts, spec.home)
    accept = spec.layout.acceptance_param(spec.vehicle.acceptance_radius, spec.vehicle.type)
    return [MissionItem(0, FRAME_REL_ALT_INT, CMD_WAYPOINT, param1=0.0, param2=accept, param4=spec.yaw_param,
                        x=to_int_e7(a), y=to_int_e7(o), z=float(p[2])) for a, o, p in zip(lat, lon, pts)]


def _route_points(wps: np.ndarray, spec: MissionSpec, trajectory: Any) -> np.ndarray:
    """ENU points (K, 3) to fly after the takeoff, goal last."""
    radius = spec.vehicle.acceptance_radius
    kept = [0]  # start: the reference for the first drop test, flown only with fly_to_start
    for i in range(1, len(wps)):
        if i == len(wps) - 1 or np.linalg.norm(wps[i] - wps[kept[-1]]) >= radius:
            kept.append(i)
        else:
            logger.debug("dropping waypoint %d: within %.1f m of waypoint %d", i, radius, kept[-1])
    if not spec.densify:
        points = wps[kept]
    else:
        traj = _trajectory_points(trajectory, wps)
        points = _densify(wps[kept], traj, spec.densify_spacing_m, radius)
    return points if spec.fly_to_start else points[1:]


def _trajectory_points(trajectory: Any, wps: np.ndarray) -> np.ndarray:
    if trajectory is None:
        return sample_trajectory(wps, DENSIFY_SAMPLE_M)["points"]
    if isinstance(trajectory, Mapping):
        trajectory = trajectory["points"]
    pts = np.asarray(getattr(trajectory, "points", trajectory), dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 2:
        raise ValueError(f"trajectory must be (M >= 2, 3) ENU metres, got shape {pts.shape}")
    return pts


def _densify(anchors: np.ndarray, traj: np.ndarray, spacing: float, min_gap: float) -> np.ndarray:
    """Anchors (K, 3), start first, with samples of ``traj`` between consecutive anchors.

    Each anchor is matched to the nearest trajectory sample at or after the previous match (the smoothed
    trajectory passes through the waypoints); each piece between matches gets evenly spaced interior
    points at most ``spacing`` apart along the arc, but never closer than ``min_gap`` (acceptance radius).
    The anchors themselves are kept exactly, so items at planned waypoints stay recognisable.
    """
    out = [anchors[0]]
    j = int(np.argmin(np.linalg.norm(traj - anchors[0], axis=1)))
    for anchor in anchors[1:]:
        rest = traj[j:]
        k = j + int(np.argmin(np.linalg.norm(rest - anchor, axis=1)))
        piece = np.vstack([out[-1], traj[j + 1:k], anchor])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(piece, axis=0), axis=1))])
        n = max(1, math.ceil(arc[-1] / spacing))
        if min_gap > 0 and arc[-1] / n < min_gap:
            n = max(1, math.floor(arc[-1] / min_gap))
        targets = arc[-1] * np.arange(1, n) / n
        out.extend(np.stack([np.interp(targets, arc, piece[:, c]) for c in range(3)], axis=-1))
        out.append(anchor)
        j = k
    return np.array(out)


def build_fence(zones: Cylinders | Sequence[Circle], home: Home, max_route_alt: float | None = None, *,
                prisms: Prisms | None = None, min_route_alt: float | None = None) -> list[MissionItem]:
    """MAV_MISSION_TYPE_FENCE items for the no-fly zones: keep-in polygons first (one
    MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION per vertex), then no-fly polygons (…_POLYGON_VERTEX_EXCLUSION), then
    one MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION per cylinder. A polygon's items carry its vertex count in param1, in the
    order of its vertices (counter-clockwise), frame GLOBAL_INT, altitude 0 (docs/autopilots.md §5.1).

    Fences are 2-D on ArduPilot and PX4: a fenced zone is no-fly at every height. So a zone the route may legally
    pass over or under is left out, and logged: a cylinder or prism whose top is below ``max_route_alt``, a prism
    whose floor is above ``min_route_alt`` (m above home; None: not checked; the flight's lowest height, so 0 when
    the climb-out from home counts, leaves out every prism with a floor). The vehicle's fence is a backstop to
    the planner's own clearance, never stricter than the plan. A keep-in polygon has no floor or ceiling and is always
    fenced. Radii are rounded up to whole metres (a slightly larger exclusion, and what every autopilot stores exactly).
    """
    items = _polygon_items(prisms, home, max_route_alt, min_route_alt) if prisms is not None else []
    for c in fenced_circles(zones, home, max_route_alt, log=True):
        items.append(MissionItem(0, FRAME_GLOBAL_INT, CMD_FENCE_CIRCLE_EXCLUSION,
                                 param1=float(math.ceil(c.radius_m)), param2=0.0, x=to_int_e7(c.lat),
                                 y=to_int_e7(c.lon), z=0.0, mission_type=FENCE))
    return [item.with_seq(seq) for seq, item in enumerate(items)]


def fenced_circles(zones: Cylinders | Sequence[Circle], home: Home, max_route_alt: float | None,
                   log: bool = False) -> list[Circle]:
    """The circles a fence holds for a route whose highest point is ``max_route_alt`` m above home (None: all): a
    zone whose top is below it may be flown over, and a fence holds at every height, so it is left out (logged
    with ``log``). The one rule for :func:`build_fence` and the exported fences, as :func:`prisms_left_out` is for
    polygons."""
    kept = []
    for c in as_circles(zones, home):
        if max_route_alt is not None and c.top_m < max_route_alt:
            if log:
                logger.info("fence: leaving out the zone at (%.6f, %.6f): top %.0f m is below the route's %.0f m",
                            c.lat, c.lon, c.top_m, max_route_alt)
            continue
        kept.append(c)
    return kept


def prisms_left_out(prisms: Prisms, low_m: float | None, high_m: float | None) -> dict[int, str]:
    """The prisms a fence leaves out for a route flown between ``low_m`` and ``high_m`` m above home (None: that
    side not checked), each with why. A fence holds at every height, so a no-fly prism is fenced only when the route
    cannot pass over or under it: its ceiling at least ``high_m`` and its floor at most ``low_m``; a keep-in
    polygon always is. The one rule for :func:`build_fence` and the exported fences (companion.mission.exports,
    the flight's mission files)."""
    out = {}
    for k in range(len(prisms)):
        if prisms.keep_in[k]:
            continue
        floor, ceiling = float(prisms.floor[k]), float(prisms.ceiling[k])
        if high_m is not None and ceiling < high_m:
            out[k] = f"its ceiling {ceiling:.0f} m is below the route's highest {high_m:.0f} m"
        elif low_m is not None and floor > low_m:
            out[k] = f"its floor {floor:.0f} m is above the route's lowest {low_m:.0f} m"
    return out


def _polygon_items(prisms: Prisms, home: Home, max_route_alt: float | None,
                   min_route_alt: float | None) -> list[MissionItem]:
    """Vertex items of the prisms to fence (:func:`build_fence`), keep-in polygons first."""
    lat, lon, _ = enu_to_geodetic(np.column_stack([prisms.vertices, np.zeros(len(prisms.vertices))]), home)
    left_out = prisms_left_out(prisms, min_route_alt, max_route_alt)
    keep_in: list[MissionItem] = []
    no_fly: list[MissionItem] = []
    for k in range(len(prisms)):
        if k in left_out:
            logger.info("fence: leaving out polygon %d: %s", k, left_out[k])
            continue
        inclusion = bool(prisms.keep_in[k])
        first, end = int(prisms.start[k]), int(prisms.start[k + 1])
        command = CMD_FENCE_POLYGON_INCLUSION if inclusion else CMD_FENCE_POLYGON_EXCLUSION
        (keep_in if inclusion else no_fly).extend(
            MissionItem(0, FRAME_GLOBAL_INT, command, param1=float(end - first), x=to_int_e7(lat[i]),
                        y=to_int_e7(lon[i]), z=0.0, mission_type=FENCE) for i in range(first, end))
    return keep_in + no_fly


def mission_waypoint_index(items: Sequence[MissionItem], waypoints_enu: np.ndarray, home: Home,
                           tol_m: float = MATCH_TOLERANCE_M) -> dict[int, int]:
    """Item seq → index of the last planned waypoint at or behind that item, for every located route item.

    An item within ``tol_m`` of a planned waypoint (searched forward in route order) is that waypoint;
    anything else (takeoff, densified samples, the end action at the goal) maps to the last waypoint matched
    before it, 0 (the start) at first. ArduPilot's home item, DO commands and RTL have no entry. Works on a
    downloaded mission too (frames normalised). So MISSION_ITEM_REACHED(seq) means the route is done up to
    ``waypoints[index]``: the remaining route is ``waypoints[index + 1:]``.
    """
    wps = np.asarray(waypoints_enu, dtype=float)
    out: dict[int, int] = {}
    last, next_k = 0, 0
    for item in items:
        if item.command not in LOCATION_COMMANDS or normalise_frame(item.frame) != FRAME_REL_ALT or (
                is_home_item(item)):
            continue
        p = geodetic_to_enu(item.lat, item.lon, home.alt + item.z, home)
        if item.command not in TAKEOFF_COMMANDS:  # the takeoff climbs at the start; it never reaches a waypoint
            # altitude is relative to home, not a geodetic height: compare z directly
            d = np.hypot(np.linalg.norm(wps[next_k:, :2] - p[:2], axis=1), wps[next_k:, 2] - item.z)
            hits = np.flatnonzero(d <= tol_m)
            if hits.size:
                last = next_k + int(hits[0])
                next_k = last + 1
        out[item.seq] = last
    return out


def _vehicle_of(source: VehicleLimits | Scenario) -> VehicleLimits:
    return source.vehicle if isinstance(source, Scenario) else source


def mission_from_plan_json(doc: Mapping[str, Any], vehicle: VehicleLimits | Scenario,
                           autopilot: Autopilot = "ardupilot", **options: Any) -> list[MissionItem]:
    """Mission items for a PLAN.json document (``fuseplan plan`` output); home from ``doc["home"]``, the
    densified route from ``doc["trajectory"]["points"]``; ``options`` are :class:`MissionSpec` fields."""
    spec = spec_from_plan_json(doc, vehicle, autopilot, **options)
    trajectory = doc.get("trajectory", {}).get("points") if spec.densify else None
    return build_mission(np.asarray(doc["waypoints"], dtype=float), spec, trajectory)


def spec_from_plan_json(doc: Mapping[str, Any], vehicle: VehicleLimits | Scenario,
                        autopilot: Autopilot = "ardupilot", **options: Any) -> MissionSpec:
    """The :class:`MissionSpec` for a PLAN.json document (its home, and its launch when that is not the origin;
    the given vehicle)."""
    h = doc["home"]
    home = Home(float(h["lat"]), float(h["lon"]), float(h["alt"]))
    launch = doc.get("launch") or [0.0, 0.0]
    if any(float(v) != 0.0 for v in launch):
        lat, lon, _ = enu_to_geodetic(np.array([float(launch[0]), float(launch[1]), 0.0]), home)
        options.setdefault("launch", Home(float(lat), float(lon), home.alt))
    return MissionSpec(autopilot, _vehicle_of(vehicle), home, **options)


__all__ = [
    "Autopilot", "MissionSpec", "build_fence", "build_mission", "is_home_item", "mission_from_plan_json",
    "mission_waypoint_index", "prisms_left_out", "spec_from_plan_json", "time_to_start", "waypoint_items",
]
