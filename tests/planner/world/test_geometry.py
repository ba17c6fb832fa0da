"""Property tests for planner.world.geometry: exact distances against brute-force sampling, and the
spherical encoding round trip."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from planner.world.geometry import (
    cartesian_to_spherical,
    cylinder_signed_distance,
    segment_cylinder_clearance,
    segment_cylinder_clearance_2d,
    segment_point_distance,
    segment_point_distance_2d,
    segment_sphere_clearance,
    spherical_to_cartesian,
)

SETTINGS = settings(max_examples=200, deadline=None)

N_SAMPLES = 20001  # spacing 1/20000 of the segment
T = np.linspace(0.0, 1.0, N_SAMPLES)

COORD = 1000.0


def coord(lo: float = -COORD, hi: float = COORD) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


radii = st.floats(0.1, 300.0, allow_nan=False, allow_infinity=False)
points3 = st.tuples(coord(), coord(), coord()).map(np.array)
points2 = st.tuples(coord(), coord()).map(np.array)


@st.composite
def segments(draw, dim: int = 3):
    """Segment a→b; sometimes degenerate (a == b) or very short."""
    pt = points3 if dim == 3 else points2
    a = draw(pt)
    kind = draw(st.sampled_from(["free", "free", "degenerate", "short"]))
    if kind == "degenerate":
        b = a.copy()
    elif kind == "short":
        b = a + draw(st.tuples(*[coord(-1e-3, 1e-3)] * dim).map(np.array))
    else:
        b = draw(pt)
    return a, b


def samples(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a + T[:, None] * (b - a)


def scale_of(*arrs) -> float:
    return max(1.0, *(float(np.max(np.abs(np.asarray(x)))) for x in arrs))


def check_against_samples(exact: float, sampled: np.ndarray, seg_len: float, scale: float) -> None:
    """exact min over the segment vs. min over the samples of a 1-Lipschitz-in-p function."""
    smin = float(np.min(sampled))
    assert exact <= smin + 1e-9 * scale, (exact, smin)
    assert exact >= smin - seg_len / 20000.0 - 1e-9 * scale, (exact, smin, seg_len)


# ---------------------------------------------------------------------------------------------
# 1. segment ↔ point distance
# ---------------------------------------------------------------------------------------------


@SETTINGS
@given(seg=segments(3), p=points3)
@example(seg=(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 0.0])), p=np.array([3.0, 4.0, 0.0]))
@example(seg=(np.array([0.0, 0.0, 0.0]), np.array([10.0, 0.0, 0.0])), p=np.array([5.0, 3.0, 4.0]))
def test_segment_point_distance_3d_matches_sampling(seg, p):
    a, b = seg
    exact = float(segment_point_distance(a, b, p))
    sampled = np.linalg.norm(samples(a, b) - p, axis=-1)
    check_against_samples(exact, sampled, float(np.linalg.norm(b - a)), scale_of(a, b, p))
    assert exact >= 0.0


@SETTINGS
@given(seg=segments(2), p=points2)
@example(seg=(np.array([1.0, 1.0]), np.array([1.0, 1.0])), p=np.array([4.0, 5.0]))
def test_segment_point_distance_2d_matches_sampling(seg, p):
    a, b = seg
    exact = float(segment_point_distance(a, b, p))
    exact_sep = float(segment_point_distance_2d(a[0], a[1], b[0], b[1], p[0], p[1]))
    sampled = np.linalg.norm(samples(a, b) - p, axis=-1)
    scale = scale_of(a, b, p)
    seg_len = float(np.linalg.norm(b - a))
    check_against_samples(exact, sampled, seg_len, scale)
    check_against_samples(exact_sep, sampled, seg_len, scale)
    assert exact_sep == pytest.approx(exact, rel=1e-12, abs=1e-9 * scale)


@SETTINGS
@given(M=st.integers(1, 6), K=st.integers(1, 4), data=st.data())
def test_segment_point_distance_broadcasting(M, K, data):
    """a, b (1, M, 3) against p (K, 1, 3) → (K, M), equal to the per-element results; same for spheres."""
    box = st.floats(-100.0, 100.0)
    a = data.draw(arrays(np.float64, (1, M, 3), elements=box))
    b = data.draw(arrays(np.float64, (1, M, 3), elements=box))
    if data.draw(st.booleans()):
        b[0, 0] = a[0, 0]  # one degenerate segment
    p = data.draw(arrays(np.float64, (K, 1, 3), elements=box))
    R = data.draw(arrays(np.float64, (K, 1), elements=st.floats(0.1, 30.0)))
    got = segment_point_distance(a, b, p)
    got_sph = segment_sphere_clearance(a, b, p, R)
    got_2d = segment_point_distance_2d(a[..., 0], a[..., 1], b[..., 0], b[..., 1], p[..., 0], p[..., 1])
    assert got.shape == got_sph.shape == got_2d.shape == (K, M)
    for k in range(K):
        for m in range(M):
            one = segment_point_distance(a[0, m], b[0, m], p[k, 0])
            assert got[k, m] == pytest.approx(one, rel=1e-12, abs=1e-12)
            assert got_sph[k, m] == pytest.approx(one - R[k, 0], rel=1e-12, abs=1e-12)
            one_2d = segment_point_distance(a[0, m, :2], b[0, m, :2], p[k, 0, :2])
            assert got_2d[k, m] == pytest.approx(one_2d, rel=1e-12, abs=1e-12)


def test_segment_point_distance_hand_cases():
    a = np.array([0.0, 0.0, 0.0])
    b = np.array([10.0, 0.0, 0.0])
    assert segment_point_distance(a, b, np.array([5.0, 3.0, 4.0])) == pytest.approx(5.0)
    assert segment_point_distance(a, b, np.array([-3.0, 4.0, 0.0])) == pytest.approx(5.0)  # beyond a
    assert segment_point_distance(a, b, np.array([13.0, 0.0, 4.0])) == pytest.approx(5.0)  # beyond b
    assert segment_point_distance(a, a, np.array([3.0, 0.0, 4.0])) == pytest.approx(5.0)  # degenerate
    assert segment_point_distance_2d(0.0, 0.0, 0.0, 0.0, 3.0, 4.0) == pytest.approx(5.0)


# ---------------------------------------------------------------------------------------------
# 2. segment ↔ sphere clearance
# ---------------------------------------------------------------------------------------------


@st.composite
def sphere_cases(draw):
    """Sphere and segment, the segment often placed near / through the sphere."""
    c = draw(points3)
    R = draw(radii)
    if draw(st.booleans()):
        off = st.tuples(*[coord(-3.0, 3.0)] * 3).map(np.array)
        a = c + R * draw(off)
        b = a.copy() if draw(st.integers(0, 5)) == 0 else c + R * draw(off)
    else:
        a, b = draw(segments(3))
    return a, b, c, R


@SETTINGS
@given(case=sphere_cases())
@example(case=(np.array([-10.0, 0.0, 0.0]), np.array([10.0, 0.0, 0.0]), np.zeros(3), 2.0))  # through
def test_segment_sphere_clearance_matches_sampling(case):
    a, b, c, R = case
    exact = float(segment_sphere_clearance(a, b, c, R))
    sampled = np.linalg.norm(samples(a, b) - c, axis=-1) - R
    check_against_samples(exact, sampled, float(np.linalg.norm(b - a)), scale_of(a, b, c, R))
    assert exact >= -R - 1e-9 * scale_of(a, b, c, R)


def test_segment_sphere_clearance_hand_cases():
    c = np.zeros(3)
    assert segment_sphere_clearance(np.array([-10.0, 0, 0]), np.array([10.0, 0, 0]), c, 2.0) == pytest.approx(-2.0)
    assert segment_sphere_clearance(np.array([-10.0, 5, 0]), np.array([10.0, 5, 0]), c, 2.0) == pytest.approx(3.0)


# ---------------------------------------------------------------------------------------------
# 3. cylinder signed distance and segment ↔ cylinder clearance
# ---------------------------------------------------------------------------------------------


def test_cylinder_signed_distance_hand_cases():
    cx, cy, R, top = 1.0, -2.0, 2.0, 10.0

    def sd(x, y, z, top=top):
        return float(cylinder_signed_distance(np.array([x + cx, y + cy, z]), cx, cy, R, top))

    # inside: −min(R − ρ, top − z)
    assert sd(1.0, 0.0, 5.0) == pytest.approx(-min(2.0 - 1.0, 10.0 - 5.0))
    assert sd(0.0, 0.5, 9.5) == pytest.approx(-min(2.0 - 0.5, 10.0 - 9.5))
    assert sd(0.0, 0.0, 0.0) == pytest.approx(-2.0)
    # above the top, within the radius: z − top
    assert sd(1.0, 0.0, 13.0) == pytest.approx(3.0)
    assert sd(0.0, 0.0, 10.0) == pytest.approx(0.0)
    # beside: ρ − R
    assert sd(0.0, 5.0, 4.0) == pytest.approx(3.0)
    assert sd(3.0, 4.0, 9.0) == pytest.approx(3.0)
    # diagonal from the rim: hypot(ρ − R, z − top)
    assert sd(5.0, 0.0, 14.0) == pytest.approx(5.0)
    assert sd(0.0, -8.0, 18.0) == pytest.approx(10.0)
    # unlimited cylinder: ρ − R regardless of height
    assert sd(5.0, 0.0, 1e6, top=np.inf) == pytest.approx(3.0)
    assert sd(1.0, 0.0, 1e6, top=np.inf) == pytest.approx(-1.0)
    # batched points and cylinders
    p = np.array([[[1.0, 0.0, 5.0]], [[5.0, 0.0, 14.0]]])  # (2, 1, 3)
    got = cylinder_signed_distance(p, np.zeros(2), np.zeros(2), np.array([2.0, 2.0]), np.array([10.0, np.inf]))
    np.testing.assert_allclose(got, [[-1.0, -1.0], [5.0, 3.0]])


@st.composite
def cylinder_cases(draw, allow_inf_top: bool = True):
    """Cylinder (cx, cy, R, top) and a segment: near/through the body, through the cap, above it,
    vertical, degenerate, or arbitrary."""
    cx, cy = draw(coord()), draw(coord())
    R = draw(radii)
    top = draw(st.floats(0.1, 300.0))
    if allow_inf_top and draw(st.integers(0, 3)) == 0:
        top = math.inf
    h = top if math.isfinite(top) else 300.0
    kind = draw(st.sampled_from(["near", "near", "cap", "above", "vertical", "degenerate", "free"]))
    rel = st.floats(-3.0, 3.0)

    def near_xy():
        return np.array([cx + R * draw(rel), cy + R * draw(rel)])

    if kind == "near":
        a = np.append(near_xy(), draw(st.floats(-0.5 * h, 2.0 * h)))
        b = np.append(near_xy(), draw(st.floats(-0.5 * h, 2.0 * h)))
    elif kind == "cap":  # enters through the top cap
        a = np.append(near_xy(), h + draw(st.floats(0.0, 2.0 * h)))
        b = np.array([cx + R * draw(st.floats(-0.9, 0.9)), cy + R * draw(st.floats(-0.9, 0.9)),
                      h - draw(st.floats(0.0, h))])
    elif kind == "above":  # entirely above the top
        a = np.append(near_xy(), h + draw(st.floats(0.01, 2.0 * h)))
        b = np.append(near_xy(), h + draw(st.floats(0.01, 2.0 * h)))
    elif kind == "vertical":
        xy = near_xy()
        a = np.append(xy, draw(st.floats(-0.5 * h, 3.0 * h)))
        b = np.append(xy, draw(st.floats(-0.5 * h, 3.0 * h)))
    elif kind == "degenerate":
        a = np.append(near_xy(), draw(st.floats(-0.5 * h, 2.0 * h)))
        b = a.copy()
    else:
        a, b = draw(segments(3))
    return a, b, cx, cy, R, top


def _brute_cylinder(a, b, cx, cy, R, top) -> np.ndarray:
    return cylinder_signed_distance(samples(a, b), cx, cy, R, top)


@SETTINGS
@given(case=cylinder_cases())
@example(case=(np.array([-10.0, 0.0, 5.0]), np.array([10.0, 0.0, 5.0]), 0.0, 0.0, 2.0, 10.0))  # through body
@example(case=(np.array([0.5, 0.0, 20.0]), np.array([0.5, 0.0, 8.0]), 0.0, 0.0, 2.0, 10.0))  # through cap
@example(case=(np.array([-10.0, 0.0, 13.0]), np.array([10.0, 0.0, 13.0]), 0.0, 0.0, 2.0, 10.0))  # above
@example(case=(np.array([5.0, 0.0, 0.0]), np.array([5.0, 0.0, 50.0]), 0.0, 0.0, 2.0, 10.0))  # vertical beside
@example(case=(np.array([-10.0, 0.0, 5.0]), np.array([10.0, 0.0, 5.0]), 0.0, 0.0, 2.0, math.inf))
def test_segment_cylinder_clearance_matches_sampling(case):
    a, b, cx, cy, R, top = case
    exact = float(segment_cylinder_clearance(a, b, cx, cy, R, top))
    sampled = _brute_cylinder(a, b, cx, cy, R, top)
    scale = scale_of(a, b, cx, cy, R, top if math.isfinite(top) else 0.0)
    check_against_samples(exact, sampled, float(np.linalg.norm(b - a)), scale)


def test_segment_cylinder_clearance_hand_cases():
    def clr(a, b, top=10.0):
        return float(segment_cylinder_clearance(np.array(a, float), np.array(b, float), 0.0, 0.0, 2.0, top))

    assert clr([-10, 0, 5], [10, 0, 5]) == pytest.approx(-2.0)  # through the body at mid height
    assert clr([-10, 0, 9], [10, 0, 9]) == pytest.approx(-1.0)  # 1 m below the cap
    assert clr([0, 0, 20], [0, 0, 9.5]) == pytest.approx(-0.5)  # vertical through the cap
    assert clr([-10, 0, 13], [10, 0, 13]) == pytest.approx(3.0)  # entirely above
    assert clr([5, 0, 0], [5, 0, 50]) == pytest.approx(3.0)  # vertical beside
    assert clr([5, 0, 14], [5, 0, 14]) == pytest.approx(5.0)  # degenerate, diagonal from the rim
    assert clr([-10, 0, 13], [10, 0, 13], top=np.inf) == pytest.approx(-2.0)
    assert clr([5, -1, 13], [5, 1, 13], top=np.inf) == pytest.approx(3.0)


@settings(max_examples=60, deadline=None)  # each example makes up to 120 scalar calls: 200 took 10-15 s
@given(
    P=st.integers(1, 3),
    S=st.integers(1, 4),
    K=st.integers(1, 5),
    data=st.data(),
)
def test_segment_cylinder_clearance_broadcasting(P, S, K, data):
    box = st.floats(-50.0, 50.0)
    a = data.draw(arrays(np.float64, (P, S, 1, 3), elements=box))
    b = data.draw(arrays(np.float64, (P, S, 1, 3), elements=box))
    cx = data.draw(arrays(np.float64, (K,), elements=st.floats(-30.0, 30.0)))
    cy = data.draw(arrays(np.float64, (K,), elements=st.floats(-30.0, 30.0)))
    R = data.draw(arrays(np.float64, (K,), elements=st.floats(0.1, 30.0)))
    top = data.draw(arrays(np.float64, (K,), elements=st.one_of(st.floats(0.1, 60.0), st.just(math.inf))))
    got = segment_cylinder_clearance(a, b, cx, cy, R, top)
    assert got.shape == (P, S, K)
    got_2d = segment_cylinder_clearance_2d(a, b, cx, cy, R)
    assert got_2d.shape == (P, S, K)
    expected = np.empty((P, S, K))
    expected_2d = np.empty((P, S, K))
    for i in range(P):
        for j in range(S):
            for k in range(K):
                expected[i, j, k] = segment_cylinder_clearance(a[i, j, 0], b[i, j, 0], cx[k], cy[k], R[k], top[k])
                expected_2d[i, j, k] = segment_cylinder_clearance_2d(a[i, j, 0], b[i, j, 0], cx[k], cy[k], R[k])
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got_2d, expected_2d, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# 4. 2-D cylinder clearance == 3-D clearance with an unlimited top
# ---------------------------------------------------------------------------------------------


@SETTINGS
@given(case=cylinder_cases(allow_inf_top=False))
def test_segment_cylinder_clearance_2d_equals_infinite_top(case):
    a, b, cx, cy, R, _ = case
    two_d = float(segment_cylinder_clearance_2d(a, b, cx, cy, R))
    three_d = float(segment_cylinder_clearance(a, b, cx, cy, R, math.inf))
    assert two_d == pytest.approx(three_d, rel=1e-12, abs=1e-12)
    # and it is the brute-force 2-D clearance
    sampled = _brute_cylinder(a, b, cx, cy, R, math.inf)
    check_against_samples(two_d, sampled, float(np.linalg.norm(b[:2] - a[:2])), scale_of(a, b, cx, cy, R))


# ---------------------------------------------------------------------------------------------
# 5. spherical encoding
# ---------------------------------------------------------------------------------------------


def _wrap(x: np.ndarray) -> np.ndarray:
    return (x + np.pi) % (2.0 * np.pi) - np.pi


@SETTINGS
@given(
    start=points3,
    batch=st.one_of(st.just(()), st.tuples(st.integers(1, 4))),
    n=st.integers(1, 8),
    data=st.data(),
)
def test_spherical_decode_encode_round_trip(start, batch, n, data):
    shape = (*batch, n)
    r = data.draw(arrays(np.float64, shape, elements=st.floats(1.0, 500.0)))
    psi = data.draw(arrays(np.float64, shape, elements=st.floats(-1.4, 1.4)))
    phi = data.draw(arrays(np.float64, shape, elements=st.floats(-3.0, 3.0)))
    pts = spherical_to_cartesian(start, r, psi, phi)
    assert pts.shape == (*shape, 3)
    r2, psi2, phi2 = cartesian_to_spherical(start, pts)
    assert r2.shape == psi2.shape == phi2.shape == shape
    np.testing.assert_allclose(r2, r, rtol=1e-9)
    np.testing.assert_allclose(psi2, psi, rtol=1e-9, atol=1e-9)
    assert np.all(np.abs(_wrap(phi2 - phi)) <= 1e-9)
    assert np.all((phi2 > -np.pi) & (phi2 <= np.pi))
    assert np.all(np.abs(psi2) <= np.pi / 2)


@SETTINGS
@given(
    start=points3,
    batch=st.one_of(st.just(()), st.tuples(st.integers(1, 4))),
    n=st.integers(1, 8),
    data=st.data(),
)
def test_spherical_encode_decode_round_trip(start, batch, n, data):
    pts = data.draw(arrays(np.float64, (*batch, n, 3), elements=coord()))
    r, psi, phi = cartesian_to_spherical(start, pts)
    assert np.all(r >= 0.0)
    back = spherical_to_cartesian(start, r, psi, phi)
    np.testing.assert_allclose(back, pts, rtol=0, atol=1e-9 * scale_of(pts, start) * n)


def test_spherical_to_cartesian_hand_example():
    start = np.array([1.0, 2.0, 3.0])
    r = np.array([2.0, 4.0])
    psi = np.array([0.0, np.pi / 6])
    phi = np.array([np.pi / 2, np.pi])
    got = spherical_to_cartesian(start, r, psi, phi)
    # step 1: 2 m due +y; step 2: 4 m at 30° elevation towards −x → (−4 cos30°, 0, 4 sin30°)
    p1 = [1.0, 4.0, 3.0]
    p2 = [1.0 - 4.0 * math.cos(math.pi / 6), 4.0, 3.0 + 2.0]
    np.testing.assert_allclose(got, [p1, p2], atol=1e-12)
    r2, psi2, phi2 = cartesian_to_spherical(start, got)
    np.testing.assert_allclose(r2, r)
    np.testing.assert_allclose(psi2, psi, atol=1e-12)
    np.testing.assert_allclose(phi2, phi)
    # batched: two paths sharing the same start
    got_b = spherical_to_cartesian(start, np.stack([r, r]), np.stack([psi, psi]), np.stack([phi, phi]))
    assert got_b.shape == (2, 2, 3)
    np.testing.assert_allclose(got_b[1], [p1, p2], atol=1e-12)
