"""A live replan keeps the vias the vehicle has not passed (issue 35): the simulated plane, replanning around an
intruder that crosses its route before a via, still flies through the via; the vias it passed, or that stay in the
items kept before the commit point, are not planned again. Real UDP on 127.0.0.1, the built-in simulator."""

from __future__ import annotations

import asyncio
import math
from pathlib import Path

import numpy as np
import pytest

from companion.cli import _plan_doc_for
from companion.flight.fly import truth_separations
from companion.flight.latency_bench import fly_on_sim
from companion.mission.builder import mission_from_plan_json
from companion.replanning.replan import MissionRoute, ReplanConfig, tail_to, vias_ahead
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
VIA = [550.0, 850.0, 70.0]  # north-east of the cylinders: the route from the start bends there towards the goal
# crosses the planned route square to it 190 m before the via, at the plane's height, as the plane passes there
INTRUDER = """
[[intruders]]
id = "crossing"
icao = 0xC0FFEE
waypoints = [[802.9, 376.0, 69.0], [130.8, 974.5, 69.0]]
speed = 15.0
meet = [429.5, 708.5, 69.0]
radius = 40.0
"""


@pytest.fixture(scope="module")
def scenario(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("vias") / "vias_traffic.toml"
    text = STATIC.read_text().replace("goal = [800.0, 800.0, 50.0]", f"goal = [800.0, 800.0, 50.0]\nvias = [{VIA}]")
    path.write_text(text + INTRUDER)
    return path


def test_vias_ahead_are_those_not_passed_nor_kept_before_the_commit_point(scenario: Path) -> None:
    doc, sc = _plan_doc_for(scenario, None, [], None, for_flight=True)
    route = MissionRoute.of(mission_from_plan_json(doc, sc), sc.home)
    via_at = int(np.flatnonzero(np.linalg.norm(route.points - VIA, axis=1) < 1.0)[0])
    seq = int(route.seqs[via_at])
    start = route.points[0]
    assert vias_ahead(route, sc.vias, int(route.seqs[1]), start, 10.0).tolist() == [VIA]
    assert vias_ahead(route, sc.vias, seq, start, 10.0).tolist() == [VIA]  # the via is the first new item
    assert len(vias_ahead(route, sc.vias, seq + 1, start, 10.0)) == 0  # kept before the commit point, or passed
    assert len(vias_ahead(route, sc.vias, int(route.seqs[1]), np.add(VIA, [5.0, 0, 0]), 10.0)) == 0  # begins there
    tail = route.points[1:]
    assert np.array_equal(tail_to(tail, np.array(VIA)), tail[:via_at])
    assert tail_to(tail, np.array([0.0, 0.0, 60.0])).tolist() == [tail[0].tolist(), [0.0, 0.0, 60.0]]


def test_a_replan_before_a_via_still_flies_through_it(scenario: Path) -> None:
    doc, sc = _plan_doc_for(scenario, None, [], None, for_flight=True)
    assert doc["status"] == "exact"
    out, records, rp, sim = asyncio.run(fly_on_sim(doc, sc, speedup=10.0, cfg=ReplanConfig(), seed=1,
                                                   flight_timeout=240.0))
    assert out is not None and out.completed, out
    events = [r["event"] for r in records]
    done = [r for r in rp.records if r.outcome == "new mission current"]
    assert done, [r.summary() for r in rp.records]
    # the new route was planned from before the via (a commit point short of it), and goes through it
    off = np.linalg.norm(np.array(done[0].new_route) - VIA, axis=1)
    assert off.min() < 1.0 and off.argmin() > 0, done[0].new_route
    track = np.array([(x, y, z) for _t, _lat, _lon, _alt, x, y, z in sim.truth])
    miss = float(np.linalg.norm(track - VIA, axis=1).min())
    assert miss < 8.0, (miss, events)  # without keeping it, the replanned plane passed 35-40 m from it
    assert truth_separations(sim, sc, math.inf)["crossing"].separation >= sc.hazard.d_coll
    assert load_scenario(scenario).vias.tolist() == [VIA]


def test_a_plane_resumed_just_past_a_via_is_sent_back_to_it_not_beyond(scenario: Path) -> None:
    """RejoinChecks.ahead_seq skips items a plane has passed or cannot turn onto; never a via's (the join to it is
    then checked, or refused and the plane replanned through it)."""
    from types import SimpleNamespace

    from companion.mission.events import EventLog
    from companion.replanning.rejoin import RejoinChecks

    doc, sc = _plan_doc_for(scenario, None, [], None, for_flight=True)
    route = MissionRoute.of(mission_from_plan_json(doc, sc), sc.home)
    k = int(np.flatnonzero(np.linalg.norm(route.points - VIA, axis=1) < 1.0)[0])
    leg = route.points[k + 1] - route.points[k]
    here = route.points[k] + 0.3 * leg  # past the via along the next leg, flying along it

    def ahead(scenario_: object) -> int:
        state = SimpleNamespace(position=here, velocity=18.0 * leg[:2] / np.linalg.norm(leg[:2]), groundspeed=18.0)
        ctx = SimpleNamespace(state=state, profile=SimpleNamespace(hold_circles=True), events=EventLog(),
                              scenario=scenario_)
        swap = SimpleNamespace(route=route, goal_seq=route.goal_seq)
        motion = SimpleNamespace(wide_turn_radius=lambda speed: 40.0)
        return RejoinChecks(ctx, motion, None, None, swap).ahead_seq(int(route.seqs[k]))

    assert ahead(sc) == int(route.seqs[k])
    without = load_scenario(scenario, ["route.vias=[]"])
    assert ahead(without) > int(route.seqs[k])  # the control: an ordinary item behind the plane is skipped
