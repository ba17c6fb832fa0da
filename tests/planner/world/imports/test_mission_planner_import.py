"""planner.world.imports.read_waypoints: Mission Planner's waypoint, fence (QGC WPL 110 and the older .fen) and
rally files read into geographic values, and every refusal naming the file, the line and the reason."""

from __future__ import annotations

from pathlib import Path

import pytest

from planner.errors import ScenarioError
from planner.world.geo_inputs import Altitude, GeoPoint
from planner.world.imports import read_qgc_plan, read_waypoints

DATA = Path(__file__).parents[3] / "data" / "imports"
MISSION = DATA / "cmac_mission.waypoints"
AREA = ((-35.357, 149.159), (-35.357, 149.174), (-35.37, 149.174), (-35.37, 149.159))


def test_reads_the_route():
    m = read_waypoints(MISSION)
    assert m.home == GeoPoint(-35.363261, 149.16523, Altitude(584.0, "amsl")) and m.start == m.home
    assert m.vias == (GeoPoint(-35.36, 149.162, Altitude(60.0, "home")),
                      GeoPoint(-35.366, 149.17, Altitude(50.0, "ground")),
                      GeoPoint(-35.368, 149.162, Altitude(654.0, "amsl")))
    # LOITER_TIME then LAND at the same place: one goal, at the landing's altitude
    assert m.goal == GeoPoint(-35.364, 149.16, Altitude(0.0, "home"))
    assert m.extras["end_command"] == "LAND" and m.zones == () and m.rally == ()


def test_the_same_route_as_the_plan():
    wp, plan = read_waypoints(MISSION), read_qgc_plan(DATA / "cmac_mission.plan")
    assert (wp.home, wp.vias[0], wp.vias[2]) == (plan.home, plan.vias[0], plan.vias[2])
    assert (wp.goal.lat, wp.goal.lon) == (plan.goal.lat, plan.goal.lon)


def test_fence_file_in_the_fence_mission_type():
    m = read_waypoints(MISSION, fence_path=DATA / "cmac_fence.waypoints")
    assert [(z.name, z.inclusion) for z in m.zones] == [
        ("cmac_fence.waypoints line 4", True), ("cmac_fence.waypoints line 8", False),
        ("cmac_fence.waypoints line 12", False)]
    assert m.zones[0].polygon == AREA
    assert m.zones[1].polygon[2] == (-35.365, 149.168)
    assert m.zones[2].centre == (-35.3605, 149.166) and m.zones[2].radius_m == 60.0
    assert m.extras["fence_return"] == GeoPoint(-35.3632, 149.165, Altitude(40.0, "home"))
    assert m.vias == read_waypoints(MISSION).vias  # the fence's home line is not a route point


def test_older_fen_and_ral_files():
    m = read_waypoints(MISSION, fence_path=DATA / "cmac.fen", rally_path=DATA / "cmac.ral")
    (area,) = m.zones
    assert area.inclusion and area.polygon == AREA  # the closing vertex dropped
    assert m.extras["fence_return"] == GeoPoint(-35.3632, 149.165)
    assert m.rally == (GeoPoint(-35.361, 149.161, Altitude(50.0, "home")),
                       GeoPoint(-35.369, 149.172, Altitude(60.0, "home")))


def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _write(tmp_path: Path, name: str, lines: list[str]) -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def _replace_field(line: str, index: int, value: str) -> str:
    fields = line.split("\t")
    fields[index] = value
    return "\t".join(fields)


def test_mission_refusals(tmp_path: Path):
    lines = _lines(MISSION)
    cases = [
        (["QGC WPL 100"] + lines[1:], "line 1", "'QGC WPL 100' is not supported"),
        (["Hello"] + lines[1:], "line 1", "not a waypoint file"),
        (lines[:3] + [lines[3].rsplit("\t", 1)[0]] + lines[4:], "line 4", "11 fields"),
        (lines[:3] + [_replace_field(lines[3], 8, "north")] + lines[4:], "line 4", "'north' is not a number"),
        (lines[:3] + [_replace_field(lines[3], 9, "190.5")] + lines[4:], "line 4", "longitude 190.5 is outside"),
        (lines[:3] + [_replace_field(lines[3], 2, "1")] + lines[4:], "line 4", "frame 1 is not supported"),
        (lines[:3] + [_replace_field(lines[3], 3, "1.5")] + lines[4:], "line 4", "'1.5' is not an integer"),
    ]
    for content, where, reason in cases:
        path = _write(tmp_path, "bad.waypoints", content)
        with pytest.raises(ScenarioError) as err:
            read_waypoints(path)
        assert (err.value.file, err.value.field) == (str(path), where), content
        assert reason in err.value.reason and "\n" not in str(err.value)


def test_fence_refusals(tmp_path: Path):
    lines = _lines(DATA / "cmac_fence.waypoints")  # file lines 4..7 inclusion polygon, 8..11 exclusion, 12 circle
    cases = [
        (lines[:9] + lines[11:], "line 10", "starting at line 8 has 4 vertices (param1) but 2 are given"),
        (lines[:10], "line 8", "the file ends after 3"),
        (lines[:3] + [_replace_field(ln, 4, "2.00000000") for ln in lines[3:5]] + lines[7:], "line 4",
         "vertex count (param1) is 2"),
        (lines[:3] + [_replace_field(lines[3], 4, "inf")] + lines[4:], "line 4", "vertex count (param1) is inf"),
        (lines[:3] + [lines[3], lines[5], lines[4], lines[6]] + lines[7:], "line 4", "intersects itself"),
        (lines[:11] + [_replace_field(lines[11], 4, "0")], "line 12", "radius (param1) is 0 m"),
        (lines + ["12\t0\t3\t16\t0\t0\t0\t0\t-35.36\t149.16\t50\t1"], "line 13", "not a fence item"),
    ]
    for content, where, reason in cases:
        path = _write(tmp_path, "bad_fence.waypoints", content)
        with pytest.raises(ScenarioError) as err:
            read_waypoints(MISSION, fence_path=path)
        assert (err.value.file, err.value.field) == (str(path), where), content
        assert reason in err.value.reason and "\n" not in str(err.value)


def test_older_format_refusals(tmp_path: Path):
    fen = _lines(DATA / "cmac.fen")
    cases = [
        ("f.fen", fen[:2] + ["-35.357 149.159 12"] + fen[3:], "fence", "line 3", "3 fields"),
        ("f.fen", fen[:4], "fence", "line 3", "2 vertices"),
        ("f.fen", ["# nothing"], "fence", "", "no fence points"),
        ("r.ral", ["RALLY\t-35.36\t149.16"], "rally", "line 1", "not a rally line"),
        ("r.ral", ["RALLY\t-95\t149.16\t50\t0\t0\t0"], "rally", "line 1", "latitude -95 is outside"),
    ]
    for name, content, kind, where, reason in cases:
        path = _write(tmp_path, name, content)
        with pytest.raises(ScenarioError) as err:
            read_waypoints(MISSION, **{f"{kind}_path": path})
        assert (err.value.file, err.value.field) == (str(path), where), content
        assert reason in err.value.reason
