"""``--zones FILE.geojson`` from the command line (issue 35): a file with a feature that is not a polygon or a
point, a polygon that crosses itself, or a floor above its ceiling is refused in one line naming the file, the
feature and the reason, with exit 2 and nothing written; good zones are planned round."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.cli import main

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
SQUARE = [[149.1700, -35.3600], [149.1710, -35.3600], [149.1710, -35.3590], [149.1700, -35.3590], [149.1700, -35.3600]]


def _zones(path: Path, geometry: dict, **props: object) -> Path:
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "ok", "floor_m": 0, "ceiling_m": 500}, "geometry": {
            "type": "Polygon", "coordinates": [SQUARE]}},
        {"type": "Feature", "properties": {"name": "bad", **props}, "geometry": geometry}]}))
    return path


@pytest.mark.parametrize(("geometry", "props", "reason"), [
    ({"type": "LineString", "coordinates": SQUARE[:2]}, {}, "LineString"),
    ({"type": "Polygon", "coordinates": [[SQUARE[0], SQUARE[2], SQUARE[1], SQUARE[3], SQUARE[0]]]}, {},
     "intersects itself"),
    ({"type": "Polygon", "coordinates": [SQUARE]}, {"floor_m": 300, "ceiling_m": 100}, "floor"),
])
def test_a_bad_zones_file_is_one_line_and_exit_2_with_nothing_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], geometry: dict, props: dict, reason: str) -> None:
    zones = _zones(tmp_path / "zones.geojson", geometry, **props)
    out = tmp_path / "PLAN.json"
    assert main(["plan", str(STATIC), "--zones", str(zones), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(zones) in err and "features[1]" in err and reason in err, err
    assert "Traceback" not in err and not out.exists() and not (tmp_path / "PLAN.scenario.toml").exists()


def test_zones_from_a_geojson_file_are_planned_round(tmp_path: Path) -> None:
    """A point with a radius becomes one more cylinder of the scenario written beside the plan, and the route keeps
    d_coll from it."""
    import numpy as np
    import pymap3d

    from planner.world.scenario import load_scenario

    base = load_scenario(STATIC)
    mid = (base.start + base.goal) / 2  # on the straight line: the route must bend round it
    lat, lon, _ = pymap3d.enu2geodetic(mid[0], mid[1], 0.0, base.home.lat, base.home.lon, base.home.alt)
    zones = tmp_path / "zones.geojson"
    zones.write_text(json.dumps({"type": "FeatureCollection", "features": [
        {"type": "Feature", "properties": {"name": "hospital pad", "radius_m": 30},
         "geometry": {"type": "Point", "coordinates": [float(lon), float(lat)]}}]}))
    out = tmp_path / "PLAN.json"
    assert main(["plan", str(STATIC), "--zones", str(zones), "-o", str(out), "-q"]) == 0
    doc = json.loads(out.read_text())
    assert doc["scenario_file"] == str(tmp_path / "PLAN.scenario.toml")
    sc = load_scenario(doc["scenario_file"])
    cyl = sc.environment.cylinders
    assert len(cyl) == len(base.environment.cylinders) + 1
    assert np.allclose([cyl.x[-1], cyl.y[-1], cyl.radius[-1]], [mid[0], mid[1], 30.0], atol=0.01)
    route = np.asarray(doc["trajectory"]["points"])
    assert np.min(np.hypot(route[:, 0] - mid[0], route[:, 1] - mid[1])) - 30.0 >= sc.hazard.d_coll
