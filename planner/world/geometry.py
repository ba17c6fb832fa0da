"""Exact, vectorised distances between path segments and obstacles, and the spherical encoding
(docs/method.md §2.2–2.3, §3.1, §4.3).

All functions broadcast: segment endpoints ``a``, ``b`` shaped ``(..., D)`` and obstacle parameters
shaped ``(K,)`` (or ``(K, D)``) give results shaped ``(..., K)`` when the caller inserts the axes.
Clearances are signed: distance from the segment to the obstacle's surface, negative when the segment
enters it (its magnitude is then the depth of the closest approach), so penalties can grow with depth.
"""

from __future__ import annotations

import numpy as np

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
GOLDEN_ITERS = 64  # interval shrinks to 0.618^64 ≈ 4e-14 of the segment


def _dot(u: tuple[np.ndarray, ...], v: tuple[np.ndarray, ...]) -> np.ndarray:
    """Component-wise dot product: keeps the long (segment) axis innermost instead of a length-3 axis."""
    out = u[0] * v[0]
    for ui, vi in zip(u[1:], v[1:]):
        out = out + ui * vi
    return out


def segment_point_distance(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Euclidean distance from point(s) p to segment(s) a→b in any dimension D; shapes broadcast (..., D).

    For speed put the many-element axis last among the leading axes, e.g. a, b (1, M, 3) and p (K, 1, 3).
    """
    a, b, p = (np.asarray(x, dtype=float) for x in (a, b, p))
    dim = a.shape[-1]
    d = tuple(b[..., i] - a[..., i] for i in range(dim))
    w = tuple(p[..., i] - a[..., i] for i in range(dim))
    dd = _dot(d, d)
    t = np.clip(_dot(w, d) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    e = tuple(wi - t * di for wi, di in zip(w, d))
    return np.sqrt(_dot(e, e))


def segment_point_distance_2d(
    ax: np.ndarray, ay: np.ndarray, bx: np.ndarray, by: np.ndarray, px: np.ndarray, py: np.ndarray
) -> np.ndarray:
    """Same as :func:`segment_point_distance` for D = 2 with separate coordinate arrays (hot path)."""
    dx = bx - ax
    dy = by - ay
    dd = dx * dx + dy * dy
    wx = px - ax
    wy = py - ay
    t = np.clip((wx * dx + wy * dy) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    ex = wx - t * dx
    ey = wy - t * dy
    return np.sqrt(ex * ex + ey * ey)


def segment_sphere_clearance(
    a: np.ndarray, b: np.ndarray, center: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Signed clearance of segment a→b from a sphere: ‖closest point − c‖ − R. a, b, center: (..., 3)."""
    return segment_point_distance(a, b, center) - radius


def cylinder_signed_distance(
    p: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, top: np.ndarray
) -> np.ndarray:
    """Signed distance from point(s) p (..., 3) to a solid vertical cylinder from the ground to ``top``.

    ``top = inf`` gives the unlimited cylinder (then this is ρ − R). Convex in p, which the segment
    minimiser relies on.
    """
    u = np.hypot(p[..., 0] - cx, p[..., 1] - cy) - radius
    with np.errstate(invalid="ignore"):
        w = np.where(np.isinf(top), -np.inf, p[..., 2] - top)
    outside = np.sqrt(np.maximum(u, 0.0) ** 2 + np.maximum(w, 0.0) ** 2)
    return outside + np.minimum(np.maximum(u, w), 0.0)


def segment_cylinder_clearance_2d(
    a: np.ndarray, b: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray
) -> np.ndarray:
    """Signed clearance of segment a→b from an unlimited vertical cylinder: 2-D distance − R (exact)."""
    return segment_point_distance_2d(a[..., 0], a[..., 1], b[..., 0], b[..., 1], cx, cy) - radius


def segment_cylinder_clearance(
    a: np.ndarray, b: np.ndarray, cx: np.ndarray, cy: np.ndarray, radius: np.ndarray, top: np.ndarray
) -> np.ndarray:
    """Signed clearance of segment a→b (..., 3) from a vertical cylinder with a finite or infinite top.

    min over t of a convex function of t, found by a vectorised golden-section search to ~1e-13 of the
    segment length; unlimited cylinders use the closed 2-D form.
    """
    a, b, cx, cy, radius, top = np.broadcast_arrays(
        a, b, *(np.asarray(v, dtype=float)[..., None] for v in (cx, cy, radius, top))
    )
    cx, cy, radius, top = cx[..., 0], cy[..., 0], radius[..., 0], top[..., 0]
    exact_2d = segment_cylinder_clearance_2d(a, b, cx, cy, radius)
    if np.all(np.isinf(top)):
        return exact_2d

    def f(t: np.ndarray) -> np.ndarray:
        return cylinder_signed_distance(a + t[..., None] * (b - a), cx, cy, radius, top)

    lo = np.zeros(cx.shape)
    hi = np.ones(cx.shape)
    x1 = hi - _GOLDEN * (hi - lo)
    x2 = lo + _GOLDEN * (hi - lo)
    f1, f2 = f(x1), f(x2)
    for _ in range(GOLDEN_ITERS):  # loop over search steps, not over segments or obstacles
        left = f1 <= f2  # minimum lies in [lo, x2]
        hi = np.where(left, x2, hi)
        lo = np.where(left, lo, x1)
        xn = np.where(left, hi - _GOLDEN * (hi - lo), lo + _GOLDEN * (hi - lo))
        fn = f(xn)
        x1, x2 = np.where(left, xn, x2), np.where(left, x1, xn)
        f1, f2 = np.where(left, fn, f2), np.where(left, f1, fn)
    best = np.minimum(np.minimum(f1, f2), np.minimum(f(lo * 0.0), f(hi * 0.0 + 1.0)))
    return np.where(np.isinf(top), exact_2d, best)


def spherical_to_cartesian(
    start: np.ndarray, r: np.ndarray, psi: np.ndarray, phi: np.ndarray
) -> np.ndarray:
    """Decode (r, ψ elevation, φ azimuth) steps into waypoints P_1…P_n (docs/method.md §3.1).

    start (3,); r, psi, phi (..., n) → points (..., n, 3) with P_k = P_{k−1} + r_k (cosψ cosφ, cosψ sinφ, sinψ).
    """
    cpsi = np.cos(psi)
    steps = np.stack([r * cpsi * np.cos(phi), r * cpsi * np.sin(phi), r * np.sin(psi)], axis=-1)
    return np.asarray(start, dtype=float) + np.cumsum(steps, axis=-2)


def cartesian_to_spherical(
    start: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inverse of :func:`spherical_to_cartesian`: points (..., n, 3) → r, ψ ∈ [−π/2, π/2], φ ∈ (−π, π]."""
    start = np.broadcast_to(np.asarray(start, dtype=float), points[..., :1, :].shape)
    steps = np.diff(np.concatenate([start, points], axis=-2), axis=-2)
    horiz = np.hypot(steps[..., 0], steps[..., 1])
    r = np.hypot(horiz, steps[..., 2])
    return r, np.arctan2(steps[..., 2], horiz), np.arctan2(steps[..., 1], steps[..., 0])


def horizontal_turn(seg: np.ndarray) -> np.ndarray:
    """Heading change (rad, in [0, π]) between consecutive segment vectors (..., S, 3) → (..., S − 1)."""
    x, y = seg[..., 0], seg[..., 1]
    cross = x[..., :-1] * y[..., 1:] - y[..., :-1] * x[..., 1:]
    dot = x[..., :-1] * x[..., 1:] + y[..., :-1] * y[..., 1:]
    return np.abs(np.arctan2(cross, dot))
