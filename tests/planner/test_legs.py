"""Routes through vias (planner.legs): every via a waypoint of the route, in order; the whole route checked as one;
the same seed the same route; a deadline shared by the legs in proportion to their length; and without vias, the
plan exactly as before."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

import planner.legs as legs
from planner.deadline import Deadline
from planner.legs import leg_problems, plan_scenario
from planner.plan import PlanStatus, assess, plan, plan_to_json, problem_from_scenario
from planner.world.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
STATIC = REPO / "sitl_scenarios" / "rescue_static.toml"
VIAS = "route.vias=[[250, 550, 60], [550, 850, 70]]"  # north-west of the cylinders, then east of them


@pytest.fixture(scope="module")
def through() -> tuple:
    sc = load_scenario(STATIC, [VIAS])
    return sc, plan_scenario(sc, sc.planner, np.random.default_rng(1), seed=1)


def _index_of(waypoints: np.ndarray, point: np.ndarray) -> int:
    d = np.linalg.norm(waypoints - point, axis=1)
    assert d.min() < 1.0, f"{point} is {d.min():.1f} m from the nearest waypoint"
    return int(d.argmin())


def test_the_route_passes_through_every_via_in_order_and_is_checked_whole(through: tuple) -> None:
    sc, res = through
    w = res.waypoints
    at = [_index_of(w, v) for v in sc.vias]
    assert 0 < at[0] < at[1] < len(w) - 1
    assert np.array_equal(w[0], sc.start) and np.array_equal(w[-1], sc.goal)
    assert len(res.legs) == 3 and res.status is PlanStatus.EXACT and res.feasible
    # the verdict is the whole route's, as plan() gives it: the same check on the same waypoints
    problem = problem_from_scenario(sc)
    _, check, feasible = assess(problem, sc.planner, w, problem.evaluate(w[None]))
    assert feasible and check.counts == res.check.counts
    assert res.evaluation.total[0] == pytest.approx(problem.evaluate(w[None]).total[0])
    doc = plan_to_json(res, sc)
    assert [v["xyz"] for v in doc["vias"]] == sc.vias.tolist() and len(doc["legs"]) == 3
    assert -35.37 < doc["vias"][0]["lat"] < -35.35 and doc["vias"][1]["alt_above_home"] == 70.0


def test_the_same_seed_gives_the_same_route_through_vias(through: tuple) -> None:
    sc, res = through
    again = plan_scenario(sc, sc.planner, np.random.default_rng(1), seed=1)
    assert np.array_equal(again.waypoints, res.waypoints)
    other = plan_scenario(sc, sc.planner, np.random.default_rng(2), seed=2)
    assert not np.array_equal(other.waypoints, res.waypoints)  # the seed reaches the legs


def test_without_vias_the_plan_is_plan_itself() -> None:
    """Same seed, same PLAN.json as the single start→goal plan (timings aside), and no vias or legs keys."""
    sc = load_scenario(STATIC)
    a = plan_to_json(plan_scenario(sc, sc.planner, np.random.default_rng(4), seed=4), sc)
    b = plan_to_json(plan(problem_from_scenario(sc), sc.planner, np.random.default_rng(4), seed=4), sc)
    for doc in (a, b):
        doc["metrics"].pop("plan_time_s")
        for phase in doc.get("phases", {}).values():
            if isinstance(phase, dict):
                phase.pop("time_s")
    assert a == b and "vias" not in a and "legs" not in a


def test_a_deadline_is_shared_by_the_legs_in_proportion_to_their_length(monkeypatch: pytest.MonkeyPatch) -> None:
    """Each leg is given its share of what is left (a leg that uses all of it leaves the next its own share), and a
    leg after a via starts flying the way the leg before arrived, at the time it arrived."""
    sc = load_scenario(STATIC, [VIAS])
    now = [0.0]
    given: list[tuple] = []
    real_plan = legs.plan

    def timed_plan(problem, settings, rng, initial_paths, deadline, seed, progress):
        result = real_plan(problem, settings, rng, seed=seed)
        given.append((deadline.seconds, problem, result))
        now[0] += deadline.seconds  # as if the leg took its whole share
        return result

    monkeypatch.setattr(legs, "plan", timed_plan)
    monkeypatch.setattr(legs, "post_reserve_s", lambda problem, settings: 0.0)
    problem = dataclasses.replace(problem_from_scenario(sc), start_time=5.0)
    legs.plan_through(problem, sc.vias, sc.planner, np.random.default_rng(1),
                      deadline=Deadline(30.0, 0.0, lambda: now[0]))
    chords = [p.direct_distance for p in leg_problems(problem, sc.vias)]
    assert [g[0] for g in given] == pytest.approx([30.0 * c / sum(chords) for c in chords])
    for (_, _, before), (_, leg, _) in zip(given[:-1], given[1:]):
        arrived = before.waypoints[-1] - before.waypoints[-2]
        assert np.allclose(leg.start_heading, arrived / np.linalg.norm(arrived))
        assert leg.start_time == pytest.approx(before.trajectory.times[-1]) and leg.start_time > 5.0
    assert given[0][1].start_time == 5.0 and given[0][1].start_heading is None


def test_the_legs_are_the_route_cut_at_its_vias() -> None:
    sc = load_scenario(STATIC, [VIAS])
    problems = leg_problems(problem_from_scenario(sc), sc.vias)
    assert [p.start.tolist() for p in problems] == [sc.start.tolist(), *sc.vias.tolist()]
    assert [p.goal.tolist() for p in problems] == [*sc.vias.tolist(), sc.goal.tolist()]


def test_a_turn_at_a_via_the_vehicle_cannot_fly_makes_the_route_infeasible(through: tuple) -> None:
    """Legs that are each fine but meet in a hairpin at their via: the whole route's check refuses the turn, and the
    route is infeasible though every leg was exact (nothing smooths it away)."""
    _, res = through
    sc = load_scenario(STATIC, ["route.vias=[[200, 600, 60]]"])
    start, via, goal = sc.start, sc.vias[0], sc.goal
    first = dataclasses.replace(res, waypoints=np.array([start, via]))
    back = dataclasses.replace(res, waypoints=np.array([via, [205.0, 350.0, 60.0], goal]))
    joined = legs._joined(problem_from_scenario(sc), sc.planner, [first, back], 1, 0.0)
    assert [r.status for r in joined.legs] == [PlanStatus.EXACT] * 2
    assert joined.status is PlanStatus.INFEASIBLE and joined.check.counts["turn"] > 0
    assert np.array_equal(joined.waypoints[1], via)  # the via stays a waypoint
