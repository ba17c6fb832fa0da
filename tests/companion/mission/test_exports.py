"""companion.mission.exports: .waypoints loads in pymavlink, .plan has QGroundControl's structure, GeoJSON is sane."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink import mavwp
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import normalise_frame
from companion.mission.builder import MissionSpec, build_mission, is_home_item
from companion.mission.exports import (
    export_from_plan_json,
    write_geojson,
    write_qgc_plan,
    write_waypoints,
    zones_of,
)
from companion.mission.geo import circles_from_cylinders, lonlatalt
from planner.trajectory.smoothing import sample_trajectory
from planner.world.config import VehicleLimits
from planner.world.environment import Cylinders
from planner.world.home import Home
from planner.world.scenario import load_scenario

HOME = Home(-35.363261, 149.165230, 584.0)
WPS = np.array([[200.0, 200.0, 50.0], [400.0, 300.0, 60.0], [600.0, 700.0, 80.0], [800.0, 800.0, 50.0]])
CYL = Cylinders([400.0, 600.0], [500.0, 200.0], [80.0, 70.0], [math.inf, 150.0], [100.0, 150.0])


def spec(autopilot: str = "ardupilot", vehicle_type: str = "plane") -> MissionSpec:
    return MissionSpec(autopilot, VehicleLimits(type=vehicle_type), HOME)  # type: ignore[arg-type]  # a parametrised name (str) where the Literal is wanted


# --- .waypoints --------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("end_action", ["loiter", "rtl", "land"])
def test_waypoints_file_loads_in_pymavlink(tmp_path: Path, end_action: str):
    items = build_mission(WPS, MissionSpec("ardupilot", VehicleLimits(end_action=end_action), HOME))
    path = write_waypoints(tmp_path / "m.waypoints", items)
    assert path.read_text().splitlines()[0] == "QGC WPL 110"
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(items)
    for it, w in zip(items, (loader.wp(i) for i in range(loader.count()))):
        assert (w.seq, w.command, w.frame) == (it.seq, it.command, normalise_frame(it.frame))
        assert w.x == pytest.approx(it.x / 1e7, abs=1e-7) and w.y == pytest.approx(it.y / 1e7, abs=1e-7)
        assert round(w.x * 1e7) == it.x and round(w.y * 1e7) == it.y  # exact to the encoded integer
        assert w.z == pytest.approx(it.z, abs=1e-6)
        assert (w.param1, w.param2, w.param3, w.param4) == pytest.approx(
            (it.param1, it.param2, it.param3, it.param4))
    assert loader.wp(0).frame == mavlink.MAV_FRAME_GLOBAL  # line 0: home
    assert loader.wp(1).frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT  # plain frame numbers in files


def test_waypoints_file_is_tab_separated_with_8_decimals(tmp_path: Path):
    path = write_waypoints(tmp_path / "m.waypoints", build_mission(WPS, spec()))
    lines = path.read_text().splitlines()[1:]
    for line in lines:
        cols = line.split("\t")
        assert len(cols) == 12
        assert len(cols[8].split(".")[1]) == 8 and len(cols[9].split(".")[1]) == 8
    assert lines[0].split("\t")[8:10] == ["-35.36326100", "149.16523000"]


def test_px4_waypoints_file_gets_a_home_line(tmp_path: Path):
    items = build_mission(WPS, spec("px4"))
    with pytest.raises(ValueError):
        write_waypoints(tmp_path / "x.waypoints", items)
    path = write_waypoints(tmp_path / "px4.waypoints", items, HOME)
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(path)) == len(items) + 1
    assert loader.wp(0).frame == mavlink.MAV_FRAME_GLOBAL and loader.wp(0).z == HOME.alt
    assert [loader.wp(i).command for i in range(1, loader.count())] == [it.command for it in items]
    assert math.isnan(loader.wp(3).param4)  # PX4 "keep heading" survives as NaN


# --- .plan ----------------------------------------------------------------------------------------------------------

def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_qgc_plan(doc: dict[str, Any]) -> None:
    """Structural check of a QGroundControl .plan v1 document (the keys and types QGC reads)."""
    assert doc["fileType"] == "Plan" and doc["version"] == 1 and isinstance(doc["groundStation"], str)
    mission = doc["mission"]
    assert mission["version"] == 2
    assert mission["firmwareType"] in (3, 12) and mission["vehicleType"] in (1, 2)
    assert _is_number(mission["cruiseSpeed"]) and _is_number(mission["hoverSpeed"])
    home = mission["plannedHomePosition"]
    assert isinstance(home, list) and len(home) == 3 and all(_is_number(v) for v in home)
    assert isinstance(mission["items"], list)
    for n, item in enumerate(mission["items"], start=1):
        assert item["type"] == "SimpleItem"
        assert isinstance(item["autoContinue"], bool)
        assert isinstance(item["command"], int) and isinstance(item["frame"], int)
        assert item["doJumpId"] == n
        assert isinstance(item["params"], list) and len(item["params"]) == 7
        assert all(p is None or _is_number(p) for p in item["params"])
    fence = doc["geoFence"]
    assert fence["version"] == 2 and isinstance(fence["polygons"], list)
    for c in fence["circles"]:
        assert isinstance(c["inclusion"], bool) and c["version"] == 1
        center = c["circle"]["center"]
        assert len(center) == 2 and all(_is_number(v) for v in center)
        assert _is_number(c["circle"]["radius"]) and c["circle"]["radius"] > 0
    rally = doc["rallyPoints"]
    assert rally["version"] == 2 and all(len(p) == 3 for p in rally["points"])


@pytest.mark.parametrize(("autopilot", "vehicle_type", "firmware", "vehicle_code"), [
    ("ardupilot", "plane", 3, 1), ("ardupilot", "copter", 3, 2), ("px4", "plane", 12, 1), ("px4", "copter", 12, 2)])
def test_qgc_plan_structure(tmp_path: Path, autopilot, vehicle_type, firmware, vehicle_code):
    s = spec(autopilot, vehicle_type)
    items = build_mission(WPS, s)
    path = write_qgc_plan(tmp_path / "m.plan", items, s, CYL, rally=[(-35.36, 149.16, 60.0)])
    text = path.read_text()
    doc = json.loads(text)
    check_qgc_plan(doc)
    assert json.loads(json.dumps(doc)) == doc
    assert "NaN" not in text
    mission = doc["mission"]
    assert (mission["firmwareType"], mission["vehicleType"]) == (firmware, vehicle_code)
    assert mission["plannedHomePosition"] == [HOME.lat, HOME.lon, HOME.alt]
    flown = [it for it in items if not is_home_item(it)]  # ArduPilot's home item lives in plannedHomePosition
    assert len(mission["items"]) == len(flown)
    assert [i["command"] for i in mission["items"]] == [it.command for it in flown]
    assert mission["items"][0]["command"] == mavlink.MAV_CMD_NAV_TAKEOFF
    for i, it in zip(mission["items"], flown):
        assert i["params"][4:6] == [it.x / 1e7, it.y / 1e7] and i["params"][6] == it.z
        if math.isnan(it.param4):
            assert i["params"][3] is None
    circles = doc["geoFence"]["circles"]
    assert [c["circle"]["radius"] for c in circles] == [80.0, 70.0]
    assert all(c["inclusion"] is False for c in circles)
    assert circles[0]["circle"]["center"] == pytest.approx(
        [circles_from_cylinders(CYL, HOME)[0].lat, circles_from_cylinders(CYL, HOME)[0].lon])


# --- GeoJSON -------------------------------------------------------------------------------------------------------

def test_geojson_lon_lat_order_and_closed_rings(tmp_path: Path):
    route = lonlatalt(WPS, HOME)
    path = write_geojson(tmp_path / "m.geojson", route, circles_from_cylinders(CYL, HOME),
                         trajectory=lonlatalt(sample_trajectory(WPS, 10.0)["points"], HOME))
    doc = json.loads(path.read_text())
    assert doc["type"] == "FeatureCollection"
    kinds = [f["geometry"]["type"] for f in doc["features"]]
    assert kinds.count("LineString") == 2 and kinds.count("Polygon") == 2 and kinds.count("Point") == 2
    line = doc["features"][0]["geometry"]["coordinates"]
    assert len(line) == len(WPS)
    for lon, lat, alt in line:  # near CMAC: lon ≈ 149, lat ≈ −35
        assert abs(lon - HOME.lon) < 0.05 and abs(lat - HOME.lat) < 0.05
        assert alt > HOME.alt
    for f in doc["features"]:
        if f["geometry"]["type"] == "Polygon":
            ring = f["geometry"]["coordinates"][0]
            assert ring[0] == ring[-1] and len(ring) == 65
            assert f["properties"]["radius_m"] > 0 and "top" in f["properties"]
            assert abs(ring[0][0] - HOME.lon) < 0.05 and abs(ring[0][1] - HOME.lat) < 0.05
    tops = [f["properties"]["top"] for f in doc["features"] if f["geometry"]["type"] == "Polygon"]
    assert tops == [None, 150.0]  # unlimited is null: strict JSON
    points = {f["properties"]["name"]: f["geometry"]["coordinates"] for f in doc["features"]
              if f["geometry"]["type"] == "Point"}
    assert points["start"] == list(route[0]) and points["goal"] == list(route[-1])


# --- fuseplan export -------------------------------------------------------------------------------------------------

@pytest.fixture
def plan_doc(rescue_static: Path) -> tuple[dict[str, Any], Any]:
    scenario = load_scenario(rescue_static)
    wps = np.array([scenario.start, [500.0, 560.0, 50.0], scenario.goal])
    h = scenario.home
    doc = {"scenario": scenario.name, "status": "exact", "waypoints": wps.tolist(),
           "trajectory": {"points": sample_trajectory(wps, 5.0)["points"].tolist()},
           "home": {"lat": h.lat, "lon": h.lon, "alt": h.alt}}
    return json.loads(json.dumps(doc)), scenario


def test_export_from_plan_json_all_formats(tmp_path: Path, plan_doc):
    doc, scenario = plan_doc
    wp = export_from_plan_json(doc, scenario, "waypoints", tmp_path / "r.waypoints")
    loader = mavwp.MAVWPLoader()
    assert loader.load(str(wp)) == 1 + 2 + 1 + 2 + 1  # home, takeoff, speed, start, 2 waypoints, loiter
    plan = export_from_plan_json(doc, scenario, "plan", tmp_path / "r.plan", "px4", densify=True)
    pdoc = json.loads(plan.read_text())
    check_qgc_plan(pdoc)
    assert len(pdoc["mission"]["items"]) > 5 and pdoc["mission"]["firmwareType"] == 12
    assert len(pdoc["geoFence"]["circles"]) == len(scenario.environment.cylinders)
    gj = json.loads(export_from_plan_json(doc, scenario, "geojson", tmp_path / "r.geojson").read_text())
    assert sum(f["geometry"]["type"] == "Polygon" for f in gj["features"]) == len(zones_of(scenario, scenario.home))
    with pytest.raises(ValueError):
        export_from_plan_json(doc, scenario, "kml", tmp_path / "r.kml")  # type: ignore[arg-type]  # a value outside the Literal, on purpose


@pytest.mark.asyncio
async def test_qgc_plan_is_read_back_by_mavsdk_import(tmp_path: Path, plan_doc, mavsdk_ground_station):
    """A MAVSDK 4 ground station connected to our simulated autopilot imports the exported .plan with
    import_qgroundcontrol_mission: same items as we built (after the plannedHomePosition item it puts first),
    and one geofence item per exported circle."""
    from companion.mission.builder import is_home_item, mission_from_plan_json

    doc, scenario = plan_doc
    path = export_from_plan_json(doc, scenario, "plan", tmp_path / "r.plan")
    ours = [it for it in mission_from_plan_json(doc, scenario, "ardupilot") if not is_home_item(it)]
    n_circles = len(json.loads(path.read_text())["geoFence"]["circles"])
    async with mavsdk_ground_station(scenario) as raw:
        data = await raw.import_qgroundcontrol_mission(str(path))
    items = data.mission_items
    assert len(items) == len(ours) + 1  # MAVSDK puts the planned home first
    for got, want in zip(items[1:], ours):
        assert (got.command, got.x, got.y) == (want.command, want.x, want.y)
        assert got.z == pytest.approx(want.z, abs=1e-3)
        assert [got.param1, got.param2, got.param3] == pytest.approx([want.param1, want.param2, want.param3])
    assert len(data.geofence_items) >= n_circles
