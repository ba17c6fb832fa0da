"""Geographic scenarios: lat/lon points, altitude references, a region polygon or a derived region, polygon prisms;
each mistake refused in one line naming its field."""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from planner.errors import ScenarioError
from planner.world.geographic import DEFAULT_REGION_MARGIN_M
from planner.world.polygons import contains
from planner.world.scenario import load_scenario

HOME = (47.3970, 8.5450, 488.0)  # lat, lon, alt AMSL
REGION = "[[47.3930, 8.5400], [47.3930, 8.5600], [47.4030, 8.5600], [47.4030, 8.5450], [47.3990, 8.5400]]"
GEO = f"""
name = "geo"
[home]
lat = {HOME[0]}
lon = {HOME[1]}
alt = {HOME[2]}
[region]
polygon = {REGION}
[altitude]
min = 30.0
max = 150.0
[route]
start = {{ lat = 47.3975, lon = 8.5430, alt = 60.0 }}
goal = {{ lat = 47.4010, lon = 8.5570, alt = 548.0, ref = "amsl" }}
[[prisms]]
name = "school"
polygon = [[47.3990, 8.5480], [47.3990, 8.5520], [47.4000, 8.5520], [47.4000, 8.5480]]
ceiling = 200.0
[[prisms]]
xy = [[300.0, -200.0], [400.0, -200.0], [400.0, -100.0], [350.0, -150.0], [300.0, -100.0]]
floor = 20.0
floor_ref = "ground"
ceiling = 700.0
ceiling_ref = "amsl"
[[cylinders]]
lat = 47.3960
lon = 8.5500
radius = 40.0
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "geo.toml"
    path.write_text(text)
    return path


def _en(lat: float, lon: float, origin: tuple[float, float, float]) -> np.ndarray:
    e, n, _ = pymap3d.geodetic2enu(lat, lon, origin[2], *origin)
    return np.array([e, n])


def test_a_region_polygon_puts_the_frame_at_its_south_west_corner_and_keeps_the_route_inside(tmp_path: Path) -> None:
    sc = load_scenario(_write(tmp_path, GEO))
    origin = (sc.home.lat, sc.home.lon, sc.home.alt)
    assert sc.home.alt == HOME[2]  # heights above home stay heights above the operator's home
    assert np.allclose(_en(47.3930, 8.5400, origin), 0.0, atol=0.01)  # the polygon's south-west corner
    env = sc.environment
    assert np.allclose([env.size_x, env.size_y], _en(47.4030, 8.5600, origin), atol=0.5)
    assert np.allclose(sc.launch, _en(HOME[0], HOME[1], origin), atol=0.01)  # home is inside, not at the corner
    assert np.allclose(sc.start, [*_en(47.3975, 8.5430, origin), 60.0], atol=0.01)
    assert sc.goal[2] == pytest.approx(60.0)  # 548 m AMSL over a home at 488 m
    prisms = env.prisms
    assert len(prisms) == 3 and list(prisms.keep_in) == [False, False, True]  # the region is the last, keep-in
    assert prisms.ceiling[0] == 200.0 and math.isinf(prisms.floor[0])
    assert prisms.floor[1] == 20.0 and prisms.ceiling[1] == pytest.approx(700.0 - HOME[2])  # flat ground: ref home
    # metres in a region scenario are metres from home: the second prism moved with the frame
    assert np.allclose(prisms.polygon(1).min(axis=0), np.array(sc.launch) + [300.0, -200.0], atol=0.05)
    cyl = env.cylinders
    assert np.allclose([cyl.x[0], cyl.y[0]], _en(47.3960, 8.5500, origin), atol=0.01)
    assert contains(prisms.polygon(2), sc.start[:2]) and contains(prisms.polygon(2), sc.goal[:2])


def test_a_derived_region_covers_every_input_with_the_margin(tmp_path: Path) -> None:
    text = GEO.replace(f"polygon = {REGION}", "margin_m = 250.0")
    sc = load_scenario(_write(tmp_path, text))
    env = sc.environment
    assert len(env.prisms) == 2 and not env.prisms.keep_in.any()
    lo = np.min(np.vstack([env.prisms.vertices, [sc.start[:2], sc.goal[:2], sc.launch],
                           [[env.cylinders.x[0] - 40.0, env.cylinders.y[0] - 40.0]]]), axis=0)
    assert np.allclose(lo, 250.0, atol=0.1)  # the frame's corner is the margin below the lowest input
    assert load_scenario(_write(tmp_path, text.replace("margin_m = 250.0", ""))).environment.size_x == \
        pytest.approx(env.size_x + 2 * (DEFAULT_REGION_MARGIN_M - 250.0))


def test_local_scenarios_take_lat_lon_points_about_their_corner_home(tmp_path: Path) -> None:
    text = f"""
[home]
lat = {HOME[0]}
lon = {HOME[1]}
alt = {HOME[2]}
[bounds]
x = 2000.0
y = 2000.0
[altitude]
min = 30.0
max = 150.0
[route]
start = [100.0, 100.0, 60.0]
goal = {{ lat = 47.4100, lon = 8.5650, alt = 80.0 }}
[[prisms]]
xy = [[500.0, 500.0], [900.0, 500.0], [700.0, 900.0]]
"""
    sc = load_scenario(_write(tmp_path, text))
    assert sc.launch == (0.0, 0.0) and sc.home.lat == HOME[0]
    assert np.allclose(sc.goal, [*_en(47.41, 8.565, HOME), 80.0], atol=0.01)
    assert np.allclose(sc.environment.prisms.polygon(0).min(axis=0), [500.0, 500.0])


@pytest.mark.parametrize(("edit", "field", "reason"), [
    (("[region]", "[bounds]\nx = 100.0\ny = 100.0\n[region]"), "region", "not both"),
    (("start = { lat = 47.3975,", "start = { lat = 97.3975,"), "route.start.lat", "outside [-90, 90]"),
    (("lon = 8.5430, alt = 60.0 }", "lon = 8.5430 }"), "route.start.alt", "needs alt"),
    (('ref = "amsl" }', 'ref = "agl" }'), "route.goal.ref", "not one of home, ground, amsl"),
    (("[47.4000, 8.5520], [47.4000, 8.5480]]", "[47.4000, 8.5480], [47.4000, 8.5520]]"), "prisms[0].xy",
     "intersects itself"),
    (("floor = 20.0\n", "floor = 800.0\n"), "prisms[1]", "must be below ceiling"),
    (("start = { lat = 47.3975, lon = 8.5430,", "start = { lat = 47.4020, lon = 8.5410,"), "route.start",
     "outside prisms[2] (keep-in polygon region.polygon"),
    (("start = { lat = 47.3975, lon = 8.5430,", "start = { lat = 47.3995, lon = 8.5500,"), "route.start",
     "inside prisms[0] (polygon school"),
    (("margin_m", "margin_m"), None, None),
])
def test_mistakes_are_one_line_naming_the_field(tmp_path: Path, edit: tuple[str, str], field: str | None,
                                                reason: str | None) -> None:
    old, new = edit
    assert old in GEO or old == "margin_m"
    if field is None:  # a region with both a polygon and a margin
        text = GEO.replace("[region]\n", "[region]\nmargin_m = 10.0\n")
        field, reason = "region.margin_m", "give polygon or margin_m"
    else:
        text = GEO.replace(old, new, 1)
    with pytest.raises(ScenarioError) as err:
        load_scenario(_write(tmp_path, text))
    assert err.value.field == field and reason in err.value.reason, str(err.value)
    assert "\n" not in str(err.value)


def test_the_documented_geographic_example_loads(tmp_path: Path, doc_toml: Callable[[str, str], str]) -> None:
    sc = load_scenario(_write(tmp_path, doc_toml("scenario_format.md", "## Geographic scenarios")))
    assert sc.name == "lakeside_geo" and len(sc.environment.prisms) == 2 and sc.environment.prisms.keep_in[-1]
    assert sc.goal[2] == pytest.approx(60.0)
