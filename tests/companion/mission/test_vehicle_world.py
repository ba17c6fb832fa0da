"""companion.mission.vehicle_world: the vehicle's fence, rally and mission lists read as the operator's world, and
the errors that name the item when they cannot be (the downloads themselves, over real sockets:
tests/conformance/test_ground_station_world.py and tests/px4/test_px4_vehicle_world.py)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import CompanionError, VehicleContentError
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem
from companion.mission.builder import build_fence
from companion.mission.geo import enu_to_geodetic, to_int_e7
from companion.mission.vehicle_world import fence_zones, mission_places, operator_world, rally_points
from planner.world.environment import Cylinders, Prisms
from planner.world.geo_inputs import Altitude, GeoPoint
from planner.world.home import Home

HOME = Home(-35.363261, 149.165230, 584.0)
C = mavlink
INC, EXC = C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION
GLOBAL, REL, TERRAIN = C.MAV_FRAME_GLOBAL, C.MAV_FRAME_GLOBAL_RELATIVE_ALT, C.MAV_FRAME_GLOBAL_TERRAIN_ALT


def _item(command: int, x: int, y: int, param1: float = 0.0, frame: int = GLOBAL, z: float = 0.0,
          mission_type: int = FENCE) -> MissionItem:
    return MissionItem(0, frame, command, param1=param1, x=x, y=y, z=z, mission_type=mission_type)


def _numbered(items: list[MissionItem]) -> list[MissionItem]:
    return [it.with_seq(i) for i, it in enumerate(items)]


def _polygon(command: int, vertices: list[tuple[int, int]], count: float | None = None) -> list[MissionItem]:
    return [_item(command, x, y, float(len(vertices)) if count is None else count) for x, y in vertices]


TRIANGLE = [(-353600000, 1491600000), (-353600000, 1491610000), (-353590000, 1491605000)]
SQUARE = [(-353700000, 1491500000), (-353700000, 1491800000), (-353500000, 1491800000), (-353500000, 1491500000)]


def test_the_builders_fence_reads_back_as_its_zones() -> None:
    """build_fence's items (ArduPilot's readback frame aside) are the zones they were made from: each polygon's
    vertices to the encoding's 1e-7°, its inclusion flag, the circle's centre and radius."""
    polys = [np.array([[-900.0, -900.0], [900.0, -900.0], [900.0, 900.0], [-900.0, 900.0]]),
             np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 300.0], [150.0, 100.0], [0.0, 300.0]])]
    prisms = Prisms.from_polygons(polys, [-math.inf, -math.inf], [math.inf, math.inf], keep_in=[True, False])
    fence = build_fence(Cylinders([400.0], [-500.0], [79.2], [math.inf], [0.0]), HOME, prisms=prisms)
    zones, return_point = fence_zones(fence)
    assert return_point is None and [z.inclusion for z in zones] == [True, False, False]
    for zone, k in zip(zones, (0, 1)):
        ring = prisms.polygon(k)
        lat, lon, _ = enu_to_geodetic(np.column_stack([ring, np.zeros(len(ring))]), HOME)
        assert zone.polygon == tuple((to_int_e7(a) / 1e7, to_int_e7(o) / 1e7) for a, o in zip(lat, lon))
        assert zone.centre is None and zone.floor is None and zone.ceiling is None
    lat, lon, _ = enu_to_geodetic(np.array([400.0, -500.0, 0.0]), HOME)
    circle = zones[2]
    assert circle.polygon is None and circle.radius_m == 80.0
    assert circle.centre == (to_int_e7(float(lat)) / 1e7, to_int_e7(float(lon)) / 1e7)
    assert [z.name for z in zones] == ["vehicle fence items 0-3", "vehicle fence items 4-8", "vehicle fence item 9"]


def test_circles_inclusion_and_the_return_point() -> None:
    fence = _numbered([_item(C.MAV_CMD_NAV_FENCE_RETURN_POINT, *TRIANGLE[0]),
                       _item(C.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, *SQUARE[0], param1=2000.0),
                       *_polygon(EXC, TRIANGLE),
                       _item(C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, *SQUARE[1], param1=50.5)])
    zones, return_point = fence_zones(fence)
    assert return_point == GeoPoint(TRIANGLE[0][0] / 1e7, TRIANGLE[0][1] / 1e7)
    assert [(z.inclusion, z.radius_m) for z in zones] == [(True, 2000.0), (False, None), (False, 50.5)]
    assert zones[1].polygon == tuple((x / 1e7, y / 1e7) for x, y in TRIANGLE)


BAD_FENCES = {
    "count disagrees": (_polygon(EXC, SQUARE)[:2] + _polygon(EXC, TRIANGLE), 2,
                        "vertex count 3 inside the polygon of 4 vertices that begins at item 0"),
    "another command inside": (_polygon(INC, SQUARE)[:3] + _polygon(EXC, SQUARE), 3,
                               "MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION inside the polygon of 4 vertices"),
    "cut short": (_polygon(EXC, TRIANGLE) + _polygon(INC, SQUARE)[:3], 3,
                  "a polygon of 4 vertices, but the fence ends after 3 of them"),
    "two vertices": (_polygon(EXC, TRIANGLE[:2]), 0, "a polygon of 2 vertices (at least 3 needed)"),
    "fractional count": (_polygon(EXC, TRIANGLE, count=3.5), 0, "vertex count 3.5 is not a whole number"),
    "nan count": (_polygon(EXC, TRIANGLE, count=math.nan), 0, "vertex count nan is not a whole number"),
    "zero radius": ([_item(C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, *TRIANGLE[0], param1=0.0)], 0,
                    "circle radius 0.0 is not a positive number"),
    "second return point": ([_item(C.MAV_CMD_NAV_FENCE_RETURN_POINT, *TRIANGLE[0])] * 2, 1,
                            "a second return point (the first is item 0)"),
    "unsupported": ([_item(C.MAV_CMD_NAV_WAYPOINT, *TRIANGLE[0])], 0,
                    "unsupported fence command MAV_CMD_NAV_WAYPOINT"),
    "latitude": ([_item(C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 950_000_000, 0, param1=5.0)], 0,
                 "latitude 95° is out of range"),
    "longitude in a polygon": (_polygon(EXC, TRIANGLE[:2] + [(0, 1_900_000_000)]), 2,
                               "longitude 190° is out of range"),
}


@pytest.mark.parametrize("case", BAD_FENCES)
def test_a_fence_that_cannot_be_read_names_the_item_and_why(case: str) -> None:
    items, seq, reason = BAD_FENCES[case]
    with pytest.raises(VehicleContentError) as caught:
        fence_zones(_numbered(items))
    err = caught.value
    assert isinstance(err, CompanionError)  # the CLI's one-line error, never a traceback
    assert (err.list_name, err.seq) == ("fence", seq)
    assert reason in err.reason and str(err) == f"the vehicle's fence item {seq}: {err.reason}"


def test_rally_points_keep_their_altitude_reference() -> None:
    rally = _numbered([_item(C.MAV_CMD_NAV_RALLY_POINT, *TRIANGLE[i], frame=f, z=z, mission_type=RALLY)
                       for i, (f, z) in enumerate(((REL, 60.0), (C.MAV_FRAME_GLOBAL_INT, 700.0), (11, 40.0)))])
    assert rally_points(rally) == tuple(
        GeoPoint(x / 1e7, y / 1e7, Altitude(z, ref))
        for (x, y), z, ref in zip(TRIANGLE, (60.0, 700.0, 40.0), ("home", "amsl", "ground")))
    with pytest.raises(VehicleContentError, match="rally item 0: unsupported rally command MAV_CMD_NAV_WAYPOINT"):
        rally_points([_item(C.MAV_CMD_NAV_WAYPOINT, *TRIANGLE[0], mission_type=RALLY)])
    with pytest.raises(VehicleContentError, match="rally item 0: frame 1 has no geographic altitude"):
        rally_points([_item(C.MAV_CMD_NAV_RALLY_POINT, *TRIANGLE[0], frame=C.MAV_FRAME_LOCAL_NED,
                            mission_type=RALLY)])


def _mission(*items: MissionItem) -> list[MissionItem]:
    return _numbered([MissionItem(0, it.frame, it.command, param1=it.param1, x=it.x, y=it.y, z=it.z) for it in items])


def test_the_goal_is_the_last_place_and_ardupilots_item_0_is_home() -> None:
    home = _item(C.MAV_CMD_NAV_WAYPOINT, *SQUARE[0], z=584.0)
    takeoff = _item(C.MAV_CMD_NAV_TAKEOFF, 0, 0, frame=REL, z=40.0)
    via = _item(C.MAV_CMD_NAV_WAYPOINT, *SQUARE[1], frame=REL, z=80.0)
    speed = _item(C.MAV_CMD_DO_CHANGE_SPEED, 0, 0, frame=C.MAV_FRAME_MISSION)
    goal = _item(C.MAV_CMD_NAV_LOITER_UNLIM, *SQUARE[2], frame=TERRAIN, z=50.0)
    rtl = _item(C.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0)
    got_home, vias, got_goal = mission_places(_mission(home, takeoff, via, speed, goal, rtl), home_at_zero=True)
    assert got_home == GeoPoint(SQUARE[0][0] / 1e7, SQUARE[0][1] / 1e7, Altitude(584.0, "amsl"))
    assert vias == (GeoPoint(SQUARE[1][0] / 1e7, SQUARE[1][1] / 1e7, Altitude(80.0, "home")),)
    assert got_goal == GeoPoint(SQUARE[2][0] / 1e7, SQUARE[2][1] / 1e7, Altitude(50.0, "ground"))
    # PX4: no home item, so item 0 is a place; a takeoff with a position is still no via, a land in place no goal
    px4_takeoff = _item(C.MAV_CMD_NAV_TAKEOFF, *SQUARE[3], frame=REL, z=40.0)
    land_here = _item(C.MAV_CMD_NAV_LAND, 0, 0, frame=REL)
    assert mission_places(_mission(via, px4_takeoff, goal, land_here), home_at_zero=False) == (
        None, (vias[0],), got_goal)
    # ArduPilot before home is set: item 0 all zeros; and an empty mission
    assert mission_places(_mission(_item(C.MAV_CMD_NAV_WAYPOINT, 0, 0)), home_at_zero=True) == (None, (), None)
    assert mission_places([], home_at_zero=True) == (None, (), None)


def test_operator_world_puts_the_three_lists_together() -> None:
    fence = _numbered(_polygon(INC, SQUARE) + [_item(C.MAV_CMD_NAV_FENCE_RETURN_POINT, *TRIANGLE[1])])
    rally = _numbered([_item(C.MAV_CMD_NAV_RALLY_POINT, *TRIANGLE[0], frame=REL, z=60.0, mission_type=RALLY)])
    mission = _mission(_item(C.MAV_CMD_NAV_WAYPOINT, *SQUARE[0], z=584.0),
                       _item(C.MAV_CMD_NAV_WAYPOINT, *TRIANGLE[2], frame=REL, z=90.0, mission_type=MISSION))
    world = operator_world(fence, rally, mission, home_at_zero=True, source=Path("tcp:127.0.0.1:5762"))
    assert world.source == Path("tcp:127.0.0.1:5762")
    assert world.home == world.start == GeoPoint(SQUARE[0][0] / 1e7, SQUARE[0][1] / 1e7, Altitude(584.0, "amsl"))
    assert world.goal == GeoPoint(TRIANGLE[2][0] / 1e7, TRIANGLE[2][1] / 1e7, Altitude(90.0, "home"))
    assert world.vias == () and len(world.zones) == 1 and world.zones[0].inclusion
    assert world.rally == (GeoPoint(TRIANGLE[0][0] / 1e7, TRIANGLE[0][1] / 1e7, Altitude(60.0, "home")),)
    assert world.extras == {"fence_return_point": GeoPoint(TRIANGLE[1][0] / 1e7, TRIANGLE[1][1] / 1e7)}
