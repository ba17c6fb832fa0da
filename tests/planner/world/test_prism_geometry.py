"""Property tests for the polygon prisms' exact distances (planner.world.geometry, docs/method.md §2.7): a point's
signed distance against polygons.signed_distance plus the vertical part, and a segment's clearance against a dense
sampler of that point distance, computed independently, polygon by polygon: exact to the sampler's resolution, the
sign right (negative where the segment meets the solid), keep-in polygons likewise, unlimited floors and ceilings
without NaNs."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from planner.world import geometry, polygons
from planner.world.environment import Prisms
from planner.world.geometry import prism_signed_distance, segment_prism_clearance

SETTINGS = settings(max_examples=60, deadline=None)
N_SAMPLES = 8001
T = np.linspace(0.0, 1.0, N_SAMPLES)

# a concave star, an L (concave, axis-aligned edges), a triangle and a thin sliver, in a 400 m square
SHAPES = [
    np.array([[200, 60], [230, 160], [330, 170], [250, 230], [280, 330], [200, 270], [120, 330], [150, 230],
              [70, 170], [170, 160]], float),
    np.array([[20, 20], [120, 20], [120, 60], [60, 60], [60, 180], [20, 180]], float),
    np.array([[260, 20], [380, 40], [300, 110]], float),
    np.array([[40, 250], [110, 380], [100, 385]], float),
]
LEVELS = st.sampled_from([-np.inf, 40.0, 90.0])
CEILINGS = st.sampled_from([np.inf, 120.0, 160.0])
coord = st.floats(-60.0, 460.0, allow_nan=False)
height = st.floats(0.0, 220.0, allow_nan=False)
point = st.tuples(coord, coord, height).map(np.array)


def brute(prisms: Prisms, pts: np.ndarray) -> np.ndarray:
    """Signed distance (K, M) of points to each solid, from polygons.signed_distance and the vertical part."""
    out = []
    for k in range(len(prisms)):  # independent of geometry's vectorised code: one polygon at a time
        u = polygons.signed_distance(prisms.polygon(k), pts[:, :2])
        u = -u if prisms.keep_in[k] else u
        with np.errstate(invalid="ignore"):
            w = np.maximum(prisms.floor[k] - pts[:, 2], pts[:, 2] - prisms.ceiling[k])
        out.append(np.hypot(np.maximum(u, 0.0), np.maximum(w, 0.0)) + np.minimum(np.maximum(u, w), 0.0))
    return np.array(out)


def prisms_of(floors: list[float], ceilings: list[float]) -> Prisms:
    return Prisms.from_polygons(SHAPES, [min(f, c - 1.0) for f, c in zip(floors, ceilings)], ceilings)


def assert_exact(prisms: Prisms, a: np.ndarray, b: np.ndarray) -> None:
    c = segment_prism_clearance(a, b, prisms)
    assert c.shape == (len(prisms),) and np.all(np.isfinite(c))
    d = brute(prisms, a + T[:, None] * (b - a))
    step = float(np.linalg.norm(b - a)) / (N_SAMPLES - 1)
    for k in range(len(prisms)):
        low = d[k].min()
        if low > step:  # clear of the solid: the exact least distance, to half a sample gap (distance is 1-Lipschitz)
            assert low - 0.5 * step - 1e-9 <= c[k] <= low + 1e-9, (k, c[k], low)
        elif low < -step:  # through it: a negative measure, no deeper than the deepest point
            assert low - 0.5 * step - 1e-9 <= c[k] < 0.0, (k, c[k], low)
        else:  # grazing within one sample gap: the sign may go either way, the value is near zero
            assert abs(c[k]) <= step + 1e-9, (k, c[k], low)


@SETTINGS
@given(point, point, st.lists(LEVELS, min_size=4, max_size=4), st.lists(CEILINGS, min_size=4, max_size=4))
def test_segment_clearance_is_exact_to_the_sampler(a, b, floors, ceilings) -> None:
    assert_exact(prisms_of(floors, ceilings), a, b)


@SETTINGS
@given(point, point)
def test_keep_in_clearance_is_exact_to_the_sampler(a, b) -> None:
    fence = Prisms.from_polygons([SHAPES[0] * 1.2 - 40.0, SHAPES[1] + 10.0], [-np.inf] * 2, [np.inf] * 2,
                                 [True, True])
    assert_exact(fence, a, b)


def test_point_distance_matches_the_polygon_functions_and_the_vertical_part() -> None:
    rng = np.random.default_rng(3)
    pts = rng.uniform([-60, -60, 0], [460, 460, 220], (4000, 3))
    for prisms in (prisms_of([-np.inf, 40.0, 90.0, -np.inf], [np.inf, 120.0, 160.0, 160.0]),
                   Prisms.from_polygons(SHAPES[:2], [-np.inf] * 2, [np.inf] * 2, [True, False])):
        got = prism_signed_distance(pts, prisms)
        assert got.shape == (len(prisms), len(pts)) and np.all(np.isfinite(got))
        np.testing.assert_allclose(got, brute(prisms, pts), rtol=1e-12, atol=1e-9)
        assert (got < 0).any() and (got > 0).any()  # both sides occur


def test_segments_through_and_around_the_solid() -> None:
    """Hand-made cases: over a finite ceiling, under a floor, along an edge, through a concave notch, a zero-length
    segment, and straight through: each against the sampler, with the sign it must have."""
    prisms = Prisms.from_polygons([SHAPES[0], SHAPES[1]], [40.0, -np.inf], [120.0, np.inf])
    cases = [((0, 200, 150), (400, 200, 150), 1),  # over the star's ceiling by 30 m
             ((0, 200, 10), (400, 200, 10), 1),  # under its floor by 30 m
             ((200, 200, 80), (200, 200, 80), -1),  # a point inside
             ((200, 0, 80), (200, 400, 80), -1),  # straight through
             ((200, 250, 80), (200, 300, 80), -1),  # from inside the star out into its top notch
             ((20, 0, 50), (20, 300, 50), 0),  # along the L's outer edge: touching
             ((70, 70, 100), (110, 140, 100), 1)]  # out of the L's inner corner, clear of it and the star
    for a, b, sign in cases:
        a, b = np.array(a, float), np.array(b, float)
        assert_exact(prisms, a, b)
        c = segment_prism_clearance(a, b, prisms).min()
        assert (c > 1e-6) if sign > 0 else (c < -1e-6) if sign < 0 else abs(c) < 1e-6 or c > 0, (a, b, c)
    over = segment_prism_clearance(np.array([0, 200, 150.0]), np.array([400, 200, 150.0]), prisms)[0]
    assert abs(over - 30.0) < 1e-9  # straight over the roof: the height above it


def test_shapes_broadcast_and_no_prisms() -> None:
    prisms = prisms_of([-np.inf, 40.0, 90.0, -np.inf], [np.inf, 120.0, 160.0, 160.0])
    rng = np.random.default_rng(5)
    a = rng.uniform([-60, -60, 0], [460, 460, 220], (7, 5, 3))
    b = rng.uniform([-60, -60, 0], [460, 460, 220], (7, 5, 3))
    got = segment_prism_clearance(a, b, prisms)
    assert got.shape == (4, 7, 5)
    np.testing.assert_array_equal(got[:, 3, 2], segment_prism_clearance(a[3, 2], b[3, 2], prisms))
    assert segment_prism_clearance(a, b, Prisms.empty()).shape == (0, 7, 5)
    assert prism_signed_distance(a, Prisms.empty()).shape == (0, 7, 5)


def test_a_batch_chunked_equals_it_unchunked_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    """segment_prism_clearance takes its segments in chunks (bounded memory): one segment a chunk, uneven chunks
    and the whole batch at once give the same bits, zero-length and level segments included."""
    prisms = prisms_of([-np.inf, 40.0, 90.0, -np.inf], [np.inf, 120.0, 160.0, 160.0])
    rng = np.random.default_rng(11)
    a = rng.uniform([-60, -60, 0], [460, 460, 220], (9, 37, 3))
    b = a + rng.normal(0.0, 80.0, a.shape)
    b[::3, ::4] = a[::3, ::4]
    b[1::3, ::5, 2] = a[1::3, ::5, 2]
    elements = geometry._prism_edges(prisms)[0].size  # K·V
    monkeypatch.setattr(geometry, "PRISM_CHUNK_ELEMENTS", 10**9)
    whole = segment_prism_clearance(a, b, prisms)
    for rows in (1, 7, 100):
        monkeypatch.setattr(geometry, "PRISM_CHUNK_ELEMENTS", rows * elements)
        got = segment_prism_clearance(a, b, prisms)
        assert got.shape == whole.shape == (4, 9, 37)
        assert got.tobytes() == whole.tobytes(), rows
