"""Benchmarks (pytest-benchmark). Off by default (runs once as a test); measure with
``pytest tests/planner/bench/test_benchmark.py --benchmark-enable``. Speed targets live in the README, not in
asserts."""

from __future__ import annotations

import numpy as np

from planner.plan import plan, problem_from_scenario
from planner.world.scenario import load_scenario

TABLE6 = ["planner.pso.n_pop=500", "planner.pso.max_iter=200", "planner.pso.stagnation_iters=200"]
SPSO = ['planner.algorithm="spso"']


def test_bench_spso_table6_rescue_static(benchmark, rescue_static) -> None:
    """One full Table-6 run (nPop 500, MaxIt 200) on rescue_static; target ≤ 0.5 s median on one core."""
    sc = load_scenario(rescue_static, TABLE6 + SPSO)
    prob = problem_from_scenario(sc)
    res = benchmark.pedantic(lambda: plan(prob, sc.planner, np.random.default_rng(1)), rounds=5, iterations=1)
    assert res.optimiser.iterations == 200
    assert res.optimiser.evaluations == 500 * 201
    assert res.feasible


def test_bench_fusion_time_split(benchmark, rescue_static) -> None:
    """Fusion at Tables 6/7 defaults: SPSO until its switch criterion, then 30 ants × up to 50 iterations.
    Target: the ACO phase adds ≤ 50 % to the SPSO phase's time. The split goes into extra_info."""
    sc = load_scenario(rescue_static)
    assert sc.planner.algorithm == "fusion"
    prob = problem_from_scenario(sc)
    res = benchmark.pedantic(lambda: plan(prob, sc.planner, np.random.default_rng(1)), rounds=5, iterations=1)
    pso, aco = res.optimiser.phases["pso"], res.optimiser.phases["aco"]
    benchmark.extra_info.update(pso_s=pso.time_s, aco_s=aco.time_s, aco_over_pso=aco.time_s / pso.time_s)
    assert pso.iterations > 0 and aco.iterations > 0
    assert res.cost <= pso.best_cost
