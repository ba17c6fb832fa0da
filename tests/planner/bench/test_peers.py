"""OMPL peers (planner.bench.peers, issue 15): RRTConnect finds a route on a hard map whose states and chords keep
the clearance asked of it (checked here with the project's geometry, not through OMPL), from the start to the goal,
the same seed gives the same route, the grid-accelerated validity test agrees with obstacle_clearance, BIT* runs
to its time limit, and without the ``peers`` extra the error says how to install it. Skipped without OMPL."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.bench import hardmaps, peers
from planner.errors import FuseplanError
from planner.plan import problem_from_scenario
from planner.problem import PlanningProblem
from planner.trajectory.checks import obstacle_clearance
from planner.world.config import HazardConfig, VehicleLimits
from planner.world.environment import Cylinders, Environment, Radars, Spheres
from planner.world.scenario import load_scenario

pytest.importorskip("ompl")  # the peers extra; planner.bench.peers itself imports it only when used

TIME_S = 2.0  # RRTConnect stops at its first solution, well inside this


@pytest.fixture(scope="module")
def gates(tmp_path_factory: pytest.TempPathFactory) -> PlanningProblem:
    path = tmp_path_factory.mktemp("peers") / "gates_0.toml"
    path.write_text(hardmaps.generate("gates", 0).toml)
    return problem_from_scenario(load_scenario(path))


@pytest.fixture(scope="module")
def rrt(gates: PlanningProblem) -> peers.PeerResult:
    return peers.solve(gates, "rrtconnect", TIME_S, seed=3)


def _need(problem: PlanningProblem) -> float:
    return problem.hazard.d_coll + 0.5 * problem.vehicle.acceptance_radius


def _mixed_problem() -> PlanningProblem:
    """A small map with every static family: unlimited and finite cylinders, a sphere, a hemisphere, a radar."""
    env = Environment(1000.0, 800.0, 50.0, 300.0,
                      cylinders=Cylinders([200.0, 500.0], [300.0, 500.0], [40.0, 60.0], [np.inf, 120.0],
                                          [0.0, 0.0]),
                      spheres=Spheres([[700.0, 200.0, 150.0], [400.0, 650.0, 0.0]], [50.0, 90.0]),
                      radars=Radars([[800.0, 600.0, 20.0]], [120.0], [1.0]))
    return PlanningProblem(env, [50.0, 50.0, 100.0], [950.0, 750.0, 100.0], VehicleLimits(),
                           HazardConfig(d_safe=60.0, d_coll=15.0))


def test_rrtconnect_finds_a_route_that_keeps_its_clearance(gates: PlanningProblem, rrt: peers.PeerResult) -> None:
    assert rrt.found and rrt.route is not None
    route = rrt.route
    np.testing.assert_array_equal(route[0], gates.start)
    np.testing.assert_array_equal(route[-1], gates.goal)
    assert 2 <= len(route) <= rrt.raw_waypoints + 1
    env, need = gates.env, _need(gates)
    assert (obstacle_clearance(route, None, env) >= need).all()
    assert ((route[:, 2] >= env.z_min) & (route[:, 2] <= env.z_max)).all()
    # chords, by the cost's exact segment distances: OMPL checks them every few metres, so they dip only a little
    cyl_c, sph_c, _ = gates.static_clearances(route[:-1], route[1:])
    assert cyl_c.min() >= need - 0.5
    assert rrt.length_m == pytest.approx(np.linalg.norm(np.diff(route, axis=0), axis=1).sum())
    assert rrt.flyable == (not any(rrt.violations.values()))
    assert set(rrt.violations) == set(hardmaps.route_violations(route, env, gates.hazard, gates.vehicle))


def test_rrtconnect_with_the_same_seed_gives_the_same_route(gates: PlanningProblem, rrt: peers.PeerResult) -> None:
    again = peers.solve(gates, "rrtconnect", TIME_S, seed=3)
    assert again.raw_waypoints == rrt.raw_waypoints
    np.testing.assert_array_equal(again.route, rrt.route)


def test_the_validity_test_agrees_with_obstacle_clearance_on_every_family() -> None:
    problem = _mixed_problem()
    env, need, margin = problem.env, _need(problem), 0.5 * problem.vehicle.acceptance_radius
    valid = peers.state_validity(problem, cell=25.0)
    pts = np.random.default_rng(0).uniform([-10.0, -10.0, 40.0], [1010.0, 810.0, 310.0], (4000, 3))
    solid = obstacle_clearance(pts, None, env, include_radars=False)
    radar = np.linalg.norm(pts - env.radars.center[0], axis=1) - env.radars.r_det[0]
    inside = ((pts[:, :2] >= 0.0) & (pts[:, :2] <= [env.size_x, env.size_y])).all(axis=1)
    band = (pts[:, 2] >= env.z_min) & (pts[:, 2] <= env.z_max)
    expected = inside & band & (solid >= need) & (radar >= margin)
    got = np.array([valid(*p) for p in pts.tolist()])
    np.testing.assert_array_equal(got, expected)
    assert 0.2 < expected.mean() < 0.9  # both verdicts well represented


def test_bitstar_is_anytime_and_runs_to_its_time_limit() -> None:
    problem = _mixed_problem()
    r = peers.solve(problem, "bitstar", 0.3, seed=1)
    assert r.found and r.route is not None
    np.testing.assert_array_equal(r.route[[0, -1]], np.stack([problem.start, problem.goal]))
    assert r.time_s >= 0.3
    assert (obstacle_clearance(r.route, None, problem.env, include_radars=False) >= _need(problem)).all()


def test_an_unknown_planner_is_refused(gates: PlanningProblem) -> None:
    with pytest.raises(ValueError, match="rrtconnect"):
        peers.solve(gates, "prm", 1.0, seed=0)


def test_without_the_extra_the_error_says_how_to_install_it(gates: PlanningProblem,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ompl", None)  # `import ompl` now raises ImportError
    assert not peers.available()
    with pytest.raises(FuseplanError, match=r"install the peers extra: pip install -e '\.\[peers\]'"):
        peers.solve(gates, "rrtconnect", 1.0, seed=0)


def test_a_solve_leaves_nothing_for_nanobind_to_report_at_exit() -> None:
    code = ("from planner.bench import peers\n"
            "from planner.problem import PlanningProblem\n"
            "from planner.world.config import VehicleLimits\n"
            "from planner.world.environment import Environment\n"
            "p = PlanningProblem(Environment(500.0, 500.0, 50.0, 300.0), [10, 10, 100], [490, 490, 100],"
            " VehicleLimits())\n"
            "assert peers.solve(p, 'rrtconnect', 1.0, seed=0).found\n")
    root = Path(__file__).resolve().parents[3]
    done = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "leaked" not in done.stderr, done.stderr
