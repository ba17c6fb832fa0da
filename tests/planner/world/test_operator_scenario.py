"""An operator's mission as a scenario: written as TOML, loaded and checked like any scenario file."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from planner.errors import ScenarioError
from planner.world import toml_text
from planner.world.geo_inputs import Altitude, GeoPoint, OperatorMission, Zone
from planner.world.operator_scenario import BAND_ABOVE_M, BAND_BELOW_M, OPERATOR_HAZARD, operator_raw, scenario_text
from planner.world.polygons import contains
from planner.world.scenario import load_scenario

HOME = GeoPoint(47.397, 8.545, Altitude(488.0, "amsl"))
FENCE = (
    Zone("geoFence.polygons[0]", True, polygon=((47.393, 8.540), (47.393, 8.560), (47.403, 8.560), (47.403, 8.540))),
    Zone("geoFence.polygons[1]", polygon=((47.399, 8.548), (47.399, 8.552), (47.400, 8.552), (47.400, 8.548))),
    Zone("geoFence.circles[0]", centre=(47.396, 8.550), radius_m=40.0),
)
AIRSPACE = Zone("features[0]", centre=(47.3995, 8.554), radius_m=50.0, floor=Altitude(100.0, "amsl"),
                ceiling=Altitude(800.0, "amsl"))


def _mission(**kw: object) -> OperatorMission:
    base = {"home": HOME, "goal": GeoPoint(47.401, 8.557, Altitude(60.0)), "vias": (GeoPoint(47.398, 8.55,
            Altitude(50.0)),), "zones": FENCE, "extras": {"vehicle_type": 1}}
    return OperatorMission(Path("/somewhere/rescue.plan"), **{**base, **kw})  # type: ignore[arg-type]


def _load(tmp_path: Path, text: str) -> object:
    path = tmp_path / "rescue.scenario.toml"
    path.write_text(text)
    return load_scenario(path)


def test_a_mission_becomes_a_scenario_with_its_fence_and_zones(tmp_path: Path) -> None:
    sc = _load(tmp_path, scenario_text(_mission(), zones=(AIRSPACE,)))
    env = sc.environment
    assert (sc.name, sc.vehicle.type, sc.hazard.d_coll) == ("rescue", "plane", OPERATOR_HAZARD["d_coll"])
    assert (env.z_min, env.z_max) == (50.0 - BAND_BELOW_M, 60.0 + BAND_ABOVE_M)  # around the mission's heights
    # the start is home at the first item's height; the goal as given; both inside the inclusion fence
    assert np.allclose(sc.start[:2], sc.launch) and sc.start[2] == 50.0 and sc.goal[2] == 60.0
    prisms = env.prisms
    assert list(prisms.keep_in) == [False, False, True] and len(env.cylinders) == 1
    assert contains(prisms.polygon(2), sc.goal[:2])
    # an airspace circle with a floor is a polygon around the circle (never smaller), between its heights
    ring = prisms.polygon(1)
    centre = ring.mean(axis=0)
    assert np.all(np.hypot(*(ring - centre).T) >= 50.0) and np.all(np.hypot(*(ring - centre).T) < 50.0 / math.cos(
        math.pi / 32) + 0.05)
    assert prisms.floor[1] == pytest.approx(100.0 - 488.0) and prisms.ceiling[1] == pytest.approx(800.0 - 488.0)


def test_a_base_scenario_gives_vehicle_band_and_settings(tmp_path: Path) -> None:
    base = {"vehicle": {"type": "copter", "cruise_speed": 10.0}, "altitude": {"min": 40.0, "max": 90.0},
            "hazard": {"d_coll": 5.0, "d_safe": 15.0}, "planner": {"seed": 7}}
    sc = _load(tmp_path, scenario_text(_mission(), base))
    assert (sc.vehicle.type, sc.vehicle.cruise_speed, sc.environment.z_min, sc.hazard.d_coll, sc.planner.seed) == \
        ("copter", 10.0, 40.0, 5.0, 7)


@pytest.mark.parametrize(("mission", "field", "reason"), [
    (_mission(home=None, start=None), "home", "no home"),
    (_mission(goal=None), "goal", "no navigation item"),
    (_mission(zones=(*FENCE, Zone("geoFence.circles[1]", True, centre=(47.4, 8.55), radius_m=900.0))),
     "geoFence.circles[1]", "a second inclusion zone"),
])
def test_a_mission_that_cannot_be_planned_is_refused_naming_what(mission: OperatorMission, field: str,
                                                                 reason: str) -> None:
    with pytest.raises(ScenarioError) as err:
        operator_raw(mission)
    assert err.value.field == field and reason in err.value.reason and "rescue.plan" in str(err.value)


def test_toml_text_round_trips_what_scenarios_hold() -> None:
    raw = {"name": 'a "quoted" name', "home": {"lat": 1.5, "lon": -2.0, "alt": 3.0}, "flag": True,
           "route": {"start": {"lat": 1.0, "lon": 2.0, "alt": 3.0, "ref": "amsl"}, "goal": [1.0, 2.0, 3.0]},
           "prisms": [{"xy": [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], "name": "é"}, {"xy": [[5, 5]], "skip": None}],
           "planner": {"pso": {"n_pop": 10}}}
    back = tomllib.loads(toml_text.dumps(raw, "made here\nfor a test"))
    raw["prisms"][1].pop("skip")
    assert back == raw
    with pytest.raises(ValueError, match="no TOML form"):
        toml_text.dumps({"top": math.inf})
