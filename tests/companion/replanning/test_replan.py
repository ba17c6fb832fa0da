"""The pure part of live replanning: clock, mission route, commit point, splice, warm starts, separations."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from companion.mavlink.items import compare_items
from companion.mavlink.storage import Firmware, changed_range
from companion.mission.builder import (
    CMD_LOITER_UNLIM,
    MissionSpec,
    build_mission,
    time_to_start,
)
from companion.mission.vehicle_state import VehicleClock
from companion.replanning.replan import (
    MissionRoute,
    ReplanConfig,
    commit_point,
    padded,
    replan_settings,
    splice,
    warm_starts,
    with_room,
)
from companion.replanning.separation import (
    min_separations,
    separation_to_law,
    separation_to_track,
)
from planner.replan import replan_problem
from planner.world.config import PAPER_MODE
from planner.world.environment import Threat, Threats
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
SC = load_scenario(ROOT / "sitl_scenarios" / "rescue_dynamic.toml")
ROUTE = np.array([[200.0, 200, 50], [300, 200, 60], [300, 400, 80], [500, 400, 100], [800, 800, 150]])


def _spec() -> MissionSpec:
    return MissionSpec("ardupilot", SC.vehicle, SC.home)


def _items() -> list:
    return build_mission(ROUTE, _spec())


def test_vehicle_clock_extrapolates_with_a_given_or_measured_rate() -> None:
    c = VehicleClock(rate=20.0)
    assert not c.synced and c.now(5.0) == 0.0
    c.observe(10_000, wall=100.0)
    assert c.now(100.5) == pytest.approx(20.0)  # 10 s + 0.5 wall s × 20
    m = VehicleClock()
    m.observe(0, 0.0)
    m.observe(4_000, 2.0)  # 4 vehicle s in 2 wall s
    assert m.rate == pytest.approx(2.0)
    assert m.now(3.0) == pytest.approx(6.0)
    m.observe(1_000, 3.0)  # reboot: time went backwards, measurement restarts
    assert m.rate == 1.0


def test_mission_route_reads_the_waypoints_back_from_items() -> None:
    items = _items()
    r = MissionRoute.of(items, SC.home)
    assert np.allclose(r.points, ROUTE, atol=0.05)  # 1e-7 deg ≈ 1 cm
    assert r.goal_seq == max(it.seq for it in items if it.command == 16)
    route, seqs = r.remaining(np.array([250.0, 200, 55]), int(r.seqs[1]))
    assert np.allclose(route[0], [250, 200, 55]) and seqs[0] == -1
    assert np.allclose(route[1:], ROUTE[1:], atol=0.05) and list(seqs[1:]) == list(r.seqs[1:])


def _cos(a: np.ndarray, b: np.ndarray) -> float:
    return float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))


def test_commit_point_on_the_current_leg_replaces_the_active_item() -> None:
    r = MissionRoute.of(_items(), SC.home)
    here = np.array([250.0, 200, 55])
    route, seqs = r.remaining(here, int(r.seqs[1]))
    cp = commit_point(route, seqs, int(r.seqs[1]), lead_m=30.0, speed=18.0, t_now=100.0)
    leg = ROUTE[1] - here  # 30 m along the 3-D leg being flown
    assert np.allclose(cp.point, here + 30.0 * leg / np.linalg.norm(leg), atol=0.05)
    assert cp.first_new_seq == r.seqs[1]  # the active item's slot gets the commit point
    assert cp.t == pytest.approx(100 + 30 / 18)
    assert np.allclose(cp.old_tail[0], cp.point) and np.allclose(cp.old_tail[1:], ROUTE[1:], atol=0.05)
    assert _cos(cp.heading, leg) > 0.9999  # the vehicle's direction through the commit point: along the leg


def test_commit_point_beyond_the_active_waypoint_keeps_the_waypoints_before_it() -> None:
    r = MissionRoute.of(_items(), SC.home)
    here = np.array([250.0, 200, 55])
    route, seqs = r.remaining(here, int(r.seqs[1]))
    first_leg = np.linalg.norm(ROUTE[1] - here)
    cp = commit_point(route, seqs, int(r.seqs[1]), lead_m=first_leg + 100.0, speed=18.0, t_now=0.0)
    leg = ROUTE[2] - ROUTE[1]  # 100 m up the second leg
    assert np.allclose(cp.point, ROUTE[1] + 100.0 * leg / np.linalg.norm(leg), atol=0.05)
    assert cp.first_new_seq == r.seqs[2]  # waypoint seqs[1] (300, 200) is kept and flown first
    assert _cos(cp.heading, leg) > 0.9999
    far = commit_point(route, seqs, int(r.seqs[1]), lead_m=1e6, speed=18.0, t_now=0.0)
    assert far.lead_m < np.sum(np.linalg.norm(np.diff(route, axis=0), axis=1))  # kept short of the goal


def test_splice_keeps_the_prefix_and_the_end_action() -> None:
    items = _items()
    r = MissionRoute.of(items, SC.home)
    first = int(r.seqs[2])
    new_route = np.array([[300.0, 300, 70], [450, 300, 90], [600, 700, 130], [800, 800, 150]])
    out = splice(items, first, new_route, r.goal_seq, _spec())
    assert [it.seq for it in out] == list(range(len(out)))
    assert all(compare_items(a, b) is None for a, b in zip(items[:first], out[:first]))
    assert np.allclose(MissionRoute.of(out, SC.home).points[2:], new_route, atol=0.05)
    assert out[-1].command == items[-1].command and compare_items(items[-1].with_seq(out[-1].seq), out[-1]) is None
    with pytest.raises(ValueError):
        splice(items, 0, new_route, r.goal_seq, _spec())


def test_a_shorter_replan_is_padded_to_the_flying_missions_length_on_the_same_path() -> None:
    """So that only its changed part needs writing (MISSION_WRITE_PARTIAL_LIST): a mission that ends in RTL gets
    points in the middle of the longest legs, never a turn; a longer route is left as it is (the whole list is
    uploaded)."""
    spec = dataclasses.replace(_spec(), vehicle=dataclasses.replace(SC.vehicle, end_action="rtl"))
    items = build_mission(ROUTE, spec)
    r = MissionRoute.of(items, SC.home)
    first = int(r.seqs[2])
    short = np.array([[300.0, 300, 70], [800, 800, 150]])
    out = splice(items, first, short, r.goal_seq, spec, length=len(items) + 3)
    assert len(out) == len(items) + 3 and out[-1].command == items[-1].command
    pts = MissionRoute.of(out, SC.home).points[2:]
    assert np.allclose(pts[0], short[0], atol=0.05) and np.allclose(pts[-1], short[-1], atol=0.05)
    d = (short[1] - short[0]) / np.linalg.norm(short[1] - short[0])
    off = pts - short[0]
    assert np.allclose(off - np.outer(off @ d, d), 0.0, atol=0.05)  # every added point on the one straight leg
    assert np.all(np.diff(off @ d) > 0)  # in order along it
    assert len(splice(items, first, short, r.goal_seq, spec, length=2)) == len(splice(
        items, first, short, r.goal_seq, spec))  # already longer: nothing added
    tiny = np.array([[300.0, 300, 70], [310, 300, 70]])
    assert len(padded(tiny, 10, 30.0)) == 2  # no leg long enough to split


def test_a_loiter_end_gets_room_behind_it_and_a_replan_keeps_the_length_with_copies_of_it() -> None:
    """A mission ending in NAV_LOITER_UNLIM (never left) is flown with copies of it behind (with_room). A longer
    replan fits in that length, a shorter one is made up with copies, never with points on the route; the copies
    that were there before stay in their slots, so the write ends at the last slot that really changed."""
    items = _items()
    assert items[-1].command == CMD_LOITER_UNLIM
    roomy = with_room(items, 6)
    assert len(roomy) == len(items) + 6 and [it.seq for it in roomy] == list(range(len(roomy)))
    assert all(compare_items(items[-1].with_seq(it.seq), it) is None for it in roomy[len(items):])
    r = MissionRoute.of(roomy, SC.home)
    assert r.goal_seq == MissionRoute.of(items, SC.home).goal_seq  # the copies are not route
    first = int(r.seqs[2])
    for new_route in (np.array([[300.0, 300, 70], [800, 800, 150]]),  # shorter than the old tail
                      np.array([[300.0, 300, 70], [400, 350, 80], [500, 450, 90], [600, 550, 110], [700, 650, 130],
                                [800, 800, 150]])):  # longer: uses some of the room
        out = splice(roomy, first, new_route, r.goal_seq, _spec(), length=len(roomy))
        assert len(out) == len(roomy) and [it.seq for it in out] == list(range(len(out)))
        got = MissionRoute.of(out, SC.home)
        assert np.allclose(got.points[2:], new_route, atol=0.05)  # no point added on the route
        end = got.goal_seq + 1
        assert all(compare_items(items[-1].with_seq(it.seq), it) is None for it in out[end:])
        changed = changed_range(out, roomy, firmware=Firmware.ARDUPLANE)
        assert changed is not None and changed[0] == first
        assert changed[1] == max(end, r.goal_seq + 1) - 1  # from the later loiter on, slots are left as they were
    assert with_room(build_mission(ROUTE, dataclasses.replace(_spec(), vehicle=dataclasses.replace(
        SC.vehicle, end_action="rtl"))), 6)[-1].command != CMD_LOITER_UNLIM  # an RTL end gets no room


def test_warm_starts_bend_the_old_route_both_ways_and_keep_its_ends() -> None:
    tail = np.array([[0.0, 0, 100], [500, 0, 100], [1000, 0, 100]])
    seeds = warm_starts(tail, (-200.0, 200.0), n_points=11)
    assert seeds.shape == (3, 11, 3)
    assert np.allclose(seeds[:, 0], tail[0]) and np.allclose(seeds[:, -1], tail[-1])
    assert np.allclose(seeds[0, :, 1], 0.0)  # the old route itself
    assert seeds[1, 5, 1] == pytest.approx(-200.0) and seeds[2, 5, 1] == pytest.approx(200.0)  # left of east is +y


def test_replan_problem_uses_the_threat_picture_and_the_commit_time() -> None:
    tr = Threat(id="adsb-1", kind="track", radius=40.0, p0=(500.0, 500, 120), p1=(-10.0, 0, 0), t_ref=5.0)
    p = replan_problem(SC, np.array([300.0, 300, 80]), SC.goal, Threats(items=(tr,)), 12.5,
                       heading=np.array([3.0, 4.0, 0.0]))
    assert p.start_time == 12.5 and [t.id for t in p.env.threats.items] == ["adsb-1"]
    assert np.allclose(p.start_heading, [0.6, 0.8, 0.0])  # the turn onto the new route is held to the limits
    assert len(p.env.cylinders) == len(SC.environment.cylinders)


def test_replan_problem_plans_for_the_replanners_margin_around_threats() -> None:
    """A route the replanner would call a conflict (separation below d_coll + margin) costs a violation."""
    tr = Threat(id="adsb-1", kind="track", radius=40.0, p0=(900.0, 150, 150), p1=(0.0, 0, 0), t_ref=0.0)
    y = 150.0 - 40 - SC.hazard.d_coll - 8  # passes the threat 8 m outside d_coll: inside a margin of 15 m
    route = np.stack([np.linspace(800.0, 1000.0, 51), np.full(51, y), np.full(51, 150.0)], axis=1)
    bare = replan_problem(SC, route[0], route[-1], Threats(items=(tr,)), 0.0)
    with_margin = replan_problem(SC, route[0], route[-1], Threats(items=(tr,)), 0.0, threat_margin=15.0)
    assert with_margin.env.threats.items[0].radius == 55.0 and bare.env.threats.items[0].radius == 40.0
    assert bare.evaluate(route).n_violations[0] == 0
    assert with_margin.evaluate(route).violations["collision"][0] > 0


def test_time_to_start_is_the_climb_and_the_leg_to_the_start() -> None:
    v = SC.vehicle
    climb = v.takeoff_alt / (v.cruise_speed * np.sin(v.max_climb))
    rest = (np.hypot(200, 200) - v.takeoff_alt / np.tan(v.max_climb)) / v.cruise_speed
    assert time_to_start(SC) == pytest.approx(climb + rest)
    assert 14.0 < time_to_start(SC) < 18.0  # the simulator reaches the start 15.6 s after mission start


def test_separation_to_a_track_is_hand_computed() -> None:
    # vehicle east along y = 0 at 10 m/s, intruder north along x = 100 at 10 m/s: at t = 10 the vehicle is at
    # (100, 0) and the intruder at (100, -50 + 100) = (100, 50): 50 m apart, the closest they come
    t = np.arange(0.0, 20.01, 0.1)
    vehicle = np.stack([t, 10 * t, 0 * t, 0 * t + 100], axis=1)
    intruder = np.stack([t, 0 * t + 100, -50 + 10 * t, 0 * t + 100], axis=1)
    s = separation_to_track(vehicle, intruder, radius=40.0, threat_id="x")
    # d(t)² = (10t − 100)² + (10t − 50)²: minimum at t = 7.5, d = √(25² + 25²) = 35.36
    assert s.t == pytest.approx(7.5) and s.distance == pytest.approx(np.hypot(25, 25), abs=1e-6)
    assert s.separation == pytest.approx(np.hypot(25, 25) - 40.0, abs=1e-6)
    late = intruder.copy()
    late[:, 0] += 100.0  # flies only after the vehicle's track ends: never met
    assert separation_to_track(vehicle, late, 40.0, "x").separation == np.inf


def test_separation_to_scripted_threats_runs_on_mission_time() -> None:
    loiter = Threat(id="l", kind="loiter", radius=10.0, p0=(0.0, 0, 100), circle_radius=50.0, speed=5.0)
    # vehicle clock 100 and 101 s; the mission started at 100 → law time 0 and 1
    vehicle = np.array([[100.0, 50.0, 0, 100], [101.0, 0, 0, 0]])
    (s,) = separation_to_law(vehicle, Threats(items=(loiter,)), clock_offset=100.0)
    assert s.t == 100.0 and s.separation == pytest.approx(-10.0)  # on the threat's centre at law time 0
    both = min_separations(vehicle, {"i": (np.array([[100.0, 50, 30, 100], [101, 50, 30, 100]]), 5.0)},
                           Threats(items=(loiter,)), mission_t0=100.0)
    assert set(both) == {"i", "l"} and both["i"].separation == pytest.approx(25.0)


def test_replan_settings_take_the_swarm_size_and_the_roadmap_unless_told_not_to() -> None:
    """A replan plans with the replanning swarm and the roadmap pipeline (``ReplanConfig.roadmap``, the default;
    off, the scenario's planner as it says), every other setting as the scenario says."""
    assert SC.planner.roadmap.enabled  # the default planner
    paper = load_scenario(SC.source, [PAPER_MODE]).planner  # a scenario in paper mode keeps it
    plain = replan_settings(paper, ReplanConfig(population=37, roadmap=False))
    assert plain.pso.n_pop == 37 and not plain.roadmap.enabled and plain.aco == SC.planner.aco
    on = replan_settings(SC.planner, ReplanConfig())  # the default: replans by the roadmap
    assert on.roadmap.enabled and on.roadmap.spacing == SC.planner.roadmap.spacing and on.pso.n_pop == 100
    # a safe route now: the swarm stops once feasible, around one guide route (the old route seeds the others)
    assert on.pso.feasible_iters == ReplanConfig().settle_iters > 0 and SC.planner.pso.feasible_iters == 0
    assert on.roadmap.n_routes == ReplanConfig().guide_routes == 1 != SC.planner.roadmap.n_routes


def test_the_latency_report_says_which_planner_made_the_replans(tmp_path: Path) -> None:
    """`bench replan [--replan-paper]`: the report says which planner made the replans."""
    from companion.flight.latency_bench import LatencyRun, write_report

    run = [LatencyRun("crossing_traffic", 1, 1.0, "approximate", False, 0.16, 0.14, 0.02, 40.0)]
    write_report(run, ReplanConfig(), tmp_path / "on")
    write_report(run, ReplanConfig(roadmap=False), tmp_path / "off")
    assert "replans by the roadmap pipeline" in (tmp_path / "on" / "replan.md").read_text()
    off = (tmp_path / "off" / "replan.md").read_text()
    assert "roadmap" not in off and "replans by the scenario's planner" in off
    from planner import kernel
    assert f"cost kernel: {kernel.chosen()}" in off


@pytest.mark.asyncio
async def test_a_planner_process_started_before_the_route_is_known_plans_once_warmed_on_it() -> None:
    """`fly` starts the planner process as soon as the link is open (no route yet: process start and imports only)
    and the replanner warms it on the route later; a plan then comes from that process, within its budget."""
    from companion.replanning.worker import PlanWorker

    worker = PlanWorker()
    try:
        assert await worker.ready() >= 0.0  # started and imported, nothing planned yet
        problem = replan_problem(SC, np.array([200.0, 200, 50]), SC.goal, SC.environment.threats, 0.0)
        settings = replan_settings(SC.planner, ReplanConfig())
        worker.warm(problem, settings)
        await worker.ready()
        out = await worker.plan(problem, settings, [1, 2], None, 1.0)
        assert out.status in ("exact", "approximate") and out.waypoints.shape[1] == 3
    finally:
        worker.close()
