"""``--zones`` with airspace as operators get it (OpenAIP, ED-269) from the command line: a bad file is one line
naming the file, the zone and the reason, exit 2 and nothing written; an ED-269 prohibited zone across the straight
route is planned round, and a NO_RESTRICTION zone is skipped with a warning."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from companion.cli import main
from planner.world.geometry import segment_prism_clearance
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
CMAC_GEO = ROOT / "sitl_scenarios" / "cmac_geo.toml"
DATA = ROOT / "tests" / "data" / "imports"


def _ed269_square(path: Path, restriction: str = "PROHIBITED", **volume: object) -> Path:
    """An ED-269 file with one square zone, 80 m a side, centred 1050 m east and 640 m north of cmac_geo's home: on
    the straight line from its start to its goal, clear of its other zones; 0-400 ft above ground (over the band)."""
    base = load_scenario(CMAC_GEO)
    corners = [(1010.0, 600.0), (1090.0, 600.0), (1090.0, 680.0), (1010.0, 680.0), (1010.0, 600.0)]
    ring = []
    for east, north in corners:
        lat, lon, _ = pymap3d.enu2geodetic(east, north, 0.0, base.home.lat, base.home.lon, base.home.alt)
        ring.append([float(lon), float(lat)])
    path.write_text(json.dumps({"features": [
        {"identifier": "T-P1", "name": "Substation", "restriction": restriction, "geometry": [
            {"uomDimensions": "FT", "lowerLimit": 0, "lowerVerticalReference": "AGL", "upperLimit": 400,
             "upperVerticalReference": "AGL", "horizontalProjection": {"type": "Polygon", "coordinates": [ring]},
             **volume}]},
        {"identifier": "T-I1", "name": "Park information", "restriction": "NO_RESTRICTION", "geometry": [
            {"uomDimensions": "M", "upperLimit": 120, "upperVerticalReference": "AGL",
             "horizontalProjection": {"type": "Circle", "center": [149.17, -35.36], "radius": 50}}]}]}))
    return path


@pytest.mark.parametrize(("make", "line"), [
    (lambda tmp: DATA / "cmac_openaip_bad_unit.json",
     "items[1] 'R405 MAJURA' lowerLimit: unit 7 is not metres (0), feet (1) or a flight level (6)"),
    (lambda tmp: _ed269_square(tmp / "zones.json", upperVerticalReference="WGS84"),
     "features[0] 'Substation' geometry[0].upperVerticalReference: WGS84 heights (above the ellipsoid) are not read"),
    (lambda tmp: _ed269_square(tmp / "zones.json", uomDimensions="NM"),
     "features[0] 'Substation' geometry[0].uomDimensions: 'NM' is not M or FT"),
], ids=["openaip-unit", "ed269-wgs84", "ed269-uom"])
def test_a_bad_airspace_file_is_one_line_and_exit_2_with_nothing_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], make, line: str) -> None:
    zones = make(tmp_path)
    out = tmp_path / "x.json"
    assert main(["plan", str(CMAC_GEO), "--zones", str(zones), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{zones}: {line}" in err, err
    assert "Traceback" not in err and not out.exists() and not (tmp_path / "x.scenario.toml").exists()


def test_an_ed269_prohibited_zone_across_the_route_is_planned_round(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The zone becomes one more prism of the scenario written beside the plan, between 0 and 121.92 m above the
    ground (400 ft); the route is feasible and keeps d_coll from it; the NO_RESTRICTION zone adds nothing."""
    zones = _ed269_square(tmp_path / "geozones.json")
    out = tmp_path / "PLAN.json"
    base = load_scenario(CMAC_GEO)
    with caplog.at_level(logging.WARNING, logger="planner.world.imports.airspace"):
        assert main(["plan", str(CMAC_GEO), "--zones", str(zones), "-o", str(out), "-q"]) == 0
    assert [r.getMessage() for r in caplog.records if "NO_RESTRICTION" in r.getMessage()] == [
        f"{zones}: features[1] 'Park information': restriction NO_RESTRICTION is informational: not a no-fly zone, "
        "skipped"]
    doc = json.loads(out.read_text())
    assert doc["status"] == "exact" and not any(doc["violations"].values()), doc["violations"]
    sc = load_scenario(doc["scenario_file"])
    prisms = sc.environment.prisms
    assert len(prisms) == len(base.environment.prisms) + 1 and len(sc.environment.cylinders) == 1
    (k,) = [k for k in range(len(prisms)) if np.allclose(prisms.polygon(k).mean(axis=0), [1050.0, 640.0], atol=1.0)]
    assert prisms.ceiling[k] == pytest.approx(400 * 0.3048)  # no terrain: above ground is above home
    assert segment_prism_clearance(sc.start, sc.goal, prisms)[k] < 0.0  # the straight route goes through it
    route = np.asarray(doc["trajectory"]["points"])
    clearance = segment_prism_clearance(route[:-1], route[1:], prisms)[k]
    assert clearance.min() >= sc.hazard.d_coll, clearance.min()
