"""The exact band test over terrain (docs/method.md §15.1): least and greatest height above the bilinear ground
along a straight segment, against dense sampling, and the checker's chords between samples."""

from __future__ import annotations

import numpy as np
import pytest

from planner.world.environment import Environment
from planner.world.terrain import Terrain


def _sampled(terrain: Terrain, a: np.ndarray, b: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.linspace(0.0, 1.0, n)[:, None, None]
    p = a[None] + t * (b - a)[None]
    h = p[..., 2] - terrain.height_at(p[..., 0], p[..., 1])
    return h.min(axis=0), h.max(axis=0)


@pytest.mark.parametrize("seed", [0, *(pytest.param(k, marks=pytest.mark.slow(  # more random grids, the same property
    covered_by="test_the_range_is_what_dense_sampling_finds_and_never_less[0]")) for k in (1, 2))])
def test_the_range_is_what_dense_sampling_finds_and_never_less(seed: int) -> None:
    rng = np.random.default_rng(seed)
    terrain = Terrain(-40.0, 25.0, 20.0, 30.0, rng.uniform(0.0, 6.0, (18, 22)))
    a = rng.uniform(-100.0, 500.0, (200, 3))  # 165 random segments beside the special ones (400 took 14 s of CI)
    b = a + rng.normal(0.0, 120.0, (200, 3))
    b[:20, 0] = a[:20, 0]  # along a grid axis
    b[20:30, :2] = a[20:30, :2]  # vertical
    b[30:35] = a[30:35]  # a point
    lo, hi = terrain.clearance_range(a, b)
    s_lo, s_hi = _sampled(terrain, a, b, 100_001)
    assert np.all(lo <= s_lo + 1e-9) and np.all(hi >= s_hi - 1e-9)  # never optimistic
    assert np.abs(lo - s_lo).max() < 1e-3 and np.abs(hi - s_hi).max() < 1e-3  # and exact (sampling's error)


def test_a_ridge_between_nine_samples_is_found() -> None:
    """A one-cell ridge a 9-sample test steps over: the old roadmap band test missed it, this one does not."""
    h = np.zeros((3, 41))
    h[:, 20] = 200.0  # a ridge 200 m high, one cell (10 m) wide at x = 200
    terrain = Terrain(0.0, 0.0, 10.0, 50.0, h)
    env = Environment(400.0, 100.0, 30.0, 150.0, terrain=terrain)
    a, b = np.array([[5.0, 50.0, 100.0]]), np.array([[300.0, 50.0, 100.0]])  # samples at x = 189.4 and 226.3
    t = np.linspace(0.0, 1.0, 9)
    p = a + t[:, None] * (b - a)
    assert np.all(p[:, 2] - env.ground(p[:, 0], p[:, 1]) >= 30.0)  # every sample is inside the band
    assert env.band_depth(a, b)[0] == pytest.approx(130.0)  # the segment passes 100 m below the crest + 30 m floor


def test_flat_ground_is_the_ends_heights() -> None:
    env = Environment(100.0, 100.0, 20.0, 80.0)
    lo, hi = env.height_range(np.array([[0.0, 0.0, 10.0]]), np.array([[50.0, 0.0, 90.0]]))
    assert lo[0] == 10.0 and hi[0] == 90.0
    assert env.band_depth(np.array([[0.0, 0.0, 50.0]]), np.array([[50.0, 0.0, 60.0]]))[0] == -20.0
