"""Baseline optimisers of the fusion comparison (PSO, QPSO, PSOGSA, BPSO): determinism, improvement,
warm start, and their update rules by hand."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from planner.deadline import Deadline
from planner.plan import problem_from_scenario
from planner.search.baselines.bpso import BPSO, bpso_step, gray_to_index, index_to_gray, make_lattice
from planner.search.baselines.cartesian_pso import CartesianPSO
from planner.search.baselines.psogsa import PSOGSA, gravity, gsa_acceleration, masses
from planner.search.baselines.qpso import QPSO, qpso_beta, qpso_step
from planner.search.spso import SphericalPSO
from planner.world.config import BPSOConfig, PSOGSAConfig, QPSOConfig
from planner.world.scenario import load_scenario

OPTIMISERS = {"pso": CartesianPSO, "qpso": QPSO, "psogsa": PSOGSA, "bpso": BPSO}


@pytest.fixture(scope="module")
def rescue():
    sc = load_scenario(Path(__file__).resolve().parents[3] / "sitl_scenarios" / "rescue_static.toml")
    small = dataclasses.replace(sc.planner.pso, n_pop=60, max_iter=30)
    return problem_from_scenario(sc), small


@pytest.mark.parametrize("name", list(OPTIMISERS))
def test_same_seed_same_path_and_the_search_improves(rescue, name) -> None:
    prob, pso = rescue
    opt = OPTIMISERS[name](pso)
    a = opt.run(prob, np.random.default_rng(5))
    b = opt.run(prob, np.random.default_rng(5))
    c = opt.run(prob, np.random.default_rng(6))
    assert np.array_equal(a.path, b.path) and a.history == b.history
    assert not np.array_equal(a.path, c.path)
    assert a.path.shape == (pso.n_waypoints + 2, 3)
    assert np.array_equal(a.path[0], prob.start) and np.array_equal(a.path[-1], prob.goal)
    h = np.asarray(a.history)
    assert len(h) == a.iterations + 1 and a.stop_reason == "max_iterations"
    assert np.all(np.diff(h) <= 0) and h[-1] < h[0]
    assert a.cost == h[-1] == a.evaluation.total[0] == prob.evaluate(a.path[None]).total[0]
    assert a.evaluations == pso.n_pop * (a.iterations + 1)


@pytest.mark.parametrize("name", list(OPTIMISERS))
def test_budget_and_stagnation_stop(rescue, name) -> None:
    prob, pso = rescue
    timed = OPTIMISERS[name](pso).run(prob, np.random.default_rng(0), deadline=Deadline.after(0.0))
    # a spent budget stops before the first iteration (issue 16: no iteration starts that would overrun it)
    assert timed.stop_reason == "timeout" and timed.iterations == 0 and len(timed.history) == 1
    flat = OPTIMISERS[name](dataclasses.replace(pso, stagnation_iters=1)).run(prob, np.random.default_rng(0))
    assert flat.stop_reason == "stagnation" and flat.iterations < pso.max_iter
    assert flat.history[-1] == flat.history[-2]


@pytest.mark.parametrize("name", list(OPTIMISERS))
def test_warm_start_seeds_the_swarm(rescue, name) -> None:
    prob, pso = rescue
    good = SphericalPSO(pso).run(prob, np.random.default_rng(1)).path
    opt = OPTIMISERS[name](dataclasses.replace(pso, max_iter=1))
    warm = opt.run(prob, np.random.default_rng(3), initial_paths=good[None])
    cold = opt.run(prob, np.random.default_rng(3))
    if name == "bpso":  # the seed snaps to its nearest lattice cells
        lat = opt.lattice(prob)
        good = lat.decode(lat.encode(good[None]))[0]
    assert warm.history[0] <= prob.evaluate(good[None]).total[0]
    assert warm.history[0] < cold.history[0]


def test_qpso_beta_falls_linearly_over_the_run() -> None:
    cfg = QPSOConfig()
    assert qpso_beta(cfg, 0, 200) == cfg.beta_start == 1.0
    assert qpso_beta(cfg, 199, 200) == pytest.approx(cfg.beta_end)
    assert qpso_beta(cfg, 99, 199) == pytest.approx(0.5 * (cfg.beta_start + cfg.beta_end))
    assert qpso_beta(cfg, 0, 1) == cfg.beta_end  # a one-iteration run uses the final value


def test_qpso_step_by_hand() -> None:
    # two particles, one waypoint; mbest = mean of pbests = (1, 2, 3)
    x = np.array([[[0.0, 0.0, 0.0]], [[4.0, 4.0, 4.0]]])
    pbest = np.array([[[0.0, 2.0, 2.0]], [[2.0, 2.0, 4.0]]])
    gbest = np.array([[2.0, 2.0, 4.0]])
    phi = np.full_like(x, 0.5)
    u = np.full_like(x, math.exp(-1.0))  # ln(1/u) = 1
    coin = np.array([[[1, 0, 1]], [[0, 0, 1]]])
    lo, hi = np.full((1, 3), -10.0), np.full((1, 3), 10.0)
    out = qpso_step(x, pbest, gbest, 0.5, lo, hi, phi, u, coin)
    # p0 = (1, 2, 3), |mbest − x0| = (1, 2, 3): x0 = p ± 0.5 (1, 2, 3) = (1.5, 1, 4.5)
    # p1 = (2, 2, 4), |mbest − x1| = (3, 2, 1): x1 = (2 − 1.5, 2 − 1, 4 + 0.5)
    np.testing.assert_allclose(out, [[[1.5, 1.0, 4.5]], [[0.5, 1.0, 4.5]]])
    assert np.all(qpso_step(x, pbest, gbest, 50.0, lo, hi, phi, u, coin) <= 10.0)  # clamped


def test_psogsa_gravity_and_masses() -> None:
    cfg = PSOGSAConfig()
    assert gravity(cfg, 0, 200) == cfg.g0
    assert gravity(cfg, 200, 200) == pytest.approx(cfg.g0 * math.exp(-cfg.alpha))
    m = masses(np.array([3.0, 1.0, 2.0, 5.0]))
    assert m.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(m, np.array([0.5, 1.0, 0.75, 0.0]) / 2.25)  # best heaviest, worst 0
    np.testing.assert_array_equal(masses(np.full(4, 7.0)), np.full(4, 0.25))  # flat swarm: equal


def test_psogsa_acceleration_matches_the_pairwise_sum() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(500.0, 100.0, (7, 6))
    mass = masses(rng.random(7))
    r = rng.random((7, 7))
    expect = np.zeros_like(x)
    for i in range(7):  # the definition, one pair at a time
        for j in range(7):
            dist = np.linalg.norm(x[j] - x[i])
            expect[i] += r[i, j] * 0.3 * mass[j] * (x[j] - x[i]) / (dist + 1e-9)
    np.testing.assert_allclose(gsa_acceleration(x, mass, 0.3, r), expect, rtol=1e-7, atol=1e-9)


def test_gray_code_round_trip_and_neighbours_one_flip_apart() -> None:
    idx = np.arange(32)
    bits = index_to_gray(idx, 5)
    np.testing.assert_array_equal(gray_to_index(bits), idx)
    assert np.all(np.abs(np.diff(bits, axis=0)).sum(axis=1) == 1)


def test_bpso_decode_bits_corners_and_geometry(rescue) -> None:
    prob, pso = rescue
    cfg = BPSOConfig()
    lat = make_lattice(prob, pso.n_waypoints, cfg)
    n, c, a = pso.n_waypoints, 2**cfg.bits_cross, 2**cfg.bits_alt
    assert lat.cells.shape == (n, c, a, 3)
    zeros = np.zeros((1, n, lat.n_bits))
    far = np.zeros((1, n, lat.n_bits))
    far[..., 0] = far[..., cfg.bits_cross] = 1.0  # Gray 100…0 is the last cell of each group
    np.testing.assert_array_equal(lat.decode_bits(zeros)[0, 1:-1], lat.cells[:, 0, 0])
    np.testing.assert_array_equal(lat.decode_bits(far)[0, 1:-1], lat.cells[:, -1, -1])
    ones = lat.decode_bits(np.ones((1, n, lat.n_bits)))[0, 1:-1]  # Gray 11111 = 21, 1111 = 10
    np.testing.assert_array_equal(ones, lat.cells[:, 21, 10])
    env = prob.env
    assert lat.cells[..., 2].min() == env.z_min and lat.cells[..., 2].max() == env.z_max  # flat ground
    sg = prob.goal - prob.start
    half = cfg.corridor_frac * prob.direct_distance
    k = 4  # waypoint 4 of 8: its corridor ends stay inside the region, nothing is clipped
    base = prob.start + k / (n + 1) * sg
    for end in (lat.cells[k - 1, 0, 0], lat.cells[k - 1, -1, 0]):
        off = end[:2] - base[:2]
        assert np.linalg.norm(off) == pytest.approx(half)
        assert off @ sg[:2] == pytest.approx(0.0, abs=1e-6)  # cross-track: perpendicular to S→G
    inside = lat.cells[..., :2]
    assert inside.min() >= 0.0 and inside[..., 0].max() <= env.size_x and inside[..., 1].max() <= env.size_y
    # encoding picks the nearest cell: decoding it again gives the same path
    paths = lat.decode_bits(lat.sample(np.random.default_rng(2), 5))
    np.testing.assert_array_equal(lat.decode_bits(lat.encode(paths)), paths)


def test_bpso_step_by_hand() -> None:
    x = np.array([[[0.0, 1.0, 1.0]]])
    v = np.array([[[3.0, -1.0, 0.0]]])
    pbest = np.array([[[1.0, 1.0, 0.0]]])
    gbest = np.array([[1.0, 0.0, 0.0]])
    r = np.full_like(x, 0.5)
    u = np.full_like(x, 0.5)
    bits, v1 = bpso_step(x, v, pbest, gbest, 1.0, 1.5, 1.5, 4.0, r, r, u)
    # v + 0.75 (pbest − x) + 0.75 (gbest − x) = (3 + 1.5, −1 − 0.75, −1.5) → (4 clamped, −1.75, −1.5)
    np.testing.assert_allclose(v1, [[[4.0, -1.75, -1.5]]])
    np.testing.assert_array_equal(bits, [[[1.0, 0.0, 0.0]]])  # sigmoid > ½ ⇔ v > 0



def test_psogsa_plans_the_same_whatever_the_blas_threads(rescue) -> None:
    """PSOGSA's gravity is a matrix product, whose last bits depend on BLAS's thread count (they do here at these
    sizes): the run pins BLAS to one thread itself, so a seed's plan does not depend on the core count, a process
    pool or a dask worker (which pins BLAS to one thread)."""
    from threadpoolctl import threadpool_limits

    prob, pso = rescue
    opt = PSOGSA(dataclasses.replace(pso, n_pop=300, max_iter=100, stagnation_iters=100))
    runs = []
    for threads in (1, 2):
        with threadpool_limits(limits=threads, user_api="blas"):
            runs.append(opt.run(prob, np.random.default_rng(3)))
    assert runs[0].history == runs[1].history and np.array_equal(runs[0].path, runs[1].path)
