"""The operator's world a ground-station script puts on the vehicle in the vehicle-world tests (conformance: the
simulator and ArduPlane SITL; PX4 SITL), and the check that the companion reads exactly that back
(companion.mission.vehicle_world): an inclusion polygon, three exclusion polygons (one concave), an exclusion circle,
three rally points and a one-item mission (the goal)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import pymap3d
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem
from planner.world.geo_inputs import OperatorMission
from planner.world.home import Home

GLOBAL_INT, REL_INT = mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
# (inclusion, vertices as (north, east) metres from home)
POLYGONS = (
    (True, ((-1500.0, -1500.0), (-1500.0, 1500.0), (1500.0, 1500.0), (1500.0, -1500.0))),
    (False, ((500.0, -500.0), (500.0, -400.0), (400.0, -450.0))),
    (False, ((-600.0, 200.0), (-600.0, 500.0), (-300.0, 500.0), (-300.0, 400.0), (-500.0, 400.0), (-500.0, 200.0))),
    (False, ((800.0, 800.0), (800.0, 1000.0), (1000.0, 1000.0), (1000.0, 800.0))),
)
CIRCLE = (300.0, -300.0, 60.0)  # north, east, radius (m): an exclusion circle
RALLY_POINTS = ((100.0, -100.0, 60.0, "home"), (-100.0, 100.0, 700.0, "amsl"), (-100.0, -100.0, 80.0, "home"))
GOAL = (900.0, 100.0, 80.0)  # north, east, metres above home


def e7(home: Home, *, north: float, east: float) -> tuple[int, int]:
    """Degrees × 1e7 of a point ``north``/``east`` metres from ``home`` (what the ground station sends); keywords
    only, so that no caller can swap them (operator_course.py keeps its shapes east, north)."""
    lat, lon, _ = pymap3d.enu2geodetic(east, north, 0.0, home.lat, home.lon, home.alt)
    return round(float(lat) * 1e7), round(float(lon) * 1e7)


def fence_items(home: Home, polygons: Sequence[tuple[bool, Sequence[tuple[float, float]]]],
                circle: tuple[float, float, float]) -> list[MissionItem]:
    """Fence items as a ground station makes them, unnumbered: each polygon (inclusion, vertices as (north, east)
    metres from home) vertex by vertex (param1 = vertex count), then the exclusion ``circle`` (north, east, radius
    m), frames as QGroundControl sends them."""
    items = []
    for inclusion, vertices in polygons:
        command = (mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION if inclusion
                   else mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION)
        items += [MissionItem(0, GLOBAL_INT, command, param1=float(len(vertices)), x=x, y=y, mission_type=FENCE)
                  for x, y in (e7(home, north=n, east=e) for n, e in vertices)]
    x, y = e7(home, north=circle[0], east=circle[1])
    items.append(MissionItem(0, GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, param1=circle[2], x=x, y=y,
                             mission_type=FENCE))
    return items


def goal_mission(home: Home, *, north: float, east: float, alt: float, home_item: bool) -> list[MissionItem]:
    """A one-item mission, unnumbered: the goal ``north``/``east`` metres from home, ``alt`` above it; with
    ``home_item`` after a home placeholder (ArduPilot's item 0)."""
    x, y = e7(home, north=north, east=east)
    mission = [MissionItem(0, REL_INT, mavlink.MAV_CMD_NAV_WAYPOINT, x=x, y=y, z=alt, mission_type=MISSION)]
    if home_item:
        hx, hy = e7(home, north=0.0, east=0.0)
        mission.insert(0, MissionItem(0, mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, x=hx, y=hy,
                                      z=home.alt))
    return mission


@dataclass(frozen=True)
class GroundStationWorld:
    """The three lists a ground station uploads."""

    fence: list[MissionItem]
    rally: list[MissionItem]
    mission: list[MissionItem]


def ground_station_world(home: Home, home_item: bool) -> GroundStationWorld:
    """The lists, as a ground station makes them: polygons vertex by vertex (param1 = vertex count), frames as
    QGroundControl sends them; ``home_item``: the mission starts with a home placeholder (ArduPilot's item 0)."""
    rally = []
    for n, e, alt, ref in RALLY_POINTS:
        x, y = e7(home, north=n, east=e)
        rally.append(MissionItem(0, REL_INT if ref == "home" else GLOBAL_INT, mavlink.MAV_CMD_NAV_RALLY_POINT, x=x, y=y,
                                 z=alt, mission_type=RALLY))
    mission = goal_mission(home, north=GOAL[0], east=GOAL[1], alt=GOAL[2], home_item=home_item)
    return GroundStationWorld(fence_items(home, POLYGONS, CIRCLE), rally, mission)


def world_difference(world: OperatorMission, home: Home) -> str | None:
    """The first way ``world`` (read back by the companion) differs from what :func:`ground_station_world` put on
    the vehicle, in words, or None: zones in order with their vertices to 1e-7° (compared as degrees × 1e7), inclusion
    flags and radius; the rally points with altitude and reference; the goal, and no vias."""
    expected = [(inclusion, tuple(e7(home, north=n, east=e) for n, e in vertices), None, None)
                for inclusion, vertices in POLYGONS]
    expected.append((False, None, e7(home, north=CIRCLE[0], east=CIRCLE[1]), CIRCLE[2]))
    if len(world.zones) != len(expected):
        return f"{len(world.zones)} zones read back, {len(expected)} uploaded"
    for k, (zone, want) in enumerate(zip(world.zones, expected)):
        polygon = None if zone.polygon is None else tuple(_e7(p) for p in zone.polygon)
        centre = None if zone.centre is None else _e7(zone.centre)
        got = (zone.inclusion, polygon, centre, zone.radius_m)
        if got != want:
            return f"zone {k} ({zone.name}): read back {got}, uploaded {want}"
    rally = [(_e7((p.lat, p.lon)), p.alt.value if p.alt else None, p.alt.ref if p.alt else None) for p in world.rally]
    want_rally = [(e7(home, north=n, east=e), alt, ref) for n, e, alt, ref in RALLY_POINTS]
    if rally != want_rally:
        return f"rally points read back {rally}, uploaded {want_rally}"
    goal = world.goal
    got_goal = None if goal is None else (_e7((goal.lat, goal.lon)), goal.alt)
    want_goal = (e7(home, north=GOAL[0], east=GOAL[1]), GOAL[2])
    if got_goal is None or got_goal[0] != want_goal[0] or got_goal[1] is None or (
            (got_goal[1].value, got_goal[1].ref) != (GOAL[2], "home")):
        return f"goal read back {got_goal}, uploaded {want_goal} above home"
    if world.vias:
        return f"vias read back {world.vias}, none uploaded"
    return None


def _e7(latlon: tuple[float, float]) -> tuple[int, int]:
    return round(latlon[0] * 1e7), round(latlon[1] * 1e7)
