"""SPSO: one update step by hand (docs/method.md §6.1), ablation switches (§6.3), determinism, and a real run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.deadline import Deadline
from planner.plan import PlanStatus, plan, problem_from_scenario
from planner.search.encoding import make_encoding
from planner.search.spso import SphericalPSO, diversity, inertia, pso_step
from planner.world.config import SPSOConfig
from planner.world.scenario import load_scenario


def test_one_step_by_hand_with_reflection() -> None:
    # one particle, one waypoint: (r, psi, phi) with bounds r in [0, 100], psi in [-0.2, 0.2], phi in [0, 1]
    lo = np.array([[0.0, -0.2, 0.0]])
    hi = np.array([[100.0, 0.2, 1.0]])
    vmax = 0.5 * (hi - lo)  # 50, 0.2, 0.5
    x = np.array([[[50.0, 0.1, 0.5]]])
    v = np.array([[[10.0, 0.05, -0.1]]])
    pbest = np.array([[[60.0, 0.15, 0.4]]])
    gbest = np.array([[70.0, 0.2, 0.0]])
    r1 = np.array([[[0.5, 1.0, 0.2]]])
    r2 = np.array([[[0.25, 0.5, 1.0]]])
    w, c1, c2 = 0.9, 1.5, 1.5
    # by hand:
    # r:   v = 0.9*10 + 1.5*0.5*(60-50) + 1.5*0.25*(70-50) = 9 + 7.5 + 7.5 = 24 -> x = 74 (inside)
    # psi: v = 0.9*0.05 + 1.5*1*(0.05) + 1.5*0.5*(0.1) = 0.045 + 0.075 + 0.075 = 0.195 -> x = 0.295 > 0.2:
    #      put on the bound 0.2 and the velocity reflected to -0.195
    # phi: v = 0.9*-0.1 + 1.5*0.2*(-0.1) + 1.5*1*(-0.5) = -0.09 - 0.03 - 0.75 = -0.87 -> clipped to -0.5
    #      x = 0.5 - 0.5 = 0.0 (exactly on the bound: inside, velocity kept)
    x1, v1 = pso_step(x, v, pbest, gbest, w, c1, c2, lo, hi, vmax, True, r1, r2)
    np.testing.assert_allclose(x1, [[[74.0, 0.2, 0.0]]], atol=1e-12)
    np.testing.assert_allclose(v1, [[[24.0, -0.195, -0.5]]], atol=1e-12)
    # V4 (reflection off): same position, velocity kept
    x2, v2 = pso_step(x, v, pbest, gbest, w, c1, c2, lo, hi, vmax, False, r1, r2)
    np.testing.assert_allclose(x2, x1, atol=1e-12)
    np.testing.assert_allclose(v2, [[[24.0, 0.195, -0.5]]], atol=1e-12)


def test_inertia_schedules() -> None:
    f = np.array([1.0, 2.0, 3.0])
    assert inertia(SPSOConfig(), 0, f, 1.0) == 1.0
    assert inertia(SPSOConfig(), 10, f, 1.0) == pytest.approx(0.98**10)
    assert inertia(SPSOConfig(damping=False), 10, f, 1.0) == 1.0  # V5: fixed at w0 = 1
    w = inertia(SPSOConfig(inertia="adaptive", max_iter=100), 50, f, 1.0)[:, 0, 0]
    sigma = np.std(f)
    expect = 0.9 - 0.5 * 0.5 * np.exp(-((f - 1.0) ** 2) / (2 * sigma**2))
    np.testing.assert_allclose(w, expect)
    assert w[0] < w[1] < w[2]  # the best particle exploits, the worst explores


def test_diversity_is_zero_for_a_collapsed_swarm() -> None:
    lo, hi = np.zeros((2, 3)), np.ones((2, 3))
    same = np.full((5, 2, 3), 0.3)
    assert diversity(same, lo, hi) == 0.0
    spread = np.stack([np.zeros((2, 3)), np.ones((2, 3))])
    assert diversity(spread, lo, hi) == pytest.approx(6 * 0.25)


def test_encoding_bounds_follow_spec(rescue_static) -> None:
    sc = load_scenario(rescue_static)
    prob = problem_from_scenario(sc)
    enc = make_encoding(prob, SPSOConfig(n_waypoints=8))
    assert enc.hi[0, 0] == pytest.approx(2 * prob.direct_distance / 8)  # r_max = 2‖SG‖/n
    assert enc.hi[0, 1] == pytest.approx(np.radians(15.0))  # min(π/4, max climb 15°)
    assert enc.lo[0, 2] == pytest.approx(np.pi / 4 - np.pi / 4)  # S→G bearing 45° ± 45°
    assert enc.hi[0, 2] == pytest.approx(np.pi / 2)
    full = make_encoding(prob, SPSOConfig(direction="full"))
    assert full.lo[0, 2] == pytest.approx(-np.pi) and full.hi[0, 2] == pytest.approx(np.pi)
    fly = make_encoding(prob, SPSOConfig(flyability_bound=True))
    veh = sc.vehicle
    assert fly.lo[0, 0] == pytest.approx(2 * veh.min_turn_radius * np.sin(veh.max_turn))
    # warm-start encoding round-trips a decoded swarm
    x = enc.sample(np.random.default_rng(0), 4)
    np.testing.assert_allclose(enc.encode(enc.decode(x)), x, atol=1e-9)


SMALL = ["planner.pso.n_pop=60", "planner.pso.max_iter=40", "planner.roadmap.enabled=false"]  # paper SPSO variants


@pytest.mark.parametrize("variant", [
    [], ["planner.pso.encoding=\"cartesian\""], ["planner.pso.direction=\"full\""],
    ["planner.pso.reflection=false"], ["planner.pso.damping=false"], ["planner.pso.inertia=\"adaptive\""],
])
def test_same_seed_same_plan_for_every_variant(rescue_static, variant) -> None:
    sc = load_scenario(rescue_static, SMALL + variant + ['planner.algorithm="spso"'])
    prob = problem_from_scenario(sc)
    a = plan(prob, sc.planner, np.random.default_rng(5))
    b = plan(prob, sc.planner, np.random.default_rng(5))
    c = plan(prob, sc.planner, np.random.default_rng(6))
    assert np.array_equal(a.waypoints, b.waypoints)
    assert a.optimiser.history == b.optimiser.history
    assert not np.array_equal(a.waypoints, c.waypoints)
    h = np.asarray(a.optimiser.history)
    assert np.all(np.diff(h) <= 0)  # the global best never gets worse
    assert h[-1] < h[0]  # and the search improved on its initial best


def test_rescue_static_full_budget_is_feasible(rescue_static) -> None:
    sc = load_scenario(rescue_static, ['planner.algorithm="spso"'])
    prob = problem_from_scenario(sc)
    res = plan(prob, sc.planner, np.random.default_rng(1))
    assert res.status is PlanStatus.EXACT
    assert all(v == 0 for v in res.violations.values())
    assert res.trajectory.length <= 1.3 * prob.direct_distance
    assert res.optimiser.iterations <= sc.planner.pso.max_iter


def test_stagnation_and_budget_stop_early(rescue_static) -> None:
    sc = load_scenario(rescue_static, ["planner.pso.n_pop=50", "planner.pso.stagnation_iters=5"])
    res = SphericalPSO(sc.planner.pso).run(problem_from_scenario(sc), np.random.default_rng(0))
    assert res.stop_reason == "stagnation" and res.iterations < sc.planner.pso.max_iter
    timed = SphericalPSO(sc.planner.pso).run(problem_from_scenario(sc), np.random.default_rng(0),
                                             deadline=Deadline.after(0.0))
    assert timed.stop_reason == "timeout" and timed.iterations == 0  # issue 16: no iteration past the budget


def test_warm_start_seeds_the_swarm(rescue_static) -> None:
    sc = load_scenario(rescue_static, ["planner.pso.n_pop=40", "planner.pso.max_iter=1"])
    prob = problem_from_scenario(sc)
    full = load_scenario(rescue_static, ['planner.algorithm="spso"', "planner.roadmap.enabled=false"])
    good = plan(problem_from_scenario(full), full.planner, np.random.default_rng(1)).waypoints
    cold = SphericalPSO(sc.planner.pso).run(prob, np.random.default_rng(3))
    warm = SphericalPSO(sc.planner.pso).run(prob, np.random.default_rng(3), initial_paths=good[None])
    assert warm.history[0] <= prob.evaluate(good[None]).total[0] + 1e-6
    assert warm.history[0] < cold.history[0]


def test_cost_alone_equals_cost_in_swarm_with_many_obstacles() -> None:
    """100 obstacles (≥ 8 per family, where numpy's pairwise summation would kick in): a path costs the
    same, bit for bit, alone or inside a swarm of any size."""
    sc = load_scenario(Path(__file__).resolve().parents[3] / "sitl_scenarios" / "large_obstacle_field.toml")
    prob = problem_from_scenario(sc)
    enc = make_encoding(prob, sc.planner.pso)
    paths = enc.decode(enc.sample(np.random.default_rng(3), 37))
    batch = prob.evaluate(paths).total
    for i in (0, 5, 36):
        assert prob.evaluate(paths[i : i + 1]).total[0] == batch[i]
        assert prob.evaluate(paths[i : i + 2]).total[0] == batch[i]


def test_warm_start_accepts_paths_with_another_point_count(rescue_static) -> None:
    """A merged plan or an old route with fewer points is resampled along its length before seeding."""
    from planner.search.encoding import resample_paths

    sc = load_scenario(rescue_static, ["planner.pso.n_pop=20", "planner.pso.max_iter=1"])
    prob = problem_from_scenario(sc)
    enc = make_encoding(prob, sc.planner.pso)
    short = np.array([[prob.start, [300.0, 600.0, 80.0], prob.goal]])
    res = resample_paths(short, enc.n + 2)
    assert res.shape == (1, enc.n + 2, 3)
    np.testing.assert_allclose(res[0, [0, -1]], short[0, [0, -1]])
    gaps = np.linalg.norm(np.diff(res[0], axis=0), axis=1)
    np.testing.assert_allclose(gaps, gaps.mean(), rtol=0.35)  # evenly spread along the length
    seeded = SphericalPSO(sc.planner.pso).run(prob, np.random.default_rng(0), initial_paths=short)
    assert seeded.history[0] <= prob.evaluate(enc.decode(enc.encode(short))).total[0] + 1e-9


def test_a_swarm_asked_for_a_safe_route_stops_once_its_best_has_been_feasible_for_the_iterations_asked(
        rescue_static) -> None:
    """pso.feasible_iters (a replan's early stop): the search ends that many iterations after its best became
    feasible, and not before; 0 leaves the search as it was."""
    sc = load_scenario(rescue_static, ["planner.pso.n_pop=300", "planner.pso.feasible_iters=4"])
    prob = problem_from_scenario(sc)
    res = SphericalPSO(sc.planner.pso).run(prob, np.random.default_rng(0))
    assert res.stop_reason == "feasible"
    assert int(res.evaluation.n_violations[0]) == 0
    assert res.state is not None and res.state.feasible == 4  # feasible for exactly the last 4 iterations
    off = load_scenario(rescue_static, ["planner.pso.n_pop=300"])
    full = SphericalPSO(off.planner.pso).run(prob, np.random.default_rng(0))
    assert full.stop_reason != "feasible" and full.iterations > res.iterations
    # the same search until it stopped: the stop changes when, not what
    assert full.history[: res.iterations + 1] == res.history
