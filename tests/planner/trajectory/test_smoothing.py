"""Tests for planner.trajectory.smoothing: the cubic Bézier smoothing of docs/method.md §11 (paper Properties 1–4)
and the closed forms the cost relies on (peak curvature, extrapolated direction)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from planner.trajectory.smoothing import (
    bezier_controls,
    bezier_derivatives,
    climb_angle,
    curvature,
    flown_deviation,
    overshoot_bound,
    peak_climb,
    peak_curvature,
    peak_factor,
    sample_trajectory,
)

SETTINGS = settings(max_examples=60, deadline=None)
T_DENSE = np.linspace(0.0, 1.0, 20001)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def direction(elev: float, azim: float) -> np.ndarray:
    return np.array([math.cos(elev) * math.cos(azim), math.cos(elev) * math.sin(azim), math.sin(elev)])


def turned(u: np.ndarray, theta: float, spin: float) -> np.ndarray:
    """A unit vector at angle ``theta`` from unit ``u``, rotated by ``spin`` about u."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(u[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = unit(np.cross(u, helper))
    e2 = np.cross(u, e1)
    return math.cos(theta) * u + math.sin(theta) * (math.cos(spin) * e1 + math.sin(spin) * e2)


@st.composite
def polylines(draw, max_turn_deg: float = 179.0, min_len: float = 2.0, max_len: float = 400.0,
              n_max: int = 7):
    """Non-degenerate polylines (N, 3): every segment at least ``min_len`` long, turns ≤ max_turn."""
    n_seg = draw(st.integers(1, n_max - 1))
    start = np.array([draw(st.floats(-500.0, 500.0)) for _ in range(3)])
    u = direction(draw(st.floats(-1.2, 1.2)), draw(st.floats(-math.pi, math.pi)))
    pts = [start]
    for _ in range(n_seg):
        r = draw(st.floats(min_len, max_len))
        pts.append(pts[-1] + r * u)
        u = turned(u, math.radians(draw(st.floats(0.0, max_turn_deg))), draw(st.floats(-math.pi, math.pi)))
    return np.array(pts)


def seg_dirs(path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.diff(path, axis=0)
    r = np.linalg.norm(d, axis=1)
    return d / r[:, None], r


# ---------------------------------------------------------------------------------------------
# control points, Property 1, interpolation
# ---------------------------------------------------------------------------------------------


def test_bezier_controls_hand_case():
    """Q1 = P_k + r/3 d̂_k, Q2 = P_{k+1} − r/3 d̂_{k+1}; the last segment uses its own direction."""
    p = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [30.0, 60.0, 0.0]])
    c = bezier_controls(p)
    assert c.shape == (2, 4, 3)
    np.testing.assert_allclose(c[0], [[0, 0, 0], [10, 0, 0], [30, -10, 0], [30, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(c[1], [[30, 0, 0], [30, 20, 0], [30, 40, 0], [30, 60, 0]], atol=1e-12)
    # batched input gives the same as one path at a time
    batch = np.stack([p, p[::-1]])
    cb = bezier_controls(batch)
    assert cb.shape == (2, 2, 4, 3)
    np.testing.assert_array_equal(cb[0], c)
    np.testing.assert_array_equal(cb[1], bezier_controls(p[::-1]))


@SETTINGS
@given(path=polylines())
def test_property1_tangent_at_waypoints_equals_segment_direction(path):
    """B'(0) of segment k is along d̂_k; B'(1) along d̂_{k+1} (the last segment: d̂_k itself)."""
    dirs, r = seg_dirs(path)
    ctrl = bezier_controls(path)
    pos, d1, _ = bezier_derivatives(ctrl, np.array([0.0, 1.0]))
    nxt = np.concatenate([dirs[1:], dirs[-1:]])
    np.testing.assert_allclose(unit(d1[:, 0]), dirs, atol=1e-9)
    np.testing.assert_allclose(unit(d1[:, 1]), nxt, atol=1e-9)
    # speed at the ends is r_k (control legs of length r_k / 3)
    np.testing.assert_allclose(np.linalg.norm(d1[:, 0], axis=1), r, rtol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(d1[:, 1], axis=1), r, rtol=1e-9)
    # C¹-direction continuity: the end tangent of segment k is the start tangent of segment k+1
    if len(dirs) > 1:
        np.testing.assert_allclose(unit(d1[:-1, 1]), unit(d1[1:, 0]), atol=1e-9)


@SETTINGS
@given(path=polylines(), spacing=st.floats(1.0, 80.0))
def test_curve_passes_through_every_waypoint(path, spacing):
    ctrl = bezier_controls(path)
    pos, _, _ = bezier_derivatives(ctrl, np.array([0.0, 1.0]))
    scale = max(1.0, float(np.abs(path).max()))
    np.testing.assert_allclose(pos[:, 0], path[:-1], atol=1e-9 * scale)
    np.testing.assert_allclose(pos[:, 1], path[1:], atol=1e-9 * scale)
    smp = sample_trajectory(path, spacing)
    pts = smp["points"]
    for w in path:
        assert np.linalg.norm(pts - w, axis=1).min() <= 1e-9 * scale
    np.testing.assert_allclose(pts[0], path[0], atol=1e-9 * scale)
    np.testing.assert_allclose(pts[-1], path[-1], atol=1e-9 * scale)


@SETTINGS
@given(path=polylines(), spacing=st.floats(1.0, 50.0))
def test_last_segment_is_straight(path, spacing):
    smp = sample_trajectory(path, spacing)
    last = len(path) - 2
    on_last = smp["segment"] == last
    assert on_last.sum() >= 2
    r_last = np.linalg.norm(path[-1] - path[-2])
    assert np.all(smp["curvature"][on_last] * r_last < 1e-8)
    # the samples of the last segment lie on the chord P_{N-2} → P_{N-1}
    d = smp["points"][on_last] - path[-2]
    u = (path[-1] - path[-2]) / r_last
    off = np.linalg.norm(d - (d @ u)[:, None] * u, axis=1)
    assert off.max() < 1e-8 * max(1.0, float(np.abs(path).max()))


def test_straight_polyline_has_zero_curvature_everywhere():
    p = np.array([[0.0, 0.0, 50.0], [100.0, 100.0, 60.0], [250.0, 250.0, 75.0], [300.0, 300.0, 80.0]])
    smp = sample_trajectory(p, 3.0)
    assert smp["curvature"].max() < 1e-10
    assert smp["s"][-1] == pytest.approx(np.linalg.norm(p[-1] - p[0]), rel=1e-12)


# ---------------------------------------------------------------------------------------------
# curvature and its closed form
# ---------------------------------------------------------------------------------------------


def test_curvature_of_circle_like_derivatives():
    """κ = ‖B'×B''‖/‖B'‖³: for B' ⟂ B'' with |B'| = v, |B''| = a, κ = a / v²."""
    d1 = np.array([[3.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    d2 = np.array([[0.0, 9.0, 0.0], [0.0, 5.0, 0.0]])  # second: parallel → zero curvature
    np.testing.assert_allclose(curvature(d1, d2), [1.0, 0.0], atol=1e-15)


@SETTINGS
@given(
    r=st.floats(1.0, 1000.0),
    theta_deg=st.floats(0.2, 150.0),
    elev=st.floats(-1.0, 1.0),
    azim=st.floats(-math.pi, math.pi),
    spin=st.floats(-math.pi, math.pi),
    r_next=st.floats(1.0, 1000.0),
)
@example(r=50.0, theta_deg=150.0, elev=0.0, azim=0.0, spin=0.0, r_next=50.0)
@example(r=10.0, theta_deg=90.0, elev=0.3, azim=1.0, spin=1.0, r_next=500.0)
def test_peak_curvature_matches_dense_sampling(r, theta_deg, elev, azim, spin, r_next):
    u = direction(elev, azim)
    v = turned(u, math.radians(theta_deg), spin)
    p0 = np.array([10.0, -20.0, 30.0])
    path = np.array([p0, p0 + r * u, p0 + r * u + r_next * v])
    ctrl = bezier_controls(path)
    _, d1, d2 = bezier_derivatives(ctrl[0], T_DENSE)
    sampled = float(curvature(d1, d2).max())
    closed = float(peak_curvature(np.float64(r), np.float64(u @ v)))
    assert closed == pytest.approx(sampled, rel=1e-3)


@pytest.mark.parametrize("theta_deg", [0.05, 0.5, 2.0, 5.0, 10.0])
@pytest.mark.parametrize("r", [3.0, 120.0])
def test_peak_curvature_small_turn_is_4_sin_over_r(theta_deg, r):
    th = math.radians(theta_deg)
    assert float(peak_curvature(np.float64(r), np.float64(math.cos(th)))) == pytest.approx(
        4.0 * math.sin(th) / r, rel=1e-3)


def test_peak_curvature_broadcasts_and_straight_is_zero():
    r = np.array([[10.0], [100.0]])
    c = np.cos(np.radians([0.0, 30.0, 90.0]))
    k = peak_curvature(r, c)
    assert k.shape == (2, 3)
    assert np.all(k[:, 0] == 0.0)
    np.testing.assert_allclose(k[0], 10.0 * k[1], rtol=1e-12)  # ∝ 1/r
    assert np.all(np.diff(k, axis=1) > 0)  # sharper turn → larger peak


def test_peak_factor_grows_as_turn_sharpens():
    c = np.cos(np.radians(np.linspace(0.0, 170.0, 200)))
    g = peak_factor(c)
    assert g[0] == pytest.approx(4.0, rel=1e-9)
    assert np.all(np.diff(g) >= -1e-12)
    assert g[-1] > 100.0


# ---------------------------------------------------------------------------------------------
# sampling
# ---------------------------------------------------------------------------------------------


def sample_gaps(smp: dict) -> np.ndarray:
    return np.linalg.norm(np.diff(smp["points"], axis=0), axis=1)


@SETTINGS
@given(path=polylines(max_turn_deg=0.0), spacing=st.floats(0.5, 60.0))
def test_sample_spacing_at_most_requested_on_straight_paths(path, spacing):
    smp = sample_trajectory(path, spacing)
    assert sample_gaps(smp).max() <= spacing * (1.0 + 1e-9)
    assert np.all(np.diff(smp["s"]) > 0)


@SETTINGS
@given(path=polylines(max_turn_deg=150.0), spacing=st.floats(0.5, 60.0))
def test_sample_spacing_bounded_on_curves(path, spacing):
    """Uniform t on a segment: the gap is at most max‖B'‖ / count ≤ (5/3) r / count ≤ (5/3) spacing."""
    smp = sample_trajectory(path, spacing)
    assert sample_gaps(smp).max() <= 5.0 / 3.0 * spacing * (1.0 + 1e-9)


def test_sample_spacing_at_most_requested_at_a_right_angle():
    p = np.array([[0.0, 0.0, 0.0], [100.0, 0.0, 0.0], [100.0, 100.0, 0.0]])
    assert sample_gaps(sample_trajectory(p, 10.0)).max() <= 10.0 * (1.0 + 1e-9)


@SETTINGS
@given(path=polylines(max_turn_deg=150.0), spacing=st.floats(2.0, 40.0))
def test_arc_length_between_chord_and_control_polygon(path, spacing):
    smp = sample_trajectory(path, spacing)
    s = smp["s"]
    assert s[0] == 0.0
    np.testing.assert_allclose(s[1:], np.cumsum(sample_gaps(smp)), rtol=1e-12)
    assert s[-1] >= np.linalg.norm(path[-1] - path[0]) * (1.0 - 1e-12)
    # each segment's sampled arc ≥ its chord and ≤ its control polygon length (Bézier hull property)
    ctrl = bezier_controls(path)
    seg = smp["segment"]
    for k in range(len(ctrl)):
        idx = np.flatnonzero(seg == k)
        end = idx[-1] + 1 if k < len(ctrl) - 1 else idx[-1]  # sample at the segment's end point
        arc = s[end] - s[idx[0]]
        chord = np.linalg.norm(path[k + 1] - path[k])
        poly = np.linalg.norm(np.diff(ctrl[k], axis=0), axis=1).sum()
        assert chord * (1 - 1e-12) <= arc <= poly * (1 + 1e-12)


@SETTINGS
@given(path=polylines(max_turn_deg=2.0, min_len=20.0), spacing=st.floats(0.5, 10.0))
def test_arc_length_close_to_polyline_length_when_nearly_straight(path, spacing):
    smp = sample_trajectory(path, spacing)
    poly = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    assert smp["s"][-1] == pytest.approx(poly, rel=1e-3)


def test_sample_trajectory_fields_consistent():
    p = np.array([[0.0, 0.0, 100.0], [200.0, 0.0, 120.0], [300.0, 150.0, 130.0], [500.0, 200.0, 100.0]])
    smp = sample_trajectory(p, 7.0)
    m = len(smp["points"])
    assert smp["tangent"].shape == (m, 3) and smp["curvature"].shape == (m,)
    assert smp["segment"].shape == (m,) and smp["s"].shape == (m,)
    assert np.all(np.diff(smp["segment"]) >= 0)
    assert set(smp["segment"].tolist()) == {0, 1, 2}
    # tangent is d/dt of the Bézier: consistent with the sampled curvature recomputed independently
    ctrl = bezier_controls(p)
    t = np.linspace(0.0, 1.0, 5)
    _, d1, d2 = bezier_derivatives(ctrl, t)
    assert d1.shape == d2.shape == (3, 5, 3)
    np.testing.assert_allclose(curvature(d1, d2)[0, 0], smp["curvature"][0], rtol=1e-9)


# ---------------------------------------------------------------------------------------------
# climb angle along the curve
# ---------------------------------------------------------------------------------------------


def test_climb_angle_values():
    v = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [-1.0, 0.0, -math.sqrt(3.0)], [0.0, 0.0, 2.0]])
    np.testing.assert_allclose(climb_angle(v), [0.0, math.pi / 4, -math.pi / 3, math.pi / 2], atol=1e-15)


def _climb_check(r1, r2, g1, g2, head1, turn):
    u = direction(g1, head1)
    v = direction(g2, head1 + turn)
    path = np.array([[0.0, 0.0, 0.0], r1 * u, r1 * u + r2 * v])
    smp = sample_trajectory(path, min(r1, r2) / 400.0)
    flown = float(np.abs(climb_angle(smp["tangent"])).max())
    bound = float(peak_climb(u, v))
    return flown, bound


angle30 = st.floats(-math.radians(30.0), math.radians(30.0))


@SETTINGS
@given(r1=st.floats(5.0, 500.0), r2=st.floats(5.0, 500.0), g1=angle30, g2=angle30,
       head=st.floats(-math.pi, math.pi))
def test_climb_along_curve_bounded_without_horizontal_turn(r1, r2, g1, g2, head):
    """Directions in one vertical plane: the tangent stays between (4u − v)/3 and v in that plane."""
    flown, bound = _climb_check(r1, r2, g1, g2, head, 0.0)
    assert flown <= bound + 1e-9


@SETTINGS
@given(r1=st.floats(5.0, 500.0), r2=st.floats(5.0, 500.0), g1=angle30, g2=angle30,
       head=st.floats(-math.pi, math.pi), turn=st.floats(-math.radians(60.0), math.radians(60.0)))
@example(r1=200.0, r2=200.0, g1=math.radians(14.9), g2=math.radians(14.9), head=0.0,
         turn=math.radians(45.0))
def test_peak_climb_is_the_climb_flown_on_the_curve(r1, r2, g1, g2, head, turn):
    """peak_climb is exact: the densely sampled curve reaches it and never exceeds it."""
    flown, bound = _climb_check(r1, r2, g1, g2, head, turn)
    assert flown <= bound + 1e-9
    assert flown >= bound - 1e-4


# ---------------------------------------------------------------------------------------------
# deviation from the chord and exact height range (closed forms used by the cost)
# ---------------------------------------------------------------------------------------------


@SETTINGS
@given(r=st.floats(1.0, 1000.0), theta_deg=st.floats(0.0, 179.0), elev=st.floats(-1.0, 1.0),
       azim=st.floats(-math.pi, math.pi), spin=st.floats(-math.pi, math.pi))
@example(r=100.0, theta_deg=90.0, elev=0.0, azim=0.0, spin=0.0)
@example(r=100.0, theta_deg=170.0, elev=0.0, azim=0.0, spin=0.0)
def test_deviation_bound_covers_distance_from_chord(r, theta_deg, elev, azim, spin):
    from planner.trajectory.smoothing import deviation_bound
    from planner.world.geometry import segment_point_distance

    u = direction(elev, azim)
    v = turned(u, math.radians(theta_deg), spin)
    a = np.array([5.0, 6.0, 7.0])
    path = np.array([a, a + r * u, a + r * u + 50.0 * v])
    pos, _, _ = bezier_derivatives(bezier_controls(path)[0], np.linspace(0.0, 1.0, 2001))
    off = segment_point_distance(path[0], path[1], pos).max()
    bound = float(deviation_bound(np.float64(r), np.float64(u @ v)))
    assert off <= bound * (1 + 1e-9) + 1e-8 * r  # sin θ from cos θ loses ~1.5e-8 near θ = 0: nanometres
    if theta_deg <= 90.0:  # the bound is tight below 90°: (4/27) r sin θ at t = 2/3
        assert bound == pytest.approx((4.0 / 27.0) * r * math.sin(math.radians(theta_deg)), rel=1e-6,
                                      abs=1e-7 * r)
        assert off >= bound * (1 - 1e-3) - 1e-8 * r  # sin θ from cos θ ≈ 1 carries ~1e-8 noise


coef = st.floats(-500.0, 500.0)


@SETTINGS
@given(q=st.tuples(coef, coef, coef, coef))
@example(q=(0.0, 0.0, 0.0, 0.0))
@example(q=(0.0, 1.0, 1.0, 0.0))
@example(q=(0.0, 1.0, 2.0, 3.0))  # linear: derivative never vanishes
def test_cubic_range_matches_dense_sampling(q):
    from planner.trajectory.smoothing import cubic_range

    q0, q1, q2, q3 = (np.array([x]) for x in q)
    lo, hi = cubic_range(q0, q1, q2, q3)
    t = np.linspace(0.0, 1.0, 20001)
    s = 1.0 - t
    val = s**3 * q[0] + 3 * s**2 * t * q[1] + 3 * s * t**2 * q[2] + t**3 * q[3]
    scale = max(1.0, max(abs(x) for x in q))
    assert lo[0] <= val.min() + 1e-9 * scale
    assert hi[0] >= val.max() - 1e-9 * scale
    assert lo[0] >= val.min() - 1e-6 * scale  # dense samples are within 1e-8 in t of the extremes
    assert hi[0] <= val.max() + 1e-6 * scale


def test_the_swing_past_a_turn_widens_only_the_segment_after_it() -> None:
    """docs/method.md §4.4: a path-follower that swings ``turn_overshoot`` m per radian past a new leg adds that to
    the segment after the turn (not before it, not two segments on); 0 leaves the paper's bound as it was."""
    seg_len = np.array([300.0, 300.0, 300.0])
    cos_turn = np.array([math.cos(math.radians(30.0)), 1.0, 1.0])  # a 30° turn between segments 0 and 1
    plain = flown_deviation(seg_len, cos_turn, 20.0)
    swung = flown_deviation(seg_len, cos_turn, 20.0, turn_overshoot=24.0)
    assert np.array_equal(plain, flown_deviation(seg_len, cos_turn, 20.0, turn_overshoot=0.0))
    assert swung[1] == pytest.approx(24.0 * math.radians(30.0)) and swung[1] > plain[1]
    assert swung[0] == plain[0] and swung[2] == plain[2]
    assert overshoot_bound(10.0, np.array([-1.0, 0.0]))[0] == pytest.approx(10.0 * math.pi)
