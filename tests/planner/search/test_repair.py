"""Local repair of a nearly flyable guide (planner.search.repair, docs/method.md §15.5)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.bench import hardmaps
from planner.problem import PlanningProblem
from planner.search import roadmap as rmap
from planner.search.encoding import guided_encoding
from planner.search.repair import fault_windows, repair
from planner.world.config import HazardConfig, VehicleLimits
from planner.world.environment import Cylinders, Environment

VEHICLE = VehicleLimits()
HAZARD = HazardConfig(d_safe=60.0, d_coll=15.0)


def _problem() -> PlanningProblem:
    cyl = Cylinders(np.array([600.0]), np.array([500.0]), np.array([100.0]), np.array([np.inf]), np.zeros(1))
    env = Environment(1200.0, 1000.0, 50.0, 300.0, cylinders=cyl)
    return PlanningProblem(env, np.array([100.0, 500.0, 120.0]), np.array([1100.0, 500.0, 120.0]), VEHICLE, HAZARD)


def _grazing(pb: PlanningProblem) -> np.ndarray:
    """Around the cylinder's north side, its middle leg grazing the cylinder and a short leg before a sharp turn."""
    return np.array([pb.start, [300.0, 560.0, 120.0], [450.0, 640.0, 120.0], [600.0, 610.0, 120.0],
                     [750.0, 640.0, 120.0], [790.0, 660.0, 120.0], [950.0, 520.0, 120.0], pb.goal])


def _clear(pb: PlanningProblem) -> np.ndarray:
    """North of the cylinder with gentle turns: no violation."""
    return np.array([pb.start, [250.0, 750.0, 120.0], [450.0, 800.0, 120.0], [600.0, 800.0, 120.0],
                     [750.0, 800.0, 120.0], [950.0, 750.0, 120.0], pb.goal])


def test_a_fault_is_located_in_the_windows_around_it() -> None:
    pb = _problem()
    assert pb.evaluate(_clear(pb)).n_violations[0] == 0 and len(fault_windows(pb, _clear(pb))) == 0
    kinked = _clear(pb)
    kinked[3, 1] = 700.0  # a dent at point 3: too sharp a turn there
    assert pb.evaluate(kinked).n_violations[0] > 0
    starts = fault_windows(pb, kinked)
    assert len(starts) and all(j <= 3 <= j + 3 for j in starts)  # windows that hold point 3 only
    assert all(pb.evaluate(kinked[j:j + 4]).n_violations[0] > 0 for j in starts)
    assert len(starts) < len(kinked) - 3


def test_repair_removes_the_faults_keeps_the_ends_and_is_reproducible() -> None:
    pb = _problem()
    path = _grazing(pb)
    before = pb.evaluate(path)
    a = repair(pb, path, np.random.default_rng(3), rounds=20)
    b = repair(pb, path, np.random.default_rng(3), rounds=20)
    assert a.violations == 0 and pb.evaluate(a.path).n_violations[0] == 0
    assert a.cost == pytest.approx(float(pb.evaluate(a.path).total[0]), rel=1e-12) and a.cost < before.total[0]
    assert a.path.shape == path.shape
    np.testing.assert_array_equal(a.path[[0, -1]], path[[0, -1]])
    np.testing.assert_array_equal(a.path, b.path)


def test_a_clean_route_is_returned_as_it_is() -> None:
    pb = _problem()
    clear = _clear(pb)
    r = repair(pb, clear, np.random.default_rng(0))
    assert r.violations == 0 and r.rounds == 0 and r.evaluations == 1
    np.testing.assert_array_equal(r.path, clear)


def test_the_stretch_cost_ranks_candidates_as_the_whole_route_cost_does() -> None:
    """Repair scores candidates by the cost of path[j-3 : j+7] for a window j..j+3: without moving threats the
    rest of the route's cost is the same for all of them, so differences agree with the whole route's."""
    pb = _problem()
    path = _grazing(pb)
    rng = np.random.default_rng(11)
    for j in range(0, len(path) - 3):
        idx = np.arange(j, j + 4)
        idx = idx[(idx > 0) & (idx < len(path) - 1)]
        lo, hi = max(int(idx[0]) - 3, 0), min(int(idx[-1]) + 4, len(path))
        trial = np.repeat(path[None], 6, axis=0)
        trial[1:, idx] += rng.normal(0.0, 30.0, (5, len(idx), 3))
        whole = pb.evaluate(trial).total
        part = pb.evaluate(trial[:, lo:hi]).total
        np.testing.assert_allclose(whole - whole[0], part - part[0], rtol=1e-9, atol=1e-6 * abs(whole[0]))


def test_a_hard_maps_guide_with_turn_faults_is_repaired(tmp_path) -> None:
    """A canyon's roadmap guide as the swarm gets it has turn faults (legs a little short for their corners);
    the repair makes it flyable, which the swarm on a 0.15 s replan budget did not."""
    from planner.plan import problem_from_scenario
    from planner.world.scenario import load_scenario

    f = tmp_path / "canyon.toml"
    f.write_text(hardmaps.generate("canyon", 2000).toml)
    sc = load_scenario(f, ["planner.roadmap.enabled=true"])
    pb = problem_from_scenario(sc)
    routes = rmap.routes(pb, sc.planner.roadmap)[3]
    _, pts = guided_encoding(pb, sc.planner.pso, routes[0])
    assert pb.evaluate(pts).violations["turn"][0] > 0
    r = repair(pb, pts, np.random.default_rng(0))
    assert r.violations == 0
