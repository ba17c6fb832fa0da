"""The OMPL peers' state validity on the terrain hard maps (planner.bench.peers, issue 34): the state space's z range
holds the band over the lowest and the highest ground, and a state is valid where it stands inside the band above
the ground under it (not above home), clear of the obstacles and radars. Plain Python and numpy: no OMPL needed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from planner.bench import hardmaps, peers
from planner.plan import problem_from_scenario
from planner.trajectory.checks import obstacle_clearance, radar_clearance
from planner.world.scenario import load_scenario


@pytest.mark.parametrize("family", hardmaps.TERRAIN_FAMILIES)
def test_validity_keeps_the_band_above_the_ground_under_the_state(family: str, tmp_path: Path) -> None:
    m = hardmaps.generate(family, 0)
    problem = problem_from_scenario(load_scenario(m.write(tmp_path)))
    env = problem.env
    ground = env.terrain.heights
    assert peers.altitude_limits(env) == (ground.min() + env.z_min, ground.max() + env.z_max)
    lo, hi = peers.altitude_limits(env)
    rng = np.random.default_rng(1)
    pts = rng.uniform([-10.0, -10.0, lo - 20.0], [env.size_x + 10.0, env.size_y + 10.0, hi + 20.0], (6000, 3))
    near = pts[:3000]  # half of them near the band, where the verdicts differ
    near[:, 2] = env.ground(near[:, 0], near[:, 1]) + rng.uniform(env.z_min - 15.0, env.z_max + 15.0, len(near))
    margin = peers.tracking_margin(problem)
    above = pts[:, 2] - env.ground(pts[:, 0], pts[:, 1])
    expected = (((pts[:, :2] >= 0.0) & (pts[:, :2] <= [env.size_x, env.size_y])).all(axis=1)
                & (above >= env.z_min) & (above <= env.z_max)
                & (obstacle_clearance(pts, None, env, include_radars=False) >= problem.hazard.d_coll + margin)
                & (radar_clearance(pts, env.radars) >= margin))
    valid = peers.state_validity(problem)
    got = np.array([valid(*p) for p in pts.tolist()])
    np.testing.assert_array_equal(got, expected)
    assert 0.2 < expected[:3000].mean() < 0.95 and expected[3000:].mean() < 0.3  # the band is thin over the box
    # the planted route's waypoints are valid states (its corridor keeps more than the peers ask)
    assert all(valid(*p) for p in m.planted.tolist())


def test_rrtconnect_keeps_the_band_over_the_valley_floor(tmp_path: Path) -> None:
    """With OMPL: RRTConnect's route through the valley keeps the band above the ground under its states and along
    its chords: it plans in the band that follows the ground, not in one above home."""
    pytest.importorskip("ompl")
    problem = problem_from_scenario(load_scenario(hardmaps.generate("valley", 0).write(tmp_path)))
    r = peers.solve(problem, "rrtconnect", 2.0, seed=3)
    assert r.found and r.route is not None
    env = problem.env
    t = np.linspace(0.0, 1.0, 200)[:, None]
    chords = (r.route[:-1, None] + t * (r.route[1:, None] - r.route[:-1, None])).reshape(-1, 3)
    above = chords[:, 2] - env.ground(chords[:, 0], chords[:, 1])
    # OMPL checks a motion every 3 m; over the flat floor a chord barely strays from the band between two checks
    assert env.z_min - 1.0 <= above.min() and above.max() <= env.z_max + 1.0
