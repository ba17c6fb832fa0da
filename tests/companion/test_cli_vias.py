"""A ground station's intermediate waypoints are vias (issue 35): ``fuseplan plan MISSION.plan`` routes through each
of them in order, feasibly, and ``-o SAFE.plan`` has each as a mission item; a via inside a fence's exclusion zone is
one line, exit 2, and no plan written; the same seed plans the same route."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pymap3d
import pytest

from companion.cli import main
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "tests" / "data" / "imports" / "cmac_vias.plan"  # cmac_fenced.plan with two waypoints before its goal
WGS84 = pymap3d.Ellipsoid.from_name("wgs84")


def _vias_of_the_file() -> list[tuple[float, float, float]]:
    """(lat, lon, alt above home) of the mission's waypoints before its last."""
    items = json.loads(MISSION.read_text())["mission"]["items"]
    places = [it["params"][4:7] for it in items if it["command"] == 16]
    return [tuple(p) for p in places[:-1]]


def _local(lat: float, lon: float, alt: float, sc: object) -> np.ndarray:
    e, n, _ = pymap3d.geodetic2enu(lat, lon, sc.home.alt, sc.home.lat, sc.home.lon, sc.home.alt, ell=WGS84)
    return np.array([e, n, alt])


@pytest.fixture(scope="module")
def planned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("vias")
    assert main(["plan", str(MISSION), "-o", str(out / "PLAN.json"), "-q"]) == 0
    return out, json.loads((out / "PLAN.json").read_text())


def test_the_route_passes_through_both_vias_and_is_feasible(planned: tuple[Path, dict]) -> None:
    out, doc = planned
    sc = load_scenario(out / "PLAN.scenario.toml")
    assert len(sc.vias) == 2 and doc["status"] == "exact" and not any(doc["violations"].values())
    waypoints = np.asarray(doc["waypoints"])
    at = []
    for (lat, lon, alt), via in zip(_vias_of_the_file(), doc["vias"], strict=True):
        d = np.linalg.norm(waypoints - _local(lat, lon, alt, sc), axis=1)
        assert d.min() < 1.0
        at.append(int(d.argmin()))
        assert (via["lat"], via["lon"], via["alt_above_home"]) == pytest.approx((lat, lon, alt), abs=1e-6)
    assert 0 < at[0] < at[1] < len(waypoints) - 1


def test_the_safe_plan_has_each_via_as_a_mission_item(planned: tuple[Path, dict], tmp_path: Path) -> None:
    safe = tmp_path / "SAFE.plan"
    assert main(["plan", str(MISSION), "-o", str(safe), "-q"]) == 0
    sc = load_scenario(tmp_path / "SAFE.scenario.toml")
    items = [it for it in json.loads(safe.read_text())["mission"]["items"] if it["command"] == 16]
    places = np.array([_local(*it["params"][4:7], sc) for it in items])
    for lat, lon, alt in _vias_of_the_file():
        assert np.linalg.norm(places - _local(lat, lon, alt, sc), axis=1).min() < 1.0
    _, doc = planned  # the same seed, the same route: the plan's waypoints are the file's
    assert np.allclose(places[-len(doc["waypoints"]):], doc["waypoints"], atol=0.05)


def test_a_via_inside_an_exclusion_zone_is_one_line_and_exit_2_with_nothing_written(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plan = json.loads(MISSION.read_text())
    via = next(it for it in plan["mission"]["items"] if it["command"] == 16)
    square = plan["geoFence"]["polygons"][1]["polygon"]  # an exclusion polygon
    via["params"][4:6] = list(np.mean(square, axis=0).round(7))
    bad = tmp_path / "bad.plan"
    bad.write_text(json.dumps(plan))
    safe = tmp_path / "SAFE.plan"
    assert main(["plan", str(bad), "-o", str(safe), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "route.vias[0]: inside prisms[0] (polygon geoFence.polygons[1]" in err, err
    assert "Traceback" not in err and not safe.exists() and not (tmp_path / "SAFE.plan.part").exists()


def test_a_plan_that_skips_a_via_is_not_exported(planned: tuple[Path, dict], tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    out, doc = planned
    sc = load_scenario(out / "PLAN.scenario.toml")
    skipped = dict(doc, waypoints=[w for w in doc["waypoints"] if np.linalg.norm(np.subtract(w, sc.vias[1])) > 1.0])
    path = tmp_path / "skipped.json"
    path.write_text(json.dumps(skipped))
    assert main(["export", str(path), "--format", "plan", "-o", str(tmp_path / "x.plan")]) == 2
    err = capsys.readouterr().err
    assert "does not pass through route.vias[1]" in err and not (tmp_path / "x.plan").exists()
    assert main(["export", str(out / "PLAN.json"), "--format", "plan", "-o", str(tmp_path / "y.plan")]) == 0
