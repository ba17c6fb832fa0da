"""companion.mission.geo and companion.mission.builder: geodesy round trips, item encoding, mission layout per
autopilot."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import FENCE, MissionItem
from companion.mission.builder import (
    MissionSpec,
    build_fence,
    build_mission,
    is_home_item,
    mission_from_plan_json,
    mission_waypoint_index,
)
from companion.mission.geo import circle_ring, circles_from_cylinders, enu_to_geodetic, geodetic_to_enu, to_int_e7
from planner.trajectory.smoothing import sample_trajectory
from planner.world.config import VehicleLimits
from planner.world.environment import Cylinders, Prisms
from planner.world.home import Home

HOME = Home(-35.363261, 149.165230, 584.0)  # ArduPilot SITL CMAC
WPS = np.array([[200.0, 200.0, 50.0], [400.0, 300.0, 60.0], [600.0, 700.0, 80.0], [800.0, 800.0, 50.0]])

PLANE = VehicleLimits(type="plane", cruise_speed=18.0, takeoff_alt=50.0, acceptance_radius=20.0)
COPTER = VehicleLimits(type="copter", cruise_speed=8.0, takeoff_alt=30.0, acceptance_radius=3.0)

C = mavlink


def spec(autopilot: str = "ardupilot", vehicle: VehicleLimits = PLANE, **kw: object) -> MissionSpec:
    kw.setdefault("fly_to_start", False)  # most cases test the route items alone
    return MissionSpec(autopilot, vehicle, HOME, **kw)  # type: ignore[arg-type]  # a parametrised name (str) where the Literal is wanted


def commands(items: list[MissionItem]) -> list[int]:
    return [it.command for it in items]


# --- geo ---------------------------------------------------------------------------------------------------------

@settings(max_examples=200, deadline=None)
@given(st.floats(0, 5000), st.floats(0, 2 * math.pi), st.floats(-100, 3000),
       st.floats(-89, 89), st.floats(-180, 180), st.floats(-400, 5000))
def test_enu_geodetic_round_trip_within_a_millimetre(r, bearing, up, lat0, lon0, alt0):
    home = Home(lat0, lon0, alt0)
    p = np.array([r * math.cos(bearing), r * math.sin(bearing), up])
    lat, lon, alt = enu_to_geodetic(p, home)
    back = geodetic_to_enu(lat, lon, alt, home)
    assert np.linalg.norm(back - p) < 1e-3


def test_enu_geodetic_batches_keep_their_shape():
    lat, lon, alt = enu_to_geodetic(WPS, HOME)
    assert lat.shape == lon.shape == alt.shape == (4,)
    assert np.allclose(geodetic_to_enu(lat, lon, alt, HOME), WPS, atol=1e-6)
    # ENU origin is home; north is +lat, east is +lon
    lat0, lon0, alt0 = enu_to_geodetic(np.zeros(3), HOME)
    assert (float(lat0), float(lon0), float(alt0)) == pytest.approx((HOME.lat, HOME.lon, HOME.alt), abs=1e-9)
    assert lat[0] > HOME.lat and lon[0] > HOME.lon


@pytest.mark.parametrize(("deg", "expected"), [
    (-35.363261, -353632610), (149.16523, 1491652300), (0.0, 0),
    (1.23456785, 12345679), (-1.23456785, -12345679),  # half away from zero, both signs
    (1.23456784, 12345678), (-1.23456784, -12345678), (180.0, 1800000000), (-90.0, -900000000),
])
def test_to_int_e7_rounds_half_away_from_zero(deg, expected):
    assert to_int_e7(deg) == expected


def test_circle_ring_is_closed_counter_clockwise_and_round():
    circle = circles_from_cylinders(Cylinders([300.0], [400.0], [80.0], [math.inf], [0.0]), HOME)[0]
    ring = circle_ring(circle)
    assert len(ring) == 65 and ring[0] == ring[-1]
    lon, lat = np.array(ring).T
    enu = geodetic_to_enu(lat, lon, np.full(len(lat), HOME.alt), HOME)
    assert np.allclose(np.hypot(enu[:, 0] - 300.0, enu[:, 1] - 400.0), 80.0, atol=0.01)
    x, y = enu[:, 0], enu[:, 1]
    assert 0.5 * np.sum(x[:-1] * y[1:] - x[1:] * y[:-1]) > 0  # shoelace: positive area = CCW


# --- item encoding -----------------------------------------------------------------------------------------------

def test_waypoint_items_encode_lat_lon_e7_and_relative_altitude():
    items = build_mission(WPS, spec())
    waypoints = [it for it in items if it.command == C.MAV_CMD_NAV_WAYPOINT and not is_home_item(it)]
    assert len(waypoints) == len(WPS) - 1  # every planned waypoint after the start
    lat, lon, _ = enu_to_geodetic(WPS[1:], HOME)
    for it, a, o, p in zip(waypoints, lat, lon, WPS[1:]):
        assert it.frame == C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        assert (it.x, it.y) == (to_int_e7(a), to_int_e7(o))
        assert it.z == p[2]  # relative altitude is the ENU z, not a geodetic height
        assert it.param1 == 0.0 and it.param2 == 20.0
    assert [it.seq for it in items] == list(range(len(items)))
    assert all(it.mission_type == 0 and it.autocontinue == 1 for it in items)


def test_known_point_encodes_exactly():
    # 0 east, 0 north: the first route point at home encodes as home's own integers
    items = build_mission(np.array([[0.0, 0.0, 40.0], [0.0, 0.0, 60.0]]), spec("px4"))
    wp = next(it for it in items if it.command == C.MAV_CMD_NAV_WAYPOINT)
    assert (wp.x, wp.y, wp.z) == (-353632610, 1491652300, 60.0)


def test_ardupilot_item_0_is_home_and_px4_starts_with_takeoff():
    ap = build_mission(WPS, spec("ardupilot"))
    px4 = build_mission(WPS, spec("px4"))
    home = ap[0]
    assert is_home_item(home) and home.frame == C.MAV_FRAME_GLOBAL
    assert (home.x, home.y) == (-353632610, 1491652300)
    assert commands(ap[1:]) == commands(px4)
    assert px4[0].seq == 0 and px4[0].command == C.MAV_CMD_NAV_TAKEOFF
    assert not any(is_home_item(it) for it in px4)
    assert commands(px4) == [C.MAV_CMD_NAV_TAKEOFF, C.MAV_CMD_DO_CHANGE_SPEED] + [C.MAV_CMD_NAV_WAYPOINT] * 3 + [
        C.MAV_CMD_NAV_LOITER_UNLIM]


def test_nan_only_in_param4_of_px4_nav_commands():
    for autopilot in ("ardupilot", "px4"):
        for vehicle in (PLANE, COPTER):
            for it in build_mission(WPS, spec(autopilot, vehicle)):
                assert all(math.isfinite(p) for p in (it.param1, it.param2, it.param3, it.z))
                if autopilot == "ardupilot" or it.command == C.MAV_CMD_DO_CHANGE_SPEED:
                    assert math.isfinite(it.param4)
    px4 = build_mission(WPS, spec("px4"))
    assert math.isnan(px4[2].param4)  # keep heading; 0 would turn a PX4 copter north


def test_plane_takeoff_and_speed():
    items = build_mission(WPS, spec("ardupilot", PLANE))
    takeoff, speed = items[1], items[2]
    assert takeoff.command == C.MAV_CMD_NAV_TAKEOFF and takeoff.param1 == 10.0  # minimum pitch, deg
    assert takeoff.z == 50.0 and takeoff.frame == C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    lat, lon, _ = enu_to_geodetic(WPS[0], HOME)
    assert (takeoff.x, takeoff.y) == (to_int_e7(lat), to_int_e7(lon))
    assert speed.command == C.MAV_CMD_DO_CHANGE_SPEED and speed.frame == C.MAV_FRAME_MISSION
    assert (speed.param1, speed.param2, speed.param3) == (0.0, 18.0, -1.0)  # airspeed


def test_copter_takeoff_and_speed():
    items = build_mission(WPS, spec("ardupilot", COPTER))
    takeoff, speed = items[1], items[2]
    assert takeoff.param1 == 0.0
    assert takeoff.z == 50.0  # start z (50) above takeoff_alt (30): climb to the route's start height
    assert (speed.param1, speed.param2) == (1.0, 8.0)  # ground speed
    low = build_mission(WPS * [1, 1, 0.4], spec("ardupilot", COPTER))
    assert low[1].z == 30.0


@pytest.mark.parametrize(("action", "command"), [
    ("loiter", C.MAV_CMD_NAV_LOITER_UNLIM), ("rtl", C.MAV_CMD_NAV_RETURN_TO_LAUNCH), ("land", C.MAV_CMD_NAV_LAND)])
def test_end_actions(action, command):
    vehicle = VehicleLimits(end_action=action)
    items = build_mission(WPS, spec("ardupilot", vehicle))
    last, goal_wp = items[-1], items[-2]
    assert last.command == command
    assert goal_wp.command == C.MAV_CMD_NAV_WAYPOINT and goal_wp.z == WPS[-1, 2]
    if action == "rtl":
        assert (last.x, last.y) == (0, 0)
    else:
        assert (last.x, last.y) == (goal_wp.x, goal_wp.y)  # at the goal
    if action == "loiter":
        assert last.z == WPS[-1, 2]


def test_a_px4_vtol_takes_off_and_lands_as_a_vtol():
    """Layout px4-vtol: NAV_VTOL_TAKEOFF at the start (param1 0: PX4 transitions towards the item's position), the
    legs as a plane's (airspeed), NAV_VTOL_LAND at the goal for the end action "land"; loiter and RTL as on PX4."""
    land = dataclasses.replace(PLANE, end_action="land")
    vtol = build_mission(WPS, spec("px4-vtol", land))
    px4 = build_mission(WPS, spec("px4", land))
    assert commands(vtol) == [C.MAV_CMD_NAV_VTOL_TAKEOFF] + commands(px4)[1:-1] + [C.MAV_CMD_NAV_VTOL_LAND]
    first, last = vtol[0], vtol[-1]
    assert first.param1 == 0.0 and math.isnan(first.param4) and first.z == 50.0
    assert (first.x, first.y) == (px4[0].x, px4[0].y)  # at the start
    assert (last.x, last.y, last.z) == (px4[-1].x, px4[-1].y, 0.0)
    assert vtol[1].param1 == px4[1].param1 == 0.0  # DO_CHANGE_SPEED: airspeed
    loiter = build_mission(WPS, spec("px4-vtol", PLANE))
    assert loiter[-1].command == C.MAV_CMD_NAV_LOITER_UNLIM
    assert mission_waypoint_index(vtol, WPS, HOME)[0] == 0  # the take-off never reaches a waypoint


def test_acceptance_radius_cap_ardupilot_only():
    wide = VehicleLimits(acceptance_radius=400.0)
    wps = np.array([[0, 0, 50], [1000, 0, 50], [2000, 0, 50], [3000, 500, 60.0]])
    ap = [it for it in build_mission(wps, spec("ardupilot", wide)) if it.command == C.MAV_CMD_NAV_WAYPOINT][1:]
    px4 = [it for it in build_mission(wps, spec("px4", wide)) if it.command == C.MAV_CMD_NAV_WAYPOINT]
    assert {it.param2 for it in ap} == {255.0}
    assert {it.param2 for it in px4} == {400.0}
    odd = build_mission(wps, spec("ardupilot", VehicleLimits(acceptance_radius=12.6)))
    assert odd[3].param2 == 13.0  # whole metres: what ArduPilot stores and reads back


def test_close_waypoints_dropped_except_goal():
    wps = np.array([[0, 0, 50], [100, 0, 50], [110, 0, 50], [300, 0, 50], [310, 0, 50.0]])
    items = build_mission(wps, spec("px4"))
    route = [it for it in items if it.command == C.MAV_CMD_NAV_WAYPOINT]
    enu = geodetic_to_enu([it.lat for it in route], [it.lon for it in route], HOME.alt, HOME)
    assert np.allclose(enu[:, 0], [100, 300, 310], atol=0.05)  # 110 dropped (10 m < 20 m), goal kept at 10 m


def test_densify_follows_the_trajectory():
    wps = np.array([[0, 0, 50], [600, 0, 50], [600, 600, 80], [1200, 900, 60.0]])
    traj = sample_trajectory(wps, 5.0)["points"]
    plain = build_mission(wps, spec("ardupilot"))
    dense = build_mission(wps, spec("ardupilot", densify=True, densify_spacing_m=50.0), traj)
    route = [it for it in dense if it.command == C.MAV_CMD_NAV_WAYPOINT and not is_home_item(it)]
    assert len(dense) > len(plain) and len(route) >= 2000 / 50
    enu = geodetic_to_enu([it.lat for it in route], [it.lon for it in route], HOME.alt, HOME)
    enu[:, 2] = [it.z for it in route]
    # every item lies on the smoothed trajectory, at most ~spacing apart and never inside the acceptance radius
    gap_to_traj = np.min(np.linalg.norm(enu[:, None] - traj[None], axis=-1), axis=1)
    assert gap_to_traj.max() < 3.0
    steps = np.linalg.norm(np.diff(np.vstack([wps[:1], enu]), axis=0), axis=1)
    assert steps.max() <= 50.0 + 1e-6 and steps.min() >= 20.0
    # the planned waypoints themselves are among the items, the goal last
    index = mission_waypoint_index(dense, wps, HOME)
    matched = sorted({index[it.seq] for it in route})
    assert matched == [0, 1, 2, 3]
    assert np.allclose(enu[-1], wps[-1], atol=0.05)
    # without a trajectory the builder samples the same smoothing itself
    own = build_mission(wps, spec("ardupilot", densify=True, densify_spacing_m=50.0))
    assert len(own) == len(dense)


def test_mission_waypoint_index_maps_reached_items_to_route():
    items = build_mission(WPS, spec("ardupilot"))  # home, takeoff, speed, wp1..wp3, loiter
    assert mission_waypoint_index(items, WPS, HOME) == {1: 0, 3: 1, 4: 2, 5: 3, 6: 3}
    px4 = build_mission(WPS, spec("px4", fly_to_start=True))
    assert mission_waypoint_index(px4, WPS, HOME) == {0: 0, 2: 0, 3: 1, 4: 2, 5: 3, 6: 3}
    # a readback with ArduPilot's plain frame numbers maps the same
    plain = [MissionItem(**{**it.__dict__, "frame": 3 if it.frame == 6 else it.frame}) for it in items]
    assert mission_waypoint_index(plain, WPS, HOME) == {1: 0, 3: 1, 4: 2, 5: 3, 6: 3}


def test_fence_items():
    cyl = Cylinders([400.0, 600.0], [500.0, 200.0], [80.0, 70.4], [math.inf, 120.0], [100.0, 150.0])
    fence = build_fence(cyl, HOME)
    assert [it.seq for it in fence] == [0, 1]
    lat, lon, _ = enu_to_geodetic(np.array([[400.0, 500.0, 0.0], [600.0, 200.0, 0.0]]), HOME)
    for it, a, o, r in zip(fence, lat, lon, (80.0, 71.0)):
        assert it.command == C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION and it.mission_type == FENCE
        assert it.frame == C.MAV_FRAME_GLOBAL_INT
        assert (it.x, it.y) == (to_int_e7(a), to_int_e7(o))
        assert it.param1 == r and it.param2 == 0.0  # radius rounded up to whole metres
    # a zone the route may overfly (top below the route's highest point) is no fence
    assert len(build_fence(cyl, HOME, max_route_alt=150.0)) == 1
    assert build_fence(Cylinders.empty(), HOME) == []


SQUARE = np.array([[-1000.0, -1000.0], [1000.0, -1000.0], [1000.0, 1000.0], [-1000.0, 1000.0]])
NOTCH = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 300.0], [150.0, 100.0], [0.0, 300.0]])  # concave


def _prisms() -> Prisms:
    """A keep-in square, a concave no-fly from the ground to 150 m, a no-fly from 200 m up, one unlimited."""
    tri = np.array([[-500.0, -500.0], [-400.0, -500.0], [-450.0, -400.0]])
    return Prisms.from_polygons([NOTCH, SQUARE, NOTCH + 400.0, tri], [-math.inf, -math.inf, 200.0, -math.inf],
                                [150.0, math.inf, math.inf, math.inf], keep_in=[False, True, False, False])


def test_fence_polygons_keep_in_first_each_vertex_an_item():
    prisms = _prisms()
    cyl = Cylinders([400.0], [500.0], [80.0], [math.inf], [100.0])
    fence = build_fence(cyl, HOME, prisms=prisms)
    assert [it.seq for it in fence] == list(range(len(fence))) and {it.mission_type for it in fence} == {FENCE}
    assert [it.command for it in fence] == [C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION] * 4 + \
        [C.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION] * (5 + 5 + 3) + [C.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION]
    assert [it.param1 for it in fence[:-1]] == [4.0] * 4 + [5.0] * 10 + [3.0] * 3
    assert {(it.frame, it.z, it.param2) for it in fence} == {(C.MAV_FRAME_GLOBAL_INT, 0.0, 0.0)}
    # the vertices in the prisms' (counter-clockwise) order, encoded as the mission's positions are
    order = [1, 0, 2, 3]
    ring = np.concatenate([prisms.polygon(k) for k in order])
    lat, lon, _ = enu_to_geodetic(np.column_stack([ring, np.zeros(len(ring))]), HOME)
    assert [(it.x, it.y) for it in fence[:-1]] == [(to_int_e7(a), to_int_e7(o)) for a, o in zip(lat, lon)]


def test_fence_leaves_out_polygons_the_route_may_pass_over_or_under(caplog):
    prisms = _prisms()
    # the route between 100 and 180 m: over the notch (ceiling 150), under the raised notch (floor 200)
    with caplog.at_level("INFO", logger="companion.mission.builder"):
        fence = build_fence(Cylinders.empty(), HOME, 180.0, prisms=prisms, min_route_alt=100.0)
    assert [it.param1 for it in fence] == [4.0] * 4 + [3.0] * 3  # the keep-in square and the triangle
    assert "polygon 0: its ceiling 150 m is below the route's highest 180 m" in caplog.text
    assert "polygon 2: its floor 200 m is above the route's lowest 100 m" in caplog.text
    # a route that stays under the notch's ceiling and reaches the raised one's floor keeps both
    assert len(build_fence(Cylinders.empty(), HOME, 140.0, prisms=prisms, min_route_alt=200.0)) == 4 + 5 + 5 + 3
    assert build_fence(Cylinders.empty(), HOME, prisms=Prisms.empty()) == []


def test_mission_from_plan_json():
    doc = {"waypoints": WPS.tolist(), "home": {"lat": HOME.lat, "lon": HOME.lon, "alt": HOME.alt},
           "trajectory": {"points": sample_trajectory(WPS, 5.0)["points"].tolist()}}
    assert mission_from_plan_json(doc, PLANE, "px4") == build_mission(WPS, spec("px4", fly_to_start=True))
    dense = mission_from_plan_json(doc, PLANE, "ardupilot", densify=True, densify_spacing_m=40.0)
    assert len(dense) > len(build_mission(WPS, spec()))


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        MissionSpec("inav", PLANE, HOME)  # type: ignore[arg-type]  # a value outside the Literal, on purpose
    with pytest.raises(ValueError):
        build_mission(WPS[:1], spec())
    with pytest.raises(ValueError):
        build_mission(WPS[:, :2], spec())
