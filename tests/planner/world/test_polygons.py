"""Plan-view polygons and the Prisms family: orientation, simplicity, containment and distance against sampling."""

from __future__ import annotations

import numpy as np
import pytest

from planner.world.environment import Prisms
from planner.world.polygons import contains, counter_clockwise, signed_area, signed_distance, simplicity_problem

SQUARE = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
CONCAVE = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 30.0], [15.0, 5.0], [0.0, 30.0]])  # a notch from the top


def test_orientation_is_made_counter_clockwise_and_a_closing_vertex_dropped() -> None:
    closed_cw = np.vstack([SQUARE[::-1], SQUARE[-1:]])
    ring = counter_clockwise(closed_cw)
    assert len(ring) == 4 and signed_area(ring) == pytest.approx(100.0)


@pytest.mark.parametrize(("ring", "why"), [
    ([[0, 0], [10, 10], [10, 0], [0, 10]], "intersects itself"),
    ([[0, 0], [1, 0], [2, 0]], "area is zero"),
    ([[0, 0], [1, 0]], "at least 3"),
    ([[0, 0], [10, 0], [10, 10], [10, 0], [0, 10]], "repeated"),
    ([[0, 0], [10, 0], [10, 10], [5, 0], [0, 10]], "intersects itself"),  # a vertex on another edge
])
def test_polygons_that_are_not_simple_are_named_with_the_reason(ring: list, why: str) -> None:
    problem = simplicity_problem(np.array(ring, dtype=float))
    assert problem is not None and why in problem


def test_simple_polygons_concave_included_pass() -> None:
    assert simplicity_problem(SQUARE) is None and simplicity_problem(CONCAVE) is None


def test_containment_and_signed_distance_against_a_dense_sample_of_the_edges() -> None:
    rng = np.random.default_rng(1)
    p = rng.uniform(-10.0, 40.0, size=(400, 2))
    inside = contains(CONCAVE, p)
    assert not inside[np.hypot(p[:, 0] - 15.0, p[:, 1] - 20.0) < 4.0].any()  # the notch is outside
    t = np.linspace(0.0, 1.0, 4001)[:, None]
    ring = np.vstack([CONCAVE, CONCAVE[:1]])
    dense = np.concatenate([a + t * (b - a) for a, b in zip(ring[:-1], ring[1:], strict=True)])
    brute = np.min(np.linalg.norm(p[:, None, :] - dense[None], axis=-1), axis=1)
    sd = signed_distance(CONCAVE, p)
    assert np.allclose(np.abs(sd), brute, atol=0.02)
    assert np.array_equal(sd < 0, inside)


def test_prisms_pack_polygons_counter_clockwise_with_a_disc_around_each() -> None:
    prisms = Prisms.from_polygons([SQUARE[::-1], CONCAVE], [-np.inf, 20.0], [np.inf, 80.0])
    assert len(prisms) == 2 and list(prisms.start) == [0, 4, 9]
    for k in range(2):
        poly = prisms.polygon(k)
        assert signed_area(poly) > 0
        assert np.all(np.hypot(poly[:, 0] - prisms.cx[k], poly[:, 1] - prisms.cy[k]) <= prisms.r[k] + 1e-9)
    a, b, owner = prisms.edges()
    assert len(a) == len(b) == 9 and list(owner) == [0] * 4 + [1] * 5
    assert np.array_equal(b[3], a[0]) and np.array_equal(b[8], a[4])  # each ring closes on its first vertex
    assert len(Prisms.empty()) == 0


def test_a_keep_in_polygon_has_no_floor_or_ceiling() -> None:
    prisms = Prisms.from_polygons([SQUARE, CONCAVE], [-np.inf, 0.0], [np.inf, 50.0], keep_in=[True, False])
    assert list(prisms.keep_in) == [True, False]
    assert list(Prisms.from_polygons([SQUARE], [0.0], [9.0]).keep_in) == [False]
    with pytest.raises(ValueError, match="keep-in"):
        Prisms.from_polygons([SQUARE], [0.0], [np.inf], keep_in=[True])
