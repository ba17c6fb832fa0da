"""``route.vias`` (issue 35): points the route passes through, given as ``goal`` is (metres, or lat/lon with an
altitude reference) and refused in one line as a bad goal is: inside an obstacle, outside the bounds, keep-in
polygon or altitude band, or too close to the point before it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import pytest

from planner.errors import ScenarioError
from planner.world.scenario import load_scenario

REPO = Path(__file__).resolve().parents[3]
STATIC = REPO / "sitl_scenarios" / "rescue_static.toml"
GEO = """
name = "geo"
[home]
lat = 47.3970
lon = 8.5450
alt = 488.0
[region]
polygon = [[47.3930, 8.5400], [47.3930, 8.5600], [47.4030, 8.5600], [47.4030, 8.5450], [47.3990, 8.5400]]
[altitude]
min = 30.0
max = 150.0
[route]
start = { lat = 47.3975, lon = 8.5430, alt = 60.0 }
goal = { lat = 47.4010, lon = 8.5570, alt = 548.0, ref = "amsl" }
vias = [{ lat = 47.3985, lon = 8.5460, alt = 70.0 }, VIA2]
[[prisms]]
name = "school"
polygon = [[47.3990, 8.5480], [47.3990, 8.5520], [47.4000, 8.5520], [47.4000, 8.5480]]
ceiling = 200.0
"""


def test_vias_in_metres_are_kept_in_order() -> None:
    sc = load_scenario(STATIC, ["route.vias=[[250, 550, 60], [550, 850, 70]]"])
    assert sc.vias.tolist() == [[250.0, 550.0, 60.0], [550.0, 850.0, 70.0]]
    assert not sc.vias.flags.writeable
    assert load_scenario(STATIC).vias.shape == (0, 3)  # none: an empty (0, 3) array


def test_geographic_vias_take_lat_lon_and_altitude_references(tmp_path: Path) -> None:
    path = tmp_path / "geo.toml"
    path.write_text(GEO.replace("VIA2", '{ lat = 47.4005, lon = 8.5540, alt = 40.0, ref = "ground" }'))
    sc = load_scenario(path)
    e, n, _ = pymap3d.geodetic2enu(47.3985, 8.5460, sc.home.alt, sc.home.lat, sc.home.lon, sc.home.alt)
    assert np.allclose(sc.vias[0], [e, n, 70.0], atol=0.01)
    assert sc.vias[1][2] == pytest.approx(40.0)  # flat ground: above ground is above home


@pytest.mark.parametrize(("via2", "field", "reason"), [
    ("{ lat = 47.3995, lon = 8.5500, alt = 60.0 }", "route.vias[1]", "inside prisms[0] (polygon school"),
    ("{ lat = 47.4020, lon = 8.5410, alt = 60.0 }", "route.vias[1]", "outside prisms[1] (keep-in polygon"),
    ("{ lat = 47.4005, lon = 8.5540, alt = 10.0 }", "route.vias[1]", "outside the altitude band"),
    ("{ lat = 47.4005, lon = 8.5540 }", "route.vias[1].alt", "required key is missing"),
    ("{ lat = 47.4005, lon = 8.5540, alt = 60.0, ref = \"agl\" }", "route.vias[1].ref", "'agl' is not one of"),
    ("{ lat = 47.39851, lon = 8.54601, alt = 70.0 }", "route.vias[1]", "at least 10 m from route.vias[0]"),
])
def test_a_bad_via_is_one_line_naming_it(tmp_path: Path, via2: str, field: str, reason: str) -> None:
    path = tmp_path / "geo.toml"
    path.write_text(GEO.replace("VIA2", via2))
    with pytest.raises(ScenarioError) as err:
        load_scenario(path)
    assert err.value.field == field and reason in err.value.reason, str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize(("vias", "field", "reason"), [
    ("[[400, 500, 60]]", "route.vias[0]", "inside cylinders[0]"),
    ("[[500, 1300, 60]]", "route.vias[0]", "outside bounds"),
    ("[[205, 200, 50]]", "route.vias[0]", "at least 10 m from route.start"),
    ("[[800, 805, 50]]", "route.goal", "at least 10 m from route.vias[0]"),
    ("[[500, 300]]", "route.vias[0]", "at least 3 items"),
])
def test_a_bad_via_in_metres_is_one_line_naming_it(vias: str, field: str, reason: str) -> None:
    with pytest.raises(ScenarioError) as err:
        load_scenario(STATIC, [f"route.vias={vias}"])
    assert err.value.field == field and reason in err.value.reason, str(err.value)
