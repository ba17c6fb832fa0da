"""The roadmap of the static world, the guide-relative encoding, the colony on the roadmap and the roadmap
pipeline of the fusion (docs/method.md §15)."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.sparse.csgraph import dijkstra

from planner.bench import hardmaps
from planner.plan import PlanStatus, plan, problem_from_scenario
from planner.problem import PlanningProblem
from planner.search import roadmap as rmap
from planner.search.encoding import guided_encoding, make_encoding, resample_keeping_vertices
from planner.search.roadmap_colony import DETOUR_SCALE, adjacency, gkdm_pheromone, walk
from planner.trajectory.checks import obstacle_clearance
from planner.world.config import ACOConfig, HazardConfig, PlannerSettings, RoadmapConfig, SPSOConfig, VehicleLimits
from planner.world.environment import Cylinders, Environment, Threat, Threats
from planner.world.scenario import load_scenario

VEHICLE = VehicleLimits()
HAZARD = HazardConfig(d_safe=60.0, d_coll=15.0)
CFG = RoadmapConfig(enabled=True)


def _cylinders(*rows: tuple[float, float, float]) -> Cylinders:
    a = np.array(rows, dtype=float).reshape(-1, 3)
    return Cylinders(a[:, 0], a[:, 1], a[:, 2], np.full(len(a), np.inf), np.zeros(len(a)))


def _problem(cyl: Cylinders, start=(100.0, 500.0, 120.0), goal=(1100.0, 500.0, 120.0), size=(1200.0, 1000.0),
             threats: Threats | None = None, start_time: float | None = None) -> PlanningProblem:
    env = Environment(size[0], size[1], 50.0, 300.0, cylinders=cyl, threats=threats or Threats())
    return PlanningProblem(env, np.array(start), np.array(goal), VEHICLE, HAZARD, start_time=start_time)


def _densify(route: np.ndarray, step: float = 2.0) -> np.ndarray:
    return rmap.densify(route, step)


# --- roadmap ------------------------------------------------------------------------------------------------
def test_every_node_and_edge_keeps_the_roadmaps_clearance_band_and_climb() -> None:
    pb = _problem(_cylinders((600.0, 500.0, 150.0), (300.0, 250.0, 60.0)))
    rm = rmap.build(pb, CFG)
    need = HAZARD.d_coll + VEHICLE.acceptance_radius / 2 + CFG.margin
    assert rm.need == pytest.approx(need)
    # nodes, independently of the roadmap's own slack
    assert (obstacle_clearance(rm.nodes, None, pb.env) >= need - 1e-9).all()
    # edges: dense samples of every edge (a Lipschitz-cleared edge too)
    a, b = rm.nodes[rm.edges[:, 0]], rm.nodes[rm.edges[:, 1]]
    t = np.linspace(0.0, 1.0, 21)[:, None, None]
    pts = (a[None] + t * (b - a)[None]).reshape(-1, 3)
    assert (obstacle_clearance(pts, None, pb.env) >= need - 1e-6).all()
    assert ((pts[:, 2] >= pb.env.z_min) & (pts[:, 2] <= pb.env.z_max)).all()
    horiz = np.hypot(*(b - a)[:, :2].T)
    assert (np.abs(b[:, 2] - a[:, 2]) <= horiz * math.tan(CFG.climb_share * VEHICLE.max_climb) + 1e-9).all()
    assert len(np.unique(rm.nodes[:, 2])) > 1  # several levels, joined by climbing edges
    assert (np.abs(b[:, 2] - a[:, 2]) > 0).any()


def test_a_wall_across_the_map_leaves_no_route_and_the_plan_says_at_which_resolution() -> None:
    ys = np.arange(0.0, 1001.0, 50.0)
    pb = _problem(_cylinders(*[(600.0, y, 40.0) for y in ys]))
    rm = rmap.build(pb, CFG)
    assert rmap.diverse_routes(rm, pb, CFG) == []
    settings = PlannerSettings(roadmap=CFG, pso=SPSOConfig(n_pop=30, max_iter=10))
    res = plan(pb, settings, np.random.default_rng(0))
    assert res.status is PlanStatus.INFEASIBLE
    # none at the roadmap's spacing, without its margin, nor at half the spacing: the plan names the finest
    assert res.optimiser.phases["roadmap"].stop_reason == f"no route at {0.5 * rm.spacing:.0f} m resolution"
    assert {"pso", "aco"} <= res.optimiser.phases.keys()  # then the paper's fusion ran


def test_diverse_routes_take_both_sides_of_a_central_obstacle_and_keep_clear() -> None:
    pb = _problem(_cylinders((600.0, 500.0, 150.0)))
    routes = rmap.diverse_routes(rmap.build(pb, CFG), pb, CFG)
    assert len(routes) >= 2
    sides = {np.sign(np.interp(600.0, r[:, 0], r[:, 1]) - 500.0) for r in routes[:2]}
    assert sides == {-1.0, 1.0}
    for r in routes:
        np.testing.assert_array_equal(r[0], pb.start)
        np.testing.assert_array_equal(r[-1], pb.goal)
        assert obstacle_clearance(_densify(r), None, pb.env).min() >= HAZARD.d_coll


def test_a_moving_threat_raises_edge_weights_where_the_vehicle_would_meet_it_not_the_graph() -> None:
    cyl = _cylinders((600.0, 150.0, 40.0))
    # a threat that sits on the straight line while the vehicle would pass there (600 m at 18 m/s ≈ 28 s)
    threat = Threat("t1", "loiter", 60.0, (600.0, 500.0, 120.0), circle_radius=1.0, speed=0.1)
    pb = _problem(cyl, threats=Threats([threat]), start_time=0.0)
    static = dataclasses.replace(pb, env=dataclasses.replace(pb.env, threats=Threats()), start_time=None)
    rm = rmap.cached(pb, CFG)
    assert rmap.cached(static, CFG) is rm  # the same static world: the same roadmap, no rebuild
    straight = rmap.diverse_routes(rm, static, CFG)[0]
    dodging = rmap.diverse_routes(rm, pb, CFG)[0]
    assert abs(np.interp(600.0, straight[:, 0], straight[:, 1]) - 500.0) < 60.0
    pts = _densify(dodging)
    assert np.linalg.norm(pts[:, :2] - [600.0, 500.0], axis=1).min() > 60.0 + HAZARD.d_coll


def test_timed_weights_block_every_edge_a_moving_threat_comes_near_as_the_vehicle_flies_it() -> None:
    """timed_weights bounds an edge's clearance from one threat position per end node: every edge that a dense
    sampling (the vehicle flying from the earlier end at cruise speed, or between its ends' times; the threats
    where they are then) finds within the roadmap's clearance of a loiter, patrol or track threat (a growing
    track radius too) is blocked, and the bound leaves edges far from the threats' meeting points unblocked."""
    threats = Threats([
        Threat("l", "loiter", 50.0, (500.0, 450.0, 120.0), circle_radius=150.0, speed=20.0),
        Threat("p", "patrol", 40.0, (300.0, 100.0, 150.0), p1=(900.0, 900.0, 150.0), speed=25.0),
        Threat("t", "track", 30.0, (1100.0, 200.0, 120.0), p1=(-15.0, 10.0, 0.0), radius_growth=1.0)])
    pb = _problem(_cylinders((600.0, 150.0, 40.0)), threats=threats, start_time=3.0)
    rm = rmap.cached(pb, CFG)
    q = rmap.attach(rm, pb, CFG)
    base = rmap.clearance_weights(q, pb)
    blocked = rmap.timed_weights(q, pb, base) > base
    dist = dijkstra(q.graph(base), indices=q.start)
    v = VEHICLE.cruise_speed
    t_node = 3.0 + dist / v
    a, b = q.points[q.edges[:, 0]], q.points[q.edges[:, 1]]
    first = t_node[q.edges[:, 0]] <= t_node[q.edges[:, 1]]
    p0, p1 = np.where(first[:, None], a, b), np.where(first[:, None], b, a)
    t0 = np.minimum(t_node[q.edges[:, 0]], t_node[q.edges[:, 1]])
    flight = {"cruise": q.length / v, "between node times": np.abs(t_node[q.edges[:, 0]] - t_node[q.edges[:, 1]])}
    near = np.zeros(len(q.edges), dtype=bool)
    for duration in flight.values():
        for f in np.linspace(0.0, 1.0, 21):
            t = t0 + f * duration
            d = np.linalg.norm(p0 + f * (p1 - p0) - threats.positions(t), axis=-1) - threats.radii(t)
            near |= (d < rm.need).any(axis=0)
    assert near.sum() > 100
    assert not (near & ~blocked).any()  # nothing the vehicle would meet is left open
    assert blocked.mean() < 0.5, blocked.mean()


# --- guide-relative encoding ----------------------------------------------------------------------------------
def test_with_the_straight_line_as_guide_the_encoding_is_the_papers() -> None:
    pb = _problem(_cylinders((600.0, 500.0, 150.0)), goal=(1000.0, 900.0, 200.0))
    cfg = SPSOConfig(n_waypoints=8)
    enc, pts = guided_encoding(pb, cfg, np.stack([pb.start, pb.goal]))
    paper = make_encoding(pb, cfg)
    np.testing.assert_allclose(enc.lo, paper.lo, rtol=0, atol=1e-12)
    np.testing.assert_allclose(enc.hi, paper.hi, rtol=0, atol=1e-12)
    np.testing.assert_allclose(pts, np.linspace(pb.start, pb.goal, 10), atol=1e-9)


def test_the_guide_is_a_particle_and_any_route_in_its_corridor_round_trips() -> None:
    pb = _problem(_cylinders((600.0, 500.0, 150.0)))
    guide = np.array([pb.start, [300.0, 800.0, 150.0], [700.0, 850.0, 180.0], [1000.0, 300.0, 130.0], pb.goal])
    enc, pts = guided_encoding(pb, SPSOConfig(n_waypoints=8), guide)
    for v in guide:  # vertices kept
        assert np.linalg.norm(pts - v, axis=1).min() < 1e-9
    x = enc.encode(pts[None])
    assert ((x >= enc.lo - 1e-12) & (x <= enc.hi + 1e-12)).all()
    np.testing.assert_allclose(enc.decode(x)[0], pts, atol=1e-9)
    sample = enc.sample(np.random.default_rng(3), 200)  # any route inside the corridor
    np.testing.assert_allclose(enc.encode(enc.decode(sample)), sample, atol=1e-9)
    # azimuth cones follow the guide, not the start→goal bearing (that one is 0 here)
    mid = 0.5 * (enc.lo[:, 2] + enc.hi[:, 2])
    assert np.degrees(np.abs(mid)).max() > 60.0


def test_resampling_keeps_vertices_and_spreads_points_by_leg_length() -> None:
    route = np.array([[0.0, 0, 0], [100.0, 0, 0], [100.0, 400.0, 0]])
    pts = resample_keeping_vertices(route, 7)
    assert len(pts) == 7
    np.testing.assert_array_equal(pts[[0, 2, 6]], route)  # 1 extra point on the short leg, 3 on the long one
    with pytest.raises(ValueError):
        resample_keeping_vertices(route, 2)


# --- the colony on the roadmap ----------------------------------------------------------------------------------
def test_ants_walk_from_start_to_goal_without_revisiting_and_follow_the_pheromone() -> None:
    pb = _problem(_cylinders((600.0, 500.0, 150.0)))
    rm = rmap.build(pb, CFG)
    q = rmap.attach(rm, pb, CFG)
    adj = adjacency(q)
    deg = np.bincount(q.edges.ravel(), minlength=len(q.points))
    assert ((adj.nbr >= 0).sum(axis=1) == deg).all()
    w = rmap.clearance_weights(q, pb)
    from scipy.sparse.csgraph import dijkstra

    to_goal = dijkstra(q.graph(w), indices=q.goal)
    routes = rmap.diverse_routes(rm, pb, CFG, q, w)
    side = np.sign(np.interp(600.0, routes[1][:, 0], routes[1][:, 1]) - 500.0)
    aco = ACOConfig()
    tau = gkdm_pheromone(q, [routes[1]], aco, rm.spacing)  # the second corridor is the swarm's best
    hops = int(to_goal[q.start] / rm.spacing) + 2

    def share_on_side(tau: np.ndarray) -> float:
        seq, arrived = walk(adj, tau, w, to_goal, DETOUR_SCALE * rm.spacing, q.start, q.goal, 60, 3 * hops, aco,
                            np.random.default_rng(0))
        assert arrived.mean() > 0.9
        on_side = []
        for s in seq[arrived]:
            nodes = s[s >= 0]
            assert len(np.unique(nodes)) == len(nodes) and nodes[0] == q.start and nodes[-1] == q.goal
            p = q.points[nodes]
            on_side.append(np.sign(np.interp(600.0, p[:, 0], p[:, 1]) - 500.0) == side)
        return float(np.mean(on_side))

    # the corridor GKDM marked draws more ants than it does on uniform pheromone
    assert share_on_side(tau) > share_on_side(np.full_like(tau, aco.tau0)) + 0.2


# --- the pipeline ------------------------------------------------------------------------------------------------
def test_roadmap_fusion_flies_a_gates_map_that_the_papers_fusion_cannot_and_is_reproducible(tmp_path) -> None:
    from planner.plan import problem_from_scenario
    from planner.world.scenario import load_scenario

    hm = hardmaps.generate("gates", 0, n_walls=3)
    path = tmp_path / "gates.toml"
    path.write_text(hm.toml)
    small = ["planner.pso.n_pop=100", "planner.pso.max_iter=60"]
    sc = load_scenario(path, [*small, "planner.roadmap.enabled=true"])
    pb = problem_from_scenario(sc)
    a = plan(pb, sc.planner, np.random.default_rng(5))
    b = plan(pb, sc.planner, np.random.default_rng(5))
    assert a.feasible, a.violations
    np.testing.assert_array_equal(a.waypoints, b.waypoints)
    phases = a.optimiser.phases
    assert set(phases) >= {"roadmap", "pso", "colony", "aco"}
    swarm_phases = [p for name, p in phases.items() if name != "roadmap"]
    assert a.optimiser.cost == min(p.best_cost for p in swarm_phases)  # the cheapest phase's route
    assert a.optimiser.winner in phases and np.all(np.diff(a.optimiser.history) <= 0)
    paper = load_scenario(path, [*small, "planner.roadmap.enabled=false"])
    assert not plan(problem_from_scenario(paper), paper.planner, np.random.default_rng(5)).feasible


def test_gkdm_pheromone_is_the_largest_weighted_kernel_over_the_elites() -> None:
    """τ = τ0 (1 + A max_k w_k exp(−d_k² / 2σ²)) per edge midpoint, d_k its distance to elite k's densified route
    (w = 1 for the best, ELITE_WEIGHT for the others): computed here elite by elite, held equal bit for bit to the
    colony's two queries (the best, then the others as one point set)."""
    from scipy.spatial import cKDTree

    from planner.search.roadmap_colony import ELITE_WEIGHT

    pb = _problem(_cylinders((600.0, 500.0, 150.0), (300.0, 300.0, 80.0)))
    rm = rmap.build(pb, CFG)
    q = rmap.attach(rm, pb, CFG)
    routes = rmap.diverse_routes(rm, pb, CFG, q, rmap.clearance_weights(q, pb))
    rng = np.random.default_rng(3)
    elites = [routes[0], *(r + rng.normal(0.0, 40.0, r.shape) * [1, 1, 0] for r in (routes[0], routes[1], routes[1]))]
    aco, sigma = ACOConfig(), rm.spacing
    mids = 0.5 * (q.points[q.edges[:, 0]] + q.points[q.edges[:, 1]])
    boost = np.zeros(len(mids))
    for k, route in enumerate(elites):
        d = cKDTree(rmap.densify(route, 0.5 * sigma)).query(mids)[0]
        boost = np.maximum(boost, (1.0 if k == 0 else ELITE_WEIGHT) * np.exp(-(d**2) / (2.0 * sigma**2)))
    expected = aco.tau0 * (1.0 + aco.amplitude * boost)
    assert np.array_equal(gkdm_pheromone(q, elites, aco, sigma), expected)
    assert np.array_equal(gkdm_pheromone(q, elites[:1], aco, sigma),
                          aco.tau0 * (1.0 + aco.amplitude * np.exp(-(cKDTree(rmap.densify(elites[0], 0.5 * sigma))
                                                                       .query(mids)[0] ** 2) / (2.0 * sigma**2))))
    assert expected.max() > aco.tau0 * (1.0 + 0.9 * aco.amplitude)  # edges on the best route get nearly all of it


def test_a_budgeted_plan_skips_a_roadmap_colony_whose_set_up_does_not_fit() -> None:
    """The colony's set-up (adjacency, GKDM over every edge) cannot be interrupted: with half the rest of the
    budget below its estimate the colony is not started; with room it is."""
    from planner.search.fusion import _affords_colony
    from planner.search.roadmap_colony import setup_s

    pb = _problem(_cylinders((600.0, 500.0, 150.0)))
    rm = rmap.build(pb, CFG)
    q = rmap.attach(rm, pb, CFG)
    need = setup_s(q)
    assert need > 0.0
    assert not _affords_colony(2.0 * need, q, 0.0)  # half of it is short of the estimate with its margin
    assert _affords_colony(max(3.0 * need, 0.06), q, 0.0)
    assert not _affords_colony(0.04, q, 0.0)  # below MIN_COLONY_BUDGET_S whatever the map


ROOT = Path(__file__).resolve().parents[3]


def test_a_roadmap_plan_asked_for_a_safe_route_skips_the_colonies_once_its_swarm_has_one() -> None:
    """A replan's settings (pso.feasible_iters): the guided swarm stops once its route has been feasible for that
    many iterations and the plan ends there, feasible, with no colony run; without it the colonies run."""
    sc = load_scenario(ROOT / "sitl_scenarios" / "rescue_dynamic.toml",
                       ["planner.roadmap.enabled=true", "planner.pso.n_pop=100", "planner.pso.feasible_iters=10"])
    prob = problem_from_scenario(sc)
    quick = plan(prob, sc.planner, np.random.default_rng(2))
    assert quick.status is PlanStatus.EXACT and quick.optimiser.stop_reason == "feasible"
    assert set(quick.optimiser.phases) == {"roadmap", "repair", "pso"}
    full_sc = load_scenario(ROOT / "sitl_scenarios" / "rescue_dynamic.toml",
                            ["planner.roadmap.enabled=true", "planner.pso.n_pop=100"])
    full = plan(prob, full_sc.planner, np.random.default_rng(2))
    assert "aco" in full.optimiser.phases and full.optimiser.phases["aco"].iterations > 0
    assert full.optimiser.evaluations > quick.optimiser.evaluations


def test_an_infeasible_pipeline_route_gives_way_to_the_papers_feasible_one(monkeypatch) -> None:
    """docs/method.md §15.6: when the pipeline's best route still fails and time is left, the paper's fusion runs
    and the better route is kept. The pipeline is made to return the straight line through rescue_static's
    cylinders; the paper's fusion flies round them, and its route is the plan, recorded as the winning phase."""
    from planner.search.fusion import Fusion, FusionResult, PhaseRecord

    sc = load_scenario(Path(__file__).parents[3] / "sitl_scenarios" / "rescue_static.toml")
    pb = problem_from_scenario(sc)
    straight = np.linspace(pb.start, pb.goal, 12)
    ev = pb.evaluate(straight[None])
    assert ev.n_violations[0] > 0

    def failing_pipeline(self, problem, rng, initial_paths, deadline, progress, t0):
        return FusionResult(straight, float(ev.total[0]), ev, [float(ev.total[0])], 1, "max_iterations", 0.01, 1,
                            None, {"roadmap": PhaseRecord(math.nan, 1, 0.01, 0, "1 routes at 25 m resolution"),
                                   "pso": PhaseRecord(float(ev.total[0]), 1, 0.01, 1, "max_iterations")}, "pso")

    monkeypatch.setattr(Fusion, "_run_roadmap", failing_pipeline)
    assert sc.planner.roadmap.enabled  # the default
    res = plan(pb, sc.planner, np.random.default_rng(0))
    assert res.feasible and res.optimiser.winner == "paper"
    assert {"roadmap", "pso", "paper", "paper/pso", "paper/aco"} <= set(res.optimiser.phases)
    assert res.cost < float(ev.total[0]) and not np.array_equal(res.waypoints, straight)
    # paper mode never runs it twice, and a spent deadline leaves the pipeline's route as it is
    from planner.deadline import Deadline

    late = plan(pb, sc.planner, np.random.default_rng(0), deadline=Deadline.after(1e-6))
    assert "paper" not in late.optimiser.phases and not late.feasible


def test_no_attachment_or_guide_leg_crosses_a_ridge_above_the_band() -> None:
    """The straight start→goal edge over a ridge that rises above the band (with a pass at one side) is no
    attachment: the guide goes through the pass, and every leg of it stays in the band over the ground, exactly
    (issue 34: on the saddle maps the guide was the straight line over the crest)."""
    from planner.world.terrain import Terrain

    xs = np.arange(0.0, 1201.0, 20.0)
    ys = np.arange(0.0, 1001.0, 20.0)
    gx, gy = np.meshgrid(xs, ys)
    ridge = 600.0 * np.exp(-((gx - 600.0) / 60.0) ** 2)  # a ridge across the map at x = 600, 600 m high
    ridge *= 1.0 - np.exp(-((gy - 850.0) / 70.0) ** 2)  # with a pass at y = 850
    env = Environment(1200.0, 1000.0, 30.0, 200.0, terrain=Terrain(0.0, 0.0, 20.0, 20.0, ridge))
    pb = PlanningProblem(env, np.array([100.0, 300.0, 80.0]), np.array([1100.0, 300.0, 80.0]), VEHICLE, HAZARD)
    assert env.band_depth(pb.start[None], pb.goal[None])[0] > 100.0  # the straight line is far below the crest
    q = rmap.attach(rmap.build(pb, CFG), pb, CFG)
    n = q.roadmap.n_nodes
    assert not np.any((q.edges[:, 0] == n) & (q.edges[:, 1] == n + 1))
    _, _, _, routes, _ = rmap.routes(pb, CFG)
    assert routes
    guide = routes[0]
    assert np.all(env.band_depth(guide[:-1], guide[1:]) <= 1e-6)
    assert guide[:, 1].max() > 700.0  # through the pass
