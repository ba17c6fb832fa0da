"""ACO refinement and the fusion: GKDM / hard / uniform initialisation, ant construction, deposits,
and the fusion's guarantee never to be worse than its own SPSO phase (docs/method.md §9)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from planner.plan import PlanStatus, plan, problem_from_scenario
from planner.search.aco import AntColony, build_lattice, colony_graph, construct, deposit, initial_pheromone
from planner.search.fusion import Fusion
from planner.world.config import ACOConfig
from planner.world.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[3] / "sitl_scenarios"
SIGMA = 40.0


def _straight_route(n: int = 6) -> np.ndarray:
    x = np.linspace(0.0, 700.0, n + 2)
    return np.stack([x, np.full_like(x, 500.0), np.full_like(x, 150.0)], axis=-1)


def _uniform_lattice_cfg(**kw) -> ACOConfig:
    # uniform lattice with one cross step = σ, so the edge between the +1 nodes of two layers runs
    # parallel to the route at exactly σ
    return ACOConfig(cross_step=SIGMA, lattice_growth=1.0, cross_half=5, vert_half=1, vert_step=10.0, **kw)


def test_gkdm_field_peaks_on_route_falls_by_exp_half_at_sigma_and_is_tau0_far_away() -> None:
    cfg = _uniform_lattice_cfg()
    lat = build_lattice(_straight_route(), cfg)
    tau = initial_pheromone(lat, cfg, "gkdm")
    c = lat.centre
    idx = {tuple(o): i for i, o in enumerate(lat.offsets.tolist())}
    interior = slice(1, lat.n_layers - 2)  # edges between two interior layers
    peak = cfg.tau0 * (1 + cfg.amplitude)
    np.testing.assert_allclose(tau[interior, c, c], peak, rtol=1e-12)  # 1.3 on the PSO route
    assert tau.max() == pytest.approx(peak)
    one = idx[(1, 0)]
    expect = cfg.tau0 * (1 + cfg.amplitude * np.exp(-0.5))
    np.testing.assert_allclose(tau[interior, one, one], expect, rtol=1e-12)  # at distance σ
    far = idx[(5, 0)]  # 5σ = 200 m away
    np.testing.assert_allclose(tau[interior, far, far], cfg.tau0, rtol=1e-4)
    assert tau.min() >= cfg.tau0


def test_hard_raises_only_the_route_edges_and_uniform_is_flat() -> None:
    cfg = _uniform_lattice_cfg()
    lat = build_lattice(_straight_route(), cfg)
    hard = initial_pheromone(lat, cfg, "hard")
    c = lat.centre
    np.testing.assert_allclose(hard[:, c, c], cfg.tau0 + cfg.hard_boost)
    mask = np.ones_like(hard, dtype=bool)
    mask[:, c, c] = False
    assert np.all(hard[mask] == cfg.tau0)
    uniform = initial_pheromone(lat, cfg, "uniform")
    assert np.all(uniform == cfg.tau0)


def test_lattice_centre_is_the_seed_route_and_offsets_are_geometric() -> None:
    cfg = ACOConfig()
    route = _straight_route()
    lat = build_lattice(route, cfg)
    np.testing.assert_array_equal(lat.nodes[:, lat.centre], route)
    across = sorted({round(float(y) - 500.0, 9) for y in lat.nodes[1, :, 1]})
    assert across == [-31.0, -15.0, -7.0, -3.0, -1.0, 0.0, 1.0, 3.0, 7.0, 15.0, 31.0]


def test_ants_follow_a_dominant_trail_and_deposits_land_on_their_edges(rescue_static) -> None:
    sc = load_scenario(rescue_static)
    prob = problem_from_scenario(sc)
    cfg = dataclasses.replace(sc.planner.aco, n_ants=16)
    route = np.linspace(prob.start, prob.goal, 10)
    lat = build_lattice(route, cfg)
    graph = colony_graph(lat, prob, cfg)
    tau = np.full((lat.n_layers - 1, lat.nodes.shape[1], lat.nodes.shape[1]), 1e-9)
    tau[:, lat.centre, lat.centre] = 1e9
    choice = construct(lat, graph, tau, cfg, np.random.default_rng(0))
    assert choice.shape == (16, lat.n_layers)
    assert np.all(choice == lat.centre)
    tau0 = np.zeros_like(tau)
    deposit(tau0, choice[:2], np.array([1.0, 2.0]))
    assert tau0[:, lat.centre, lat.centre].tolist() == [3.0] * (lat.n_layers - 1)
    assert tau0.sum() == pytest.approx(3.0 * (lat.n_layers - 1))


@pytest.mark.parametrize("update", ["classic", "enhanced"])
def test_colony_is_deterministic_and_never_worse_than_its_seed(rescue_static, update) -> None:
    sc = load_scenario(rescue_static, ["planner.pso.n_pop=60", "planner.pso.max_iter=30"])
    prob = problem_from_scenario(sc)
    seed = plan(prob, dataclasses.replace(sc.planner, algorithm="spso"), np.random.default_rng(2))
    seed_path = seed.optimiser.path
    cfg = dataclasses.replace(sc.planner.aco, update=update, max_iter=15)
    a = AntColony(cfg).run(prob, np.random.default_rng(7), seed_path, seed.optimiser.cost)
    b = AntColony(cfg).run(prob, np.random.default_rng(7), seed_path, seed.optimiser.cost)
    assert np.array_equal(a.path, b.path) and a.history == b.history
    assert a.cost <= seed.optimiser.cost
    assert np.all(np.diff(a.history) <= 0)
    assert a.path.shape == seed_path.shape


def test_fusion_never_worse_than_its_spso_phase_over_many_seeds(rescue_static) -> None:
    sc = load_scenario(rescue_static, ["planner.roadmap.enabled=false", "planner.pso.n_pop=60",
                                       "planner.pso.max_iter=40", "planner.aco.max_iter=20"])
    prob = problem_from_scenario(sc)
    improved = 0
    for seed in range(12):
        res = Fusion(sc.planner).run(prob, np.random.default_rng(seed))
        pso, aco = res.phases["pso"], res.phases["aco"]
        assert res.cost <= pso.best_cost
        assert res.cost == min(pso.best_cost, aco.best_cost)
        assert len(res.history) == pso.iterations + 1 + aco.iterations
        assert res.history[pso.iterations] == pso.best_cost
        assert np.all(np.diff(res.history) <= 0)
        improved += res.winner == "aco"
    assert improved >= 1  # with a short SPSO phase the colony does find better routes


@pytest.mark.parametrize("name", ["rescue_static", "large_obstacle_field"])
def test_fusion_full_budget_feasible_with_zero_violations(name) -> None:
    sc = load_scenario(SCENARIOS / f"{name}.toml")
    assert sc.planner.algorithm == "fusion"
    prob = problem_from_scenario(sc)
    res = plan(prob, sc.planner, np.random.default_rng(sc.planner.seed))
    assert res.status is PlanStatus.EXACT
    assert not any(res.violations.values()) and not any(res.cost_violations.values())
    assert {"pso", "aco"} <= res.optimiser.phases.keys()
