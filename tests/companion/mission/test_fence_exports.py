"""companion.mission.exports fence and zone writers: prisms to zones, and every file written read back by our
importers (round trips), by MAVSDK's QGroundControl and Mission Planner importers, and by pymavlink."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavwp
from pymavlink.dialects.v20 import common as mavlink

from companion.mission.builder import MissionSpec, build_mission, is_home_item
from companion.mission.exports import (
    fence_zones,
    mp_fence_text,
    operator_plan,
    write_geojson,
    write_mp_fence,
    write_operator_plan,
    write_qgc_plan,
    write_waypoints,
    write_zones_geojson,
    zone_feature,
    zones_from_prisms,
)
from companion.mission.geo import geodetic_to_enu, to_int_e7
from planner.world.config import VehicleLimits
from planner.world.environment import Prisms
from planner.world.geo_inputs import Altitude, GeoPoint, Zone
from planner.world.home import Home
from planner.world.imports import read_qgc_plan, read_waypoints, read_zones
from planner.world.scenario import load_scenario

HOME = Home(-35.363261, 149.165230, 584.0)
DATA = Path(__file__).parents[2] / "data" / "imports"
WPS = np.array([[200.0, 200.0, 50.0], [400.0, 300.0, 60.0], [600.0, 700.0, 80.0], [800.0, 800.0, 50.0]])
SQUARE = np.array([[300.0, 400.0], [500.0, 400.0], [500.0, 600.0], [300.0, 600.0]])
TRIANGLE = np.array([[700.0, 100.0], [600.0, 300.0], [800.0, 250.0]])  # clockwise: stored counter-clockwise
AREA = np.array([[-1500.0, -1500.0], [1500.0, -1500.0], [1500.0, 1500.0], [-1500.0, 1500.0]])
PRISMS = Prisms.from_polygons([SQUARE, TRIANGLE, AREA], [-math.inf, 20.0, -math.inf], [120.0, math.inf, math.inf],
                              [False, False, True])


def spec(autopilot: str = "ardupilot") -> MissionSpec:
    return MissionSpec(autopilot, VehicleLimits(), HOME)  # type: ignore[arg-type]  # a parametrised name (str) where the Literal is wanted


def _enu(zone: Zone) -> np.ndarray:
    lat, lon = np.array(zone.polygon).T
    return geodetic_to_enu(lat, lon, HOME.alt, HOME)[:, :2]


def _same_ring(a: tuple, b: tuple) -> bool:
    """Same polygon up to orientation (writers may reverse a ring to counter-clockwise)."""
    return a == b or a == (b[0],) + tuple(reversed(b[1:]))


def test_zones_from_prisms_place_vertices_and_heights():
    zones = zones_from_prisms(PRISMS, HOME, names=["square", "triangle", "area"])
    assert [z.name for z in zones] == ["square", "triangle", "area"]
    for k, z in enumerate(zones):
        np.testing.assert_allclose(_enu(z), PRISMS.polygon(k), atol=1e-6)  # metres, back through pymap3d
    assert (zones[0].floor, zones[0].ceiling) == (None, Altitude(120.0, "home"))
    assert (zones[1].floor, zones[1].ceiling) == (Altitude(20.0, "home"), None)
    assert [z.inclusion for z in zones] == [False, False, True]
    assert zones_from_prisms(Prisms.empty(), HOME) == []


def test_geojson_round_trip(tmp_path: Path):
    zones = zones_from_prisms(PRISMS, HOME) + [Zone("mast", centre=(-35.36, 149.167), radius_m=45.0,
                                                    ceiling=Altitude(700.0, "amsl"))]
    back = read_zones(write_zones_geojson(tmp_path / "z.geojson", zones))
    assert len(back) == len(zones)
    for z, b in zip(zones, back):
        assert b.name == f"features[{zones.index(z)}] {z.name!r}"
        assert (b.inclusion, b.floor, b.ceiling, b.centre, b.radius_m) == \
            (z.inclusion, z.floor, z.ceiling, z.centre, z.radius_m)
        assert z.polygon is None or _same_ring(b.polygon, z.polygon)
    ring = zone_feature(zones[0])["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and ring[0] == [zones[0].polygon[0][1], zones[0].polygon[0][0]]  # [lon, lat]


def test_geojson_ring_is_counter_clockwise():
    clockwise = Zone("cw", polygon=((-35.36, 149.16), (-35.36, 149.17), (-35.37, 149.17)))
    ring = np.array(zone_feature(clockwise)["geometry"]["coordinates"][0][:-1])
    x, y = ring[:, 0], ring[:, 1]
    assert np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y) > 0


def test_mission_planner_fence_round_trip_and_pymavlink(tmp_path: Path):
    zones = zones_from_prisms(PRISMS, HOME) + [Zone("mast", centre=(-35.36, 149.167), radius_m=45.0)]
    back_point = GeoPoint(-35.3632, 149.165, Altitude(40.0, "home"))
    fence = write_mp_fence(tmp_path / "f.waypoints", zones, HOME, back_point)
    m = read_waypoints(DATA / "cmac_mission.waypoints", fence_path=fence)
    assert [z.inclusion for z in m.zones] == [False, False, True, False]
    for z, b in zip(zones, m.zones):
        if z.polygon is not None:
            assert np.allclose(b.polygon, z.polygon, atol=1e-8) and len(b.polygon) == len(z.polygon)
        else:
            assert b.centre == z.centre and b.radius_m == z.radius_m
    assert m.extras["fence_return"] == back_point
    loader = mavwp.MAVWPLoader()
    n = loader.load(str(fence))
    commands = [loader.wp(i).command for i in range(n)]
    assert commands == [16, mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT] + [5002] * 4 + [5002] * 3 + [5001] * 4 + [5004]
    assert [loader.wp(i).param1 for i in range(2, 13)] == [4.0] * 4 + [3.0] * 3 + [4.0] * 4


def test_mission_planner_fence_refuses_a_bad_zone():
    with pytest.raises(ValueError, match="zone flat: 2 vertices"):
        mp_fence_text([Zone("flat", polygon=((-35.36, 149.16), (-35.37, 149.17)))], HOME)
    with pytest.raises(ValueError, match="zone dot: a circle needs a radius > 0"):
        mp_fence_text([Zone("dot", centre=(-35.36, 149.16), radius_m=0.0)], HOME)


def test_plan_fence_polygons_round_trip(tmp_path: Path):
    zones = zones_from_prisms(PRISMS, HOME)
    items = build_mission(WPS, spec())
    path = write_qgc_plan(tmp_path / "z.plan", items, spec(), fence=[], zones=zones)
    doc = json.loads(path.read_text())
    assert [p["version"] for p in doc["geoFence"]["polygons"]] == [1, 1, 1]
    back = read_qgc_plan(path)
    assert [(z.inclusion, z.polygon) for z in back.zones] == [(z.inclusion, z.polygon) for z in zones]


def test_operator_plan_keeps_fence_rally_and_settings(tmp_path: Path):
    op = read_qgc_plan(DATA / "cmac_mission.plan")
    items = build_mission(WPS, spec())
    path = write_operator_plan(tmp_path / "safe.plan", items, spec(), op)
    back = read_qgc_plan(path)
    assert back.zones == op.zones and back.rally == op.rally
    for key in ("breach_return", "cruise_speed", "hover_speed", "vehicle_type", "firmware_type"):
        assert back.extras[key] == op.extras[key], key
    doc = json.loads(path.read_text())
    flown = [it for it in items if not is_home_item(it)]
    assert [i["command"] for i in doc["mission"]["items"]] == [it.command for it in flown]
    assert doc["mission"]["plannedHomePosition"] == [HOME.lat, HOME.lon, HOME.alt]
    replaced = operator_plan(items, spec(), op, zones=op.zones[:1])["geoFence"]
    assert len(replaced["polygons"]) == 1 and replaced["circles"] == []


def test_operator_plan_refuses_the_other_autopilot():
    op = read_qgc_plan(DATA / "cmac_mission.plan")  # firmwareType 3: ArduPilot
    with pytest.raises(ValueError, match="firmwareType 3, the items for 12"):
        operator_plan(build_mission(WPS, spec("px4")), spec("px4"), op)


def test_fence_zones_keeps_what_holds_at_every_height():
    zones = [Zone("low", polygon=((0, 0), (0, 1), (1, 1)), ceiling=Altitude(60.0, "home")),
             Zone("tall", polygon=((0, 0), (0, 1), (1, 1)), ceiling=Altitude(200.0, "home")),
             Zone("tall amsl", polygon=((0, 0), (0, 1), (1, 1)), ceiling=Altitude(800.0, "amsl")),
             Zone("low amsl", polygon=((0, 0), (0, 1), (1, 1)), ceiling=Altitude(650.0, "amsl")),
             Zone("terrain", polygon=((0, 0), (0, 1), (1, 1)), ceiling=Altitude(300.0, "ground")),
             Zone("raised", polygon=((0, 0), (0, 1), (1, 1)), floor=Altitude(40.0, "home")),
             Zone("full", polygon=((0, 0), (0, 1), (1, 1))),
             Zone("area", inclusion=True, polygon=((0, 0), (0, 1), (1, 1)))]
    kept = fence_zones(zones, HOME, low_m=30.0, high_m=100.0)
    assert [z.name for z in kept] == ["tall", "tall amsl", "full", "area"]


@pytest.mark.asyncio
async def test_operator_plan_and_mp_fence_load_in_mavsdk(tmp_path: Path, rescue_static: Path, mavsdk_ground_station):
    """A MAVSDK ground station connected to our simulated autopilot imports the written .plan with
    import_qgroundcontrol_mission (fence polygons as vertex items of param1 = vertex count, circles, rally
    points) and the Mission Planner fence with import_mission_planner_mission (every line an item)."""
    op = read_qgc_plan(DATA / "cmac_mission.plan")
    zones = list(op.zones) + zones_from_prisms(PRISMS, HOME)[:2]
    plan = write_operator_plan(tmp_path / "safe.plan", build_mission(WPS, spec()), spec(), op, zones=zones)
    fence_text = mp_fence_text(zones, HOME)
    async with mavsdk_ground_station(load_scenario(rescue_static)) as raw:
        data = await raw.import_qgroundcontrol_mission(str(plan))
        mp = await raw.import_mission_planner_mission_from_string(fence_text)
    polygons = [z for z in zones if z.polygon is not None]
    circles = [z for z in zones if z.centre is not None]
    want = [(5001 if z.inclusion else 5002, len(z.polygon), a, o) for z in polygons for a, o in z.polygon]
    want += [(5003 if z.inclusion else 5004, z.radius_m, *z.centre) for z in circles]
    got = [(it.command, it.param1, it.x, it.y) for it in data.geofence_items]
    assert len(got) == len(want) == 4 + 4 + 4 + 3 + 1
    for (gc, gp, gx, gy), (wc, wp, lat, lon) in zip(got, want):
        assert (gc, gp) == (wc, pytest.approx(wp))
        assert (gx, gy) == (to_int_e7(lat), to_int_e7(lon))
    assert [(it.x, it.y) for it in data.rally_items] == [(to_int_e7(p.lat), to_int_e7(p.lon)) for p in op.rally]
    assert [it.z for it in data.rally_items] == [pytest.approx(p.alt.value) for p in op.rally]
    mp_fence = [(it.command, it.param1) for it in mp.mission_items if it.command >= 5000]
    in_order = [row for z in zones for row in (
        [(5001 if z.inclusion else 5002, len(z.polygon))] * len(z.polygon) if z.polygon is not None
        else [(5003 if z.inclusion else 5004, z.radius_m)])]
    assert mp_fence == [(c, pytest.approx(p)) for c, p in in_order]  # the file's order: zone by zone


@pytest.mark.parametrize("fmt", ["waypoints", "plan"])
def test_route_exports_read_back_as_the_route(tmp_path: Path, fmt: str):
    """Our own route files read back: home is the start, the route's points the vias, its end the goal (the
    loiter at the goal counts once), heights above home."""
    items = build_mission(WPS, spec())
    if fmt == "waypoints":
        m = read_waypoints(write_waypoints(tmp_path / "r.waypoints", items))
    else:
        m = read_qgc_plan(write_qgc_plan(tmp_path / "r.plan", items, spec()))
    assert m.start == m.home == GeoPoint(HOME.lat, HOME.lon, Altitude(HOME.alt, "amsl"))
    got = [*m.vias, m.goal]
    assert len(got) == len(WPS)
    lat, lon = np.array([[p.lat, p.lon] for p in got]).T
    np.testing.assert_allclose(geodetic_to_enu(lat, lon, HOME.alt, HOME)[:, :2], WPS[:, :2], atol=0.02)  # 1e-7 deg
    assert [p.alt for p in got] == [Altitude(float(z), "home") for z in WPS[:, 2]]
    assert m.extras["end_command"] == "LOITER_UNLIM"


def test_route_geojson_draws_geographic_zones_as_read_zones_writes_them(tmp_path: Path):
    zones = zones_from_prisms(PRISMS, HOME)
    route = [(HOME.lon, HOME.lat, 634.0), (HOME.lon + 0.01, HOME.lat + 0.01, 634.0)]
    doc = json.loads(write_geojson(tmp_path / "r.geojson", route, geo_zones=zones).read_text())
    drawn = [f for f in doc["features"] if f["geometry"]["type"] == "Polygon"]
    assert drawn == [zone_feature(z) for z in zones]
