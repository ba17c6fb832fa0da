"""planner.world.imports.read_qgc_plan: a hand-written QGroundControl plan read into geographic values, and every
refusal naming the file, the item and the reason in one line."""

from __future__ import annotations

import copy
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude, GeoPoint
from planner.world.imports import read_qgc_plan

DATA = Path(__file__).parents[3] / "data" / "imports"
PLAN = DATA / "cmac_mission.plan"


def test_reads_route_fence_rally_and_settings():
    m = read_qgc_plan(PLAN)
    assert m.source == PLAN
    assert m.home == GeoPoint(-35.363261, 149.165230, Altitude(584.0, "amsl"))
    assert m.start == m.home
    # items: take-off (no place), relative WP, DO_CHANGE_SPEED, "calculated above terrain" WP, AMSL WP,
    # LOITER_TIME in the terrain frame, RTL (no place): the loiter is the goal
    assert m.vias == (GeoPoint(-35.36, 149.162, Altitude(60.0, "home")),
                      GeoPoint(-35.366, 149.17, Altitude(50.0, "ground")),  # the operator's 50 m above terrain
                      GeoPoint(-35.368, 149.162, Altitude(654.0, "amsl")))
    assert m.goal == GeoPoint(-35.364, 149.16, Altitude(40.0, "ground"))
    assert [(z.name, z.inclusion, z.polygon is not None) for z in m.zones] == [
        ("geoFence.polygons[0]", True, True), ("geoFence.polygons[1]", False, True),
        ("geoFence.circles[0]", False, False)]
    assert m.zones[0].polygon[0] == (-35.357, 149.159) and len(m.zones[0].polygon) == 4
    assert m.zones[2].centre == (-35.3605, 149.166) and m.zones[2].radius_m == 60.0
    assert all(z.floor is None and z.ceiling is None for z in m.zones)
    assert m.rally == (GeoPoint(-35.361, 149.161, Altitude(50.0, "home")),
                       GeoPoint(-35.369, 149.172, Altitude(60.0, "home")))
    x = m.extras
    assert (x["firmware_type"], x["vehicle_type"], x["cruise_speed"], x["hover_speed"]) == (3, 1, 18.0, 5.0)
    assert (x["plan_version"], x["mission_version"], x["geofence_version"], x["rally_version"]) == (1, 2, 2, 2)
    assert x["end_command"] == "RETURN_TO_LAUNCH"
    assert x["breach_return"] == GeoPoint(-35.3632, 149.165, Altitude(40.0, "home"))


def _variant(tmp_path: Path, change: Callable[[dict[str, Any]], object]) -> Path:
    doc = copy.deepcopy(json.loads(PLAN.read_text()))
    change(doc)
    path = tmp_path / "variant.plan"
    path.write_text(json.dumps(doc))
    return path


def test_without_planned_home_the_first_position_is_the_start(tmp_path: Path):
    m = read_qgc_plan(_variant(tmp_path, lambda d: d["mission"].pop("plannedHomePosition")))
    assert m.home is None
    assert m.start == GeoPoint(-35.36, 149.162, Altitude(60.0, "home"))
    assert len(m.vias) == 2 and m.goal == GeoPoint(-35.364, 149.16, Altitude(40.0, "ground"))


def test_a_land_with_a_position_is_the_goal(tmp_path: Path):
    land = {"type": "SimpleItem", "command": 21, "frame": 3, "autoContinue": True, "doJumpId": 8,
            "params": [0, 0, 0, None, -35.3625, 149.1655, 0]}
    m = read_qgc_plan(_variant(tmp_path, lambda d: d["mission"]["items"].append(land)))
    assert m.goal == GeoPoint(-35.3625, 149.1655, Altitude(0.0, "home"))
    assert m.vias[-1] == GeoPoint(-35.364, 149.16, Altitude(40.0, "ground"))
    assert m.extras["end_command"] == "LAND"


def _set(*path_and_value: Any) -> Callable[[dict[str, Any]], None]:
    *path, value = path_and_value

    def change(doc: dict[str, Any]) -> None:
        node = doc
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value
    return change


SURVEY = {"type": "ComplexItem", "complexItemType": "survey", "version": 5}
BOW_TIE = [[-35.357, 149.159], [-35.370, 149.174], [-35.357, 149.174], [-35.370, 149.159]]

ERRORS = [
    (_set("fileType", "Mission"), "fileType", "'Mission' is not a QGroundControl plan"),
    (_set("version", 2), "version", "plan version 2 is not supported"),
    (_set("mission", "version", 1), "mission.version", "mission version 1 is not supported"),
    (_set("mission", "items", 2, SURVEY), "mission.items[2]", "ComplexItem 'survey'"),
    (_set("mission", "items", 1, "type", "Thing"), "mission.items[1].type", "'Thing' is not a mission item type"),
    (_set("mission", "items", 1, "frame", 1), "mission.items[1].frame", "frame 1 is not supported"),
    (_set("mission", "items", 1, "params", [0, 0, 0, 0, -35.36, 149.16]), "mission.items[1].params",
     "6 values"),
    (_set("mission", "items", 1, "params", 4, 95.0), "mission.items[1].params", "latitude 95 is outside"),
    (_set("mission", "items", 1, "command", "16"), "mission.items[1].command", "expected an integer, got a string"),
    (_set("mission", "plannedHomePosition", [-35.36, 149.16]), "mission.plannedHomePosition",
     "expected [lat, lon, alt]"),
    (_set("geoFence", "version", 1), "geoFence.version", "geoFence version 1 is not supported"),
    (_set("geoFence", "polygons", 0, "polygon", BOW_TIE), "geoFence.polygons[0].polygon", "intersects itself"),
    (_set("geoFence", "polygons", 1, "polygon", BOW_TIE[:2]), "geoFence.polygons[1].polygon",
     "2 vertices (a polygon needs at least 3)"),
    (_set("geoFence", "polygons", 1, "polygon", 2, [-35.3, 181.0]), "geoFence.polygons[1].polygon[2]",
     "longitude 181 is outside"),
    (_set("geoFence", "polygons", 0, "inclusion", "yes"), "geoFence.polygons[0].inclusion",
     "expected true or false"),
    (_set("geoFence", "circles", 0, "circle", "radius", 0), "geoFence.circles[0].circle.radius",
     "a circle's radius must be > 0"),
    (_set("rallyPoints", "points", 1, [-35.36, 149.16]), "rallyPoints.points[1]", "expected [lat, lon, alt]"),
    (_set("rallyPoints", "version", 1), "rallyPoints.version", "rallyPoints version 1 is not supported"),
]


@pytest.mark.parametrize(("change", "where", "reason"), ERRORS, ids=[e[1] + ":" + e[2][:20] for e in ERRORS])
def test_refusals_name_file_item_and_reason(tmp_path: Path, change, where: str, reason: str):
    path = _variant(tmp_path, change)
    with pytest.raises(ScenarioError) as err:
        read_qgc_plan(path)
    assert (err.value.file, err.value.field) == (str(path), where)
    assert reason in err.value.reason
    assert str(err.value).startswith(f"{path}: {where}: ") and "\n" not in str(err.value)


def test_malformed_json_gives_line_and_column(tmp_path: Path):
    path = tmp_path / "broken.plan"
    path.write_text('{\n  "fileType": "Plan",\n  "version": 1,,\n}\n')
    with pytest.raises(ScenarioError) as err:
        read_qgc_plan(path)
    assert err.value.field == "line 3 column 16" and "malformed JSON" in err.value.reason


def test_nan_is_not_json(tmp_path: Path):
    path = _variant(tmp_path, lambda d: None)
    path.write_text(path.read_text().replace("584", "NaN"))
    with pytest.raises(ScenarioError, match="NaN is not JSON"):
        read_qgc_plan(path)


def test_a_missing_file_is_one_line(tmp_path: Path):
    with pytest.raises(ScenarioError) as err:
        read_qgc_plan(tmp_path / "nowhere.plan")
    assert err.value.file == str(tmp_path / "nowhere.plan") and "\n" not in str(err.value)
