"""An operator's mission as a scenario: written as TOML, loaded and checked like any scenario file."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pymap3d
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
    return OperatorMission(Path("/somewhere/rescue.plan"), **{**base, **kw})  # type: ignore[arg-type]  # fields from a dict of mixed values


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


def test_the_missions_intermediate_places_are_vias_in_order(tmp_path: Path) -> None:
    """Each position between the start and the goal is a via where the operator set it; one without an altitude is
    flown at the start's height."""
    vias = (GeoPoint(47.398, 8.55, Altitude(50.0)), GeoPoint(47.4, 8.556), GeoPoint(47.3995, 8.545,
                                                                                       Altitude(550.0, "amsl")))
    sc = _load(tmp_path, scenario_text(_mission(vias=vias)))
    e, n, _ = pymap3d.geodetic2enu([47.398, 47.4, 47.3995], [8.55, 8.556, 8.545], sc.home.alt, sc.home.lat,
                                   sc.home.lon, sc.home.alt)
    assert np.allclose(sc.vias, np.column_stack([e, n, [50.0, 50.0, 62.0]]), atol=0.01)
    assert len(_load(tmp_path, scenario_text(_mission(vias=()))).vias) == 0


def test_the_vehicles_mission_gives_the_goal_and_the_vias(tmp_path: Path) -> None:
    """--goal-from-vehicle: the last place of the vehicle's mission is the goal, the places before it the vias (in
    place of the base scenario's own)."""
    from planner.world.sources import vehicle_scenario

    base = tmp_path / "base.toml"
    static = Path(__file__).resolve().parents[3] / "sitl_scenarios" / "rescue_static.toml"
    base.write_text(static.read_text().replace("goal = [800.0, 800.0, 50.0]",
                                               "goal = [800.0, 800.0, 50.0]\nvias = [[900.0, 100.0, 60.0]]"))
    home = load_scenario(static).home
    places = [(250.0, 550.0, 60.0), (550.0, 850.0, 70.0), (800.0, 800.0, 55.0)]
    lat, lon, _ = pymap3d.enu2geodetic(*np.array(places).T[:2], 0.0, home.lat, home.lon, home.alt)
    points = [GeoPoint(float(a), float(o), Altitude(p[2])) for a, o, p in zip(lat, lon, places, strict=True)]
    world = OperatorMission(Path("udpin:vehicle"), home=None, goal=points[-1], vias=tuple(points[:-1]))
    sc = load_scenario(vehicle_scenario(base, world, fence=False, goal=True, beside=tmp_path / "flight"))
    assert np.allclose(sc.vias, places[:2], atol=0.01) and np.allclose(sc.goal, places[2], atol=0.01)
