"""Hard maps with a known answer (planner.bench.hardmaps, issue 15): every generated file loads, its planted route
passes the planner's own checker (docs/method.md §12) on the generated scenario, the same seed gives the same map,
and the maps are not trivial (the straight start→goal line is blocked)."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from planner.bench.hardmaps import FAMILIES, HardMap, generate
from planner.plan import problem_from_scenario
from planner.trajectory.checks import check_trajectory, smooth
from planner.world.config import CATEGORIES
from planner.world.geometry import segment_point_distance_2d
from planner.world.scenario import Scenario, load_scenario

SEEDS = range(5)
CASES = [(family, seed) for family in FAMILIES for seed in SEEDS]


def _load(m: HardMap, tmp_path: Path) -> Scenario:
    path = tmp_path / f"{m.family}_{m.seed}.toml"
    path.write_text(m.toml)
    return load_scenario(path)


@pytest.mark.parametrize(("family", "seed"), CASES)
def test_the_planted_route_is_flyable_on_the_generated_map(family: str, seed: int, tmp_path: Path) -> None:
    m = generate(family, seed)
    sc = _load(m, tmp_path)
    assert m.planted.ndim == 2 and m.planted.shape[1] == 3 and len(m.planted) >= 3
    np.testing.assert_allclose(m.planted[0], sc.start)
    np.testing.assert_allclose(m.planted[-1], sc.goal)
    traj = smooth(m.planted, sc.planner.sample_spacing, sc.vehicle.cruise_speed)
    check = check_trajectory(traj, m.planted, sc.environment, sc.hazard, sc.vehicle)
    assert check.counts == {c: 0 for c in CATEGORIES}
    assert check.min_clearance >= sc.hazard.d_coll
    # the planner's cost agrees: the planted route is feasible for the optimiser too
    ev = problem_from_scenario(sc).evaluate(m.planted[None])
    assert int(ev.n_violations[0]) == 0


@pytest.mark.parametrize("family", FAMILIES)
def test_same_seed_same_map(family: str) -> None:
    a, b = generate(family, 3), generate(family, 3)
    assert a.toml == b.toml
    np.testing.assert_array_equal(a.planted, b.planted)
    assert generate(family, 4).toml != a.toml


@pytest.mark.parametrize("seed", SEEDS)
def test_gates_block_the_straight_line_with_walls_that_each_leave_one_gap(seed: int) -> None:
    m = generate("gates", seed)
    doc = tomllib.loads(m.toml)
    cyl = doc["cylinders"]
    assert m.n_obstacles == len(cyl) and not doc.get("spheres") and not doc.get("hemispheres")
    assert all("top" not in c for c in cyl)  # unlimited: no climbing over a wall
    x = np.array([c["x"] for c in cyl])
    y = np.array([c["y"] for c in cyl])
    r = np.array([c["radius"] for c in cyl])
    walls = np.unique(x)
    assert 4 <= len(walls) <= 6
    size_y = doc["bounds"]["y"]
    for wx in walls:  # cylinders along the wall cover [0, size_y] but for exactly one gap of about 180 m
        ys, rs = y[x == wx], r[x == wx]
        order = np.argsort(ys)
        lo, hi = ys[order] - rs[order], ys[order] + rs[order]
        assert lo[0] <= 0.0 and hi[-1] >= size_y
        gaps = lo[1:] - hi[:-1]
        assert (gaps > 0).sum() == 1 and 170.0 <= gaps.max() <= 190.0
    s, g = np.array(doc["route"]["start"]), np.array(doc["route"]["goal"])
    d = segment_point_distance_2d(s[0], s[1], g[0], g[1], x, y) - r
    assert (d < 0).any()  # the straight segment runs into a wall
    assert m.straight_blocked


@pytest.mark.parametrize("seed", SEEDS)
def test_dense_field_has_the_intended_obstacles(seed: int) -> None:
    m = generate("dense", seed)
    doc = tomllib.loads(m.toml)
    counts = {k: len(doc.get(k, [])) for k in ("cylinders", "spheres", "hemispheres")}
    assert sum(counts.values()) == m.n_obstacles == 150
    assert all(v > 20 for v in counts.values())  # all three kinds, about a third each
    assert m.straight_blocked  # recorded by the generator; true for these seeds


def test_unknown_family_is_refused() -> None:
    with pytest.raises(ValueError, match="unknown family"):
        generate("mazes", 0)
