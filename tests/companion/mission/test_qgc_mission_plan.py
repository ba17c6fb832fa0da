"""Issue 35's check on a QGroundControl mission: an inclusion polygon, three exclusion polygons (one concave), one
exclusion circle and a goal, planned with ``fuseplan plan MISSION.plan``. The route is feasible and keeps d_coll
from every polygon edge by a measure of its own (dense points along the edges), and the written ``SAFE.plan``
loads in MAVSDK's QGroundControl importer with the operator's fence and rally point."""

from __future__ import annotations

import asyncio
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pymap3d
import pytest

from companion.cli import main
from planner.world.imports import read_qgc_plan
from planner.world.polygons import contains
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
MISSION = ROOT / "tests" / "data" / "imports" / "cmac_fenced.plan"


def _boundary_distance(ring: np.ndarray, points: np.ndarray, step: float = 0.25) -> np.ndarray:
    """Distance from each point to the ring's edges, by points every ``step`` m along them (the test's own
    measure, not the planner's geometry)."""
    closed = np.vstack([ring, ring[:1]])
    dense = np.concatenate([a + np.linspace(0.0, 1.0, max(2, int(np.linalg.norm(b - a) / step) + 1))[:, None] * (b - a)
                            for a, b in zip(closed[:-1], closed[1:], strict=True)])
    out = np.full(len(points), np.inf)
    for chunk in range(0, len(dense), 2000):
        d = np.linalg.norm(points[:, None, :] - dense[None, chunk:chunk + 2000], axis=-1)
        out = np.minimum(out, d.min(axis=1))
    return out - step / 2


@pytest.fixture(scope="module")
def planned(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("qgc")
    assert main(["plan", str(MISSION), "-o", str(out / "PLAN.json"), "-q"]) == 0
    return out, json.loads((out / "PLAN.json").read_text())


def test_the_route_keeps_d_coll_from_every_polygon_edge_and_the_circle(planned: tuple[Path, dict]) -> None:
    out, doc = planned
    assert doc["status"] == "exact" and doc["scenario_file"] == str(out / "PLAN.scenario.toml")
    sc = load_scenario(doc["scenario_file"])
    d_coll = sc.hazard.d_coll
    op = read_qgc_plan(MISSION)
    origin = (sc.home.lat, sc.home.lon, sc.home.alt)

    def enu(latlon: tuple) -> np.ndarray:
        ll = np.asarray(latlon, dtype=float).reshape(-1, 2)
        e, n, _ = pymap3d.geodetic2enu(ll[:, 0], ll[:, 1], origin[2], *origin)
        return np.stack([e, n], axis=-1)

    route = np.asarray(doc["trajectory"]["points"])[:, :2]
    assert np.allclose(route[-1], enu((op.goal.lat, op.goal.lon))[0], atol=1.0)
    polygons = [z for z in op.zones if z.polygon is not None]
    assert [z.inclusion for z in polygons] == [True, False, False, False]
    for zone in polygons:  # the route keeps d_coll from every edge: outside the no-fly ones, inside the fence
        ring = enu(zone.polygon)
        inside = contains(ring, route)
        assert inside.all() if zone.inclusion else not inside.any(), zone.name
        gap = _boundary_distance(ring, route)
        assert gap.min() >= d_coll, (zone.name, gap.min())
    (circle,) = [z for z in op.zones if z.centre is not None]
    gap = np.linalg.norm(route - enu(circle.centre)[0], axis=1) - circle.radius_m
    assert gap.min() >= d_coll, gap.min()


def test_the_safe_plan_keeps_the_fence_and_loads_in_mavsdk(planned: tuple[Path, dict], rescue_static: Path,
                                                           mavsdk_ground_station: Callable[..., Any]) -> None:
    out, doc = planned
    safe = out / "SAFE.plan"
    assert main(["plan", str(MISSION), "-o", str(safe), "-q"]) == 0
    op, back = read_qgc_plan(MISSION), read_qgc_plan(safe)
    assert back.zones == op.zones and back.rally == op.rally  # the operator's fence and rally point, as they were
    # the planned home is the operator's, not the frame's origin (the region's south-west corner)
    assert back.home is not None and abs(back.home.lat - op.home.lat) < 1e-7 and abs(back.home.lon - op.home.lon) < 1e-7
    sc = load_scenario(out / "SAFE.scenario.toml")
    assert back.goal is not None and abs(back.goal.lat - op.goal.lat) < 1e-6 and abs(back.goal.lon - op.goal.lon) < 1e-6

    async def imported() -> object:
        async with mavsdk_ground_station(sc) as raw:
            return await raw.import_qgroundcontrol_mission(str(safe))

    data = asyncio.run(imported())
    fence = [(it.command, round(it.param1)) for it in data.geofence_items]
    assert fence == [(5001, 6)] * 6 + [(5002, 4)] * 4 + [(5002, 8)] * 8 + [(5002, 3)] * 3 + [(5004, 60)]
    assert len(data.rally_items) == 1
    positions = [it for it in data.mission_items if it.command == 16]
    assert len(positions) >= 2 and abs(positions[-1].x - round(op.goal.lat * 1e7)) <= 2  # 1e-7° through ENU
