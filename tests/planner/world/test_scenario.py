"""Scenario loading: shipped files, each class of user mistake, overrides, random obstacles, the radar equation."""

from __future__ import annotations

import copy
import json
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from planner.bench.hardmaps import FAMILIES
from planner.errors import ScenarioError
from planner.world.config import HazardConfig, PlannerSettings, VehicleLimits
from planner.world.dem import synthetic_hills
from planner.world.environment import BOLTZMANN, radar_detection_range
from planner.world.scenario import Scenario, load_scenario

REPO = Path(__file__).resolve().parents[3]
SHIPPED = sorted((REPO / "sitl_scenarios").glob("*.toml"))

MINIMAL: dict[str, Any] = {
    "home": {"lat": -35.363261, "lon": 149.165230, "alt": 584.0},
    "bounds": {"x": 1000.0, "y": 1000.0},
    "altitude": {"min": 50.0, "max": 300.0},
    "route": {"start": [200.0, 200.0, 60.0], "goal": [800.0, 800.0, 60.0]},
    "cylinders": [{"x": 400.0, "y": 500.0, "radius": 80.0}],
}

RADAR_EQUATION = {"pt_w": 10.0, "gain": 1000.0, "wavelength_m": 0.03, "rcs_m2": 0.01, "ts_k": 500.0,
                  "bn_hz": 1.0e6, "loss": 4.0, "snr_threshold": 20.0}


def toml_value(value: Any) -> str:
    """Enough of a TOML writer for test scenarios: scalars, arrays and inline tables."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + "}"


def write_scenario(tmp_path: Path, edit: Callable[[dict[str, Any]], None] | None = None,
                   name: str = "case.toml") -> Path:
    """The minimal valid scenario, changed in place by ``edit``, written as TOML into ``tmp_path``."""
    data = copy.deepcopy(MINIMAL)
    if edit is not None:
        edit(data)
    path = tmp_path / name
    path.write_text("\n".join(f"{k} = {toml_value(v)}" for k, v in data.items()) + "\n")
    return path


def expect_error(path: Path, field: str, word: str, overrides: tuple[str, ...] = ()) -> ScenarioError:
    """Loading fails with a one-line ScenarioError naming the file, ``field`` and a reason containing ``word``."""
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, overrides)
    err = info.value
    text = str(err)
    assert "\n" not in text
    assert path.name in text
    assert err.field == field, text
    if field:
        assert f": {field}: " in text
    assert word.lower() in err.reason.lower(), text
    return err


def test_shipped_scenarios() -> None:
    assert {p.stem for p in SHIPPED} == {"rescue_static", "rescue_dynamic", "large_obstacle_field", "mountain_rescue",
                                         "crossing_traffic", "cmac_geo", *(f"hardmap_{f}_0" for f in FAMILIES)}


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_shipped_scenario_loads(path: Path) -> None:
    scenario = load_scenario(path)
    assert isinstance(scenario, Scenario)
    assert scenario.name == path.stem
    env = scenario.environment
    for point in (scenario.start, scenario.goal):
        assert 0 <= point[0] <= env.size_x and 0 <= point[1] <= env.size_y
        above = point[2] - float(env.ground(point[0], point[1]))
        assert env.z_min <= above <= env.z_max


def test_rescue_static_is_table_1() -> None:
    s = load_scenario(REPO / "sitl_scenarios" / "rescue_static.toml")
    cyl = s.environment.cylinders
    table_1 = [[400, 500, 100, 80], [600, 200, 150, 70], [500, 350, 150, 80], [350, 200, 150, 70],
               [700, 550, 150, 70], [650, 750, 150, 80]]
    assert np.column_stack([cyl.x, cyl.y, cyl.z_ref, cyl.radius]).tolist() == table_1
    assert np.all(np.isinf(cyl.top))
    assert (s.hazard.d_safe, s.hazard.d_coll) == (40.0, 10.0)
    assert s.start.tolist() == [200, 200, 50] and s.goal.tolist() == [800, 800, 50]
    assert (s.home.lat, s.home.lon, s.home.alt) == (-35.363261, 149.165230, 584.0)


def test_rescue_dynamic_threats_keep_paper_ratios() -> None:
    s = load_scenario(REPO / "sitl_scenarios" / "rescue_dynamic.toml")
    threats = {t.kind: t for t in s.environment.threats.items}
    ratio = s.vehicle.cruise_speed / 150.0
    assert threats["loiter"].speed == pytest.approx(40.0 * ratio)
    assert threats["patrol"].speed == pytest.approx(140.0 * ratio)
    assert threats["loiter"].p0 == (600.0, 560.0, 150.0) and threats["loiter"].circle_radius == 100.0
    assert threats["patrol"].p0 == (900.0, 650.0, 150.0) and threats["patrol"].p1 == (200.0, 200.0, 150.0)
    assert s.goal.tolist() == [800, 800, 150]
    (intruder,) = s.intruders
    assert intruder.speed == 15.0 and intruder.meet == (471.0, 729.0, 120.0) and intruder.radius == 40.0


def test_minimal_scenario_takes_dataclass_defaults(tmp_path: Path) -> None:
    s = load_scenario(write_scenario(tmp_path))
    assert s.vehicle == VehicleLimits()
    assert s.hazard == HazardConfig()
    assert s.planner == PlannerSettings()
    assert s.name == "case" and s.description == ""
    assert s.environment.terrain is None and len(s.environment.threats) == 0
    assert not s.start.flags.writeable


def test_documented_example_loads(tmp_path: Path, doc_toml: Callable[[str, str], str]) -> None:
    path = tmp_path / "example.toml"
    path.write_text(doc_toml("scenario_format.md", "## Full example"))
    s = load_scenario(path)
    assert len(s.environment.radars) == 2 and len(s.environment.threats) == 2
    assert s.environment.threats.direction.tolist() == [-1.0, 1.0]
    assert s.environment.threats.phase[0] == pytest.approx(math.pi / 2)


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    """An ``edit`` that sets ``a.b`` or ``a[0].b`` in the scenario dict."""
    def edit(data: dict[str, Any]) -> None:
        node: Any = data
        steps = [int(s) if s.isdigit() else s for s in re.split(r"[.\[\]]+", path) if s]
        for step in steps[:-1]:
            node = node.setdefault(step, {}) if isinstance(step, str) else node[step]
        node[steps[-1]] = value
    return edit


BAD_CASES = {
    "unknown top-level key": (_set("colour", "red"), "colour", "unknown"),
    "unknown nested key": (_set("planner.pso.n_pops", 10), "planner.pso.n_pops", "unknown"),
    "unknown key in a table section": (_set("route.via", [1.0, 2.0, 3.0]), "route.via", "unknown"),
    "unknown key in an array entry": (_set("cylinders[0].height", 5.0), "cylinders[0].height", "unknown"),
    "missing section": (lambda d: d.pop("route"), "route", "missing"),
    "string for a number": (_set("vehicle.cruise_speed", "18"), "vehicle.cruise_speed", "number"),
    "string for a number in a list": (_set("route.start", [200.0, "200", 60.0]), "route.start[1]", "number"),
    "float for an integer": (_set("planner.pso.n_pop", 100.0), "planner.pso.n_pop", "integer"),
    "wrong literal": (_set("vehicle.end_action", "hover"), "vehicle.end_action", "loiter"),
    "NaN": (_set("cylinders[0].radius", math.nan), "cylinders[0].radius", "finite"),
    "inf": (_set("route.goal", [math.inf, 800.0, 60.0]), "route.goal[0]", "finite"),
    "inf in a config dataclass": (_set("hazard.d_safe", math.inf), "hazard.d_safe", "finite"),
    "negative radius": (_set("cylinders[0].radius", -80.0), "cylinders[0].radius", "greater than 0"),
    "zero size": (_set("bounds.x", 0.0), "bounds.x", "greater than 0"),
    "negative speed": (_set("vehicle.cruise_speed", -5.0), "vehicle.cruise_speed", "> 0"),
    "zero sphere radius": (_set("spheres", [{"x": 1.0, "y": 2.0, "z": 3.0, "radius": 0.0}]), "spheres[0].radius",
                           "greater than 0"),
    "altitude band inverted": (_set("altitude.min", 300.0), "altitude.min", "below"),
    "dataclass post-init check": (_set("planner.pso.n_pop", 1), "planner.pso.n_pop", ">= 2"),
    "start inside a cylinder": (_set("route.start", [400.0, 500.0, 60.0]), "route.start", "inside cylinders[0]"),
    "start under a cylinder top": (
        lambda d: (_set("cylinders[0].top", 100.0)(d), _set("route.start", [400.0, 500.0, 60.0])(d)),
        "route.start", "inside cylinders[0]"),
    "start inside a sphere": (lambda d: d.update(spheres=[{"x": 200.0, "y": 210.0, "z": 70.0, "radius": 30.0}]),
                              "route.start", "inside spheres[0]"),
    "goal inside a hemisphere": (lambda d: d.update(hemispheres=[{"x": 800.0, "y": 800.0, "radius": 70.0}]),
                                 "route.goal", "inside hemispheres[0]"),
    "goal inside a radar range": (
        lambda d: d.update(radars=[{"x": 800.0, "y": 700.0, "z": 0.0, "r_det": 150.0}]),
        "route.goal", "inside radars[0]"),
    "goal outside bounds": (_set("route.goal", [1200.0, 800.0, 60.0]), "route.goal", "outside bounds"),
    "goal below zero": (_set("route.goal", [800.0, -3.0, 60.0]), "route.goal", "outside bounds"),
    "start below the altitude band": (_set("route.start", [200.0, 200.0, 20.0]), "route.start", "altitude band"),
    "start above the altitude band": (_set("route.start", [200.0, 200.0, 301.0]), "route.start", "altitude band"),
    "radar with r_det and equation": (
        lambda d: d.update(radars=[{"x": 0.0, "y": 900.0, "z": 0.0, "r_det": 100.0, **RADAR_EQUATION}]),
        "radars[0]", "not both"),
    "radar with neither": (lambda d: d.update(radars=[{"x": 0.0, "y": 900.0, "z": 0.0, "pt_w": 10.0}]),
                           "radars[0]", "missing gain"),
    "threat of unknown kind": (lambda d: d.update(threats=[{"id": "a", "kind": "orbit", "radius": 5.0}]),
                               "threats[0]", "kind"),
    "threat missing a key": (
        lambda d: d.update(threats=[{"id": "a", "kind": "patrol", "radius": 5.0, "a": [0.0, 0.0, 90.0],
                                     "speed": 3.0}]),
        "threats[0].b", "missing"),
    "duplicate ids": (
        lambda d: d.update(
            threats=[{"id": "x", "kind": "patrol", "radius": 5.0, "a": [0.0, 0.0, 90.0], "b": [9.0, 0.0, 90.0],
                      "speed": 3.0}],
            intruders=[{"id": "x", "icao": 1, "waypoints": [[0.0, 0.0, 90.0], [5.0, 5.0, 90.0]], "speed": 9.0}]),
        "intruders[0].id", "duplicate"),
    "intruder with one waypoint": (
        lambda d: d.update(intruders=[{"id": "i", "icao": 1, "waypoints": [[0.0, 0.0, 90.0]], "speed": 9.0}]),
        "intruders[0].waypoints", "at least 2"),
    "icao out of range": (
        lambda d: d.update(intruders=[{"id": "i", "icao": 0x1000000, "waypoints": [[0.0, 0.0, 9.0]] * 2,
                                       "speed": 9.0}]),
        "intruders[0].icao", "less than"),
    "random range reversed": (
        lambda d: d.update(random_obstacles={"seed": 1, "count": 3, "radius": [50.0, 10.0], "height": [1.0, 2.0]}),
        "random_obstacles.radius", "must not exceed"),
    "terrain file missing": (lambda d: d.update(terrain={"kind": "file", "path": "missing.asc"}), "terrain.path",
                             "cannot read"),
    "terrain file of unknown format": (lambda d: d.update(terrain={"kind": "file", "path": "dem.tif"}),
                                       "terrain.path", "unknown dem format"),
}


@pytest.mark.parametrize("case", list(BAD_CASES), ids=list(BAD_CASES))
def test_bad_scenario_is_reported(tmp_path: Path, case: str) -> None:
    edit, field, word = BAD_CASES[case]
    expect_error(write_scenario(tmp_path, edit), field, word)


def test_error_names_the_cylinder(tmp_path: Path) -> None:
    err = expect_error(write_scenario(tmp_path, _set("route.start", [420.0, 480.0, 60.0])), "route.start", "inside")
    assert err.reason == "inside cylinders[0] (x=400, y=500, r=80)"


def test_start_above_a_cylinder_top_is_allowed(tmp_path: Path) -> None:
    def edit(d: dict[str, Any]) -> None:
        d["cylinders"][0]["top"] = 100.0
        d["route"]["start"] = [400.0, 500.0, 120.0]

    assert load_scenario(write_scenario(tmp_path, edit)).start.tolist() == [400, 500, 120]


def test_altitude_band_follows_terrain(tmp_path: Path) -> None:
    hills = {"kind": "hills", "seed": 3, "count": 12, "max_height": 180.0, "sigma": [120.0, 300.0], "spacing": 25.0}
    terrain = synthetic_hills(1000.0, 1000.0, np.random.default_rng(3), 12, 180.0, (120.0, 300.0), 25.0)
    g_start, g_goal = float(terrain.height_at(500.0, 500.0)), float(terrain.height_at(800.0, 800.0))
    assert g_start > 1.0

    def edit(d: dict[str, Any]) -> None:
        d.update(terrain=hills, cylinders=[])
        d["route"] = {"start": [500.0, 500.0, g_start + 51.0], "goal": [800.0, 800.0, g_goal + 100.0]}

    path = write_scenario(tmp_path, edit)
    scenario = load_scenario(path)
    np.testing.assert_array_equal(scenario.environment.terrain.heights, terrain.heights)
    expect_error(path, "route.start", "altitude band", (f"route.start=[500, 500, {g_start + 49.0}]",))


def test_missing_file(tmp_path: Path) -> None:
    expect_error(tmp_path / "nope.toml", "", "not found")


def test_malformed_toml(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text('name = "x"\n[home]\nlat = \n')
    err = expect_error(path, "", "malformed")
    assert "line 3" in err.reason


def test_non_utf8_file(tmp_path: Path) -> None:
    path = tmp_path / "latin1.toml"
    path.write_bytes('name = "Zürich"\n'.encode("latin-1"))
    expect_error(path, "", "utf-8")


def test_overrides_change_values(tmp_path: Path) -> None:
    path = write_scenario(tmp_path)
    s = load_scenario(path, ["planner.pso.n_pop=100", "hazard.d_coll=20", "planner.seed=3", "vehicle.type=copter",
                             "cylinders[0].radius=90", "route.goal=[800, 800, 120]", 'name="renamed"'])
    assert s.planner.pso.n_pop == 100
    assert s.hazard.d_coll == 20.0
    assert s.planner.seed == 3
    assert s.vehicle.type == "copter"
    assert s.environment.cylinders.radius.tolist() == [90.0]
    assert s.goal.tolist() == [800, 800, 120]
    assert s.name == "renamed"
    assert load_scenario(path).planner.pso.n_pop == PlannerSettings().pso.n_pop  # file itself unchanged


@pytest.mark.parametrize("override", ["planner.seed", "=3", "planner..seed=3", "planner.seed=", "pla net.seed=3",
                                      "cylinders[5].radius=3", "bounds.x.sub=1", "cylinders.x=1"])
def test_bad_override_syntax(tmp_path: Path, override: str) -> None:
    expect_error(write_scenario(tmp_path), "--set", "", (override,))


def test_override_with_unknown_key(tmp_path: Path) -> None:
    expect_error(write_scenario(tmp_path), "planner.pso.bogus", "unknown", ("planner.pso.bogus=1",))


def test_override_bare_word_for_number_is_rejected(tmp_path: Path) -> None:
    expect_error(write_scenario(tmp_path), "hazard.d_coll", "number", ("hazard.d_coll=twenty",))


def _random_field(tmp_path: Path, seed: int) -> Scenario:
    spec = {"seed": seed, "count": 40, "kinds": ["sphere", "cylinder", "hemisphere"], "radius": [20.0, 60.0],
            "height": [60.0, 250.0], "clearance": 100.0}
    return load_scenario(write_scenario(tmp_path, lambda d: d.update(random_obstacles=spec, cylinders=[]),
                                        name=f"rand{seed}.toml"))


def test_random_obstacles_are_deterministic(tmp_path: Path) -> None:
    a, b, c = _random_field(tmp_path, 7), _random_field(tmp_path, 7), _random_field(tmp_path, 8)
    ea, eb, ec = a.environment, b.environment, c.environment
    assert len(ea.cylinders) + len(ea.spheres) == 40
    np.testing.assert_array_equal(ea.spheres.center, eb.spheres.center)
    np.testing.assert_array_equal(ea.spheres.radius, eb.spheres.radius)
    np.testing.assert_array_equal(ea.cylinders.x, eb.cylinders.x)
    assert not (len(ea.spheres) == len(ec.spheres) and np.array_equal(ea.spheres.center, ec.spheres.center))


def test_random_obstacles_keep_start_and_goal_clear(tmp_path: Path) -> None:
    env = _random_field(tmp_path, 11).environment
    for point in (np.array([200.0, 200.0, 60.0]), np.array([800.0, 800.0, 60.0])):
        cyl_gap = np.hypot(env.cylinders.x - point[0], env.cylinders.y - point[1]) - env.cylinders.radius
        sph_gap = np.linalg.norm(env.spheres.center - point, axis=1) - env.spheres.radius
        assert cyl_gap.min(initial=np.inf) >= 100.0 and sph_gap.min(initial=np.inf) >= 100.0
    hemispheres = env.spheres.center[:, 2] == 0.0
    assert np.all((env.spheres.center[~hemispheres, 2] >= 60.0) & (env.spheres.center[~hemispheres, 2] <= 250.0))
    assert np.all((env.spheres.radius >= 20.0) & (env.spheres.radius <= 60.0))


def test_unplaceable_random_obstacles(tmp_path: Path) -> None:
    spec = {"seed": 1, "count": 1, "kinds": ["cylinder"], "radius": [400.0, 500.0], "height": [1.0, 2.0],
            "clearance": 400.0}
    expect_error(write_scenario(tmp_path, lambda d: d.update(random_obstacles=spec)), "random_obstacles", "clear")


def test_radar_equation_range_has_threshold_snr(tmp_path: Path) -> None:
    p = RADAR_EQUATION
    r_det = radar_detection_range(**p)
    snr = (p["pt_w"] * p["gain"] ** 2 * p["wavelength_m"] ** 2 * p["rcs_m2"]
           / ((4 * math.pi) ** 3 * BOLTZMANN * p["ts_k"] * p["bn_hz"] * p["loss"] * r_det**4))
    assert snr == pytest.approx(p["snr_threshold"], rel=1e-9)
    radar = {"x": 0.0, "y": 1000.0, "z": 0.0, **p}
    s = load_scenario(write_scenario(tmp_path, lambda d: d.update(radars=[radar])))
    assert s.environment.radars.r_det.tolist() == pytest.approx([r_det])
    assert s.environment.radars.soft_weight.tolist() == [1.0]


def test_esri_terrain_path_is_relative_to_the_scenario(tmp_path: Path) -> None:
    (tmp_path / "dem").mkdir()
    rows = np.full((3, 3), 600.0)
    header = "ncols 3\nnrows 3\nxllcorner -500\nyllcorner -500\ncellsize 1000\n"
    (tmp_path / "dem" / "flat.asc").write_text(header + "\n".join(" ".join(map(str, r)) for r in rows))
    s = load_scenario(write_scenario(tmp_path, lambda d: d.update(terrain={"kind": "file", "path": "dem/flat.asc"}),
                                     name="with_dem.toml"), ["route.start=[200, 200, 80]", "route.goal=[800,800,80]"])
    assert float(s.environment.ground(300.0, 300.0)) == pytest.approx(16.0)


def test_esri_terrain_errors_name_the_field(tmp_path: Path) -> None:
    header = "ncols 2\nnrows 2\nxllcorner 0\nyllcorner 0\ncellsize 1000\nNODATA_value -9999\n"
    (tmp_path / "holes.asc").write_text(header + "1 2\n-9999 4\n")
    path = write_scenario(tmp_path, lambda d: d.update(terrain={"kind": "file", "path": "holes.asc"}))
    expect_error(path, "terrain.path", "nodata")


def test_scenario_text_loads_where_its_folder_is_gone(tmp_path: Path) -> None:
    """A run on a cluster worker gets the scenario as text with the DEM it names (planner.world.scenario_text):
    loaded after the folder is deleted it is the same scenario, terrain included."""
    import shutil

    from planner.world.scenario_text import ScenarioText, materialise

    folder = tmp_path / "site"
    (folder / "dem").mkdir(parents=True)
    header = "ncols 3\nnrows 3\nxllcorner -500\nyllcorner -500\ncellsize 1000\n"
    (folder / "dem" / "slope.asc").write_text(header + "590 595 600\n602 605 608\n610 612 615\n")
    sets = ["route.start=[200, 200, 80]", "route.goal=[800,800,80]"]
    path = write_scenario(folder, lambda d: d.update(terrain={"kind": "file", "path": "dem/slope.asc"}),
                          name="with_dem.toml")
    here = load_scenario(path, sets)
    text = ScenarioText.read(path, sets)
    assert [(key, name) for key, name, _ in text.named] == [("terrain.path", "slope.asc")]
    shutil.rmtree(folder)
    copy_path, extra = materialise(text)
    there = load_scenario(copy_path, [*sets, *extra])
    assert there.name == here.name == "with_dem"
    assert copy_path.parent != folder and copy_path.name == "with_dem.toml"
    for x, y in ((300.0, 300.0), (-400.0, 900.0), (750.0, 10.0)):
        assert float(there.environment.ground(x, y)) == float(here.environment.ground(x, y))
    assert materialise(text) == (copy_path, extra)  # once per process and content
