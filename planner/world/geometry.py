"""Exact, vectorised distances between path segments and obstacles, and the spherical encoding
(docs/method.md §2.2–2.3, §3.1, §4.3).

All functions broadcast: segment endpoints ``a``, ``b`` shaped ``(..., D)`` and obstacle parameters
shaped ``(K,)`` (or ``(K, D)``) give results shaped ``(..., K)`` when the caller inserts the axes.
Clearances are signed: distance from the segment to the obstacle's surface, negative when the segment
enters it (its magnitude is then the depth of the closest approach), so penalties can grow with depth.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from planner.world.environment import Prisms

_GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
GOLDEN_ITERS = 64  # interval shrinks to 0.618^64 ≈ 4e-14 of the segment
# (K, V, M) elements a chunk of segment_prism_clearance holds: its few dozen float temporaries stay under ~50 MB
PRISM_CHUNK_ELEMENTS = 40_000


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
    ax: np.ndarray | float, ay: np.ndarray | float, bx: np.ndarray | float, by: np.ndarray | float,
    px: np.ndarray | float, py: np.ndarray | float,
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
    a: np.ndarray, b: np.ndarray, center: np.ndarray, radius: np.ndarray | float
) -> np.ndarray:
    """Signed clearance of segment a→b from a sphere: ‖closest point − c‖ − R. a, b, center: (..., 3)."""
    return segment_point_distance(a, b, center) - radius


def cylinder_signed_distance(
    p: np.ndarray, cx: np.ndarray | float, cy: np.ndarray | float, radius: np.ndarray | float,
    top: np.ndarray | float,
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
    a: np.ndarray, b: np.ndarray, cx: ArrayLike, cy: ArrayLike, radius: ArrayLike, top: ArrayLike
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


def _edge_sq(px: np.ndarray, py: np.ndarray, ax: np.ndarray, ay: np.ndarray, ex: np.ndarray, ey: np.ndarray,
             l2: np.ndarray) -> np.ndarray:  # broadcastable arrays
    """Squared plan-view distance from points (px, py) to edges A + s·E, s ∈ [0, 1] (``l2`` = |E|², 1 if zero)."""
    wx = px - ax
    wy = py - ay
    s = np.clip((wx * ex + wy * ey) / l2, 0.0, 1.0)
    qx = wx - s * ex
    qy = wy - s * ey
    return qx * qx + qy * qy


def _inside_count(px: np.ndarray, py: np.ndarray, ax: np.ndarray, ay: np.ndarray, bx: np.ndarray,
                  by: np.ndarray) -> np.ndarray:  # broadcastable arrays, edge axis -2
    """Even-odd containment (polygons.contains) of points in each padded polygon: edges on axis −2."""
    straddles = (ay > py) != (by > py)
    dy = np.where(by != ay, by - ay, 1.0)
    x_at = ax + (py - ay) * (bx - ax) / dy
    return (np.count_nonzero(straddles & (px < x_at), axis=-2) % 2) == 1


def _prism_edges(prisms: Prisms) -> tuple[np.ndarray, ...]:
    """The prisms' padded edges (K, V, 1): start x, y, direction x, y and squared length (1 where zero)."""
    ax, ay, bx, by = (e[..., None] for e in prisms.padded)
    ex, ey = bx - ax, by - ay
    l2 = ex * ex + ey * ey
    return ax, ay, bx, by, ex, ey, np.where(l2 > 0.0, l2, 1.0)


def prism_signed_distance(p: np.ndarray, prisms: Prisms) -> np.ndarray:
    """Signed distance (K, ...) from points p (..., 3) to each prism's solid (docs/method.md §2.7): u the signed
    plan-view distance (negative inside the polygon; the other way round for a keep-in polygon), w = max(f − z,
    z − h); unlimited floors and ceilings (∓inf) give w = −inf, never NaN."""
    p = np.asarray(p, dtype=float)
    shape = p.shape[:-1]
    q = p.reshape(-1, 3)
    if not len(prisms):
        return np.zeros((0, *shape))
    ax, ay, bx, by, ex, ey, l2 = _prism_edges(prisms)
    px, py, pz = q[:, 0], q[:, 1], q[:, 2]
    u = np.sqrt(_edge_sq(px, py, ax, ay, ex, ey, l2).min(axis=1))  # (K, M)
    inside = _inside_count(px, py, ax, ay, bx, by)
    u = np.where(inside != prisms.keep_in[:, None], -u, u)
    w = np.maximum(prisms.floor[:, None] - pz, pz - prisms.ceiling[:, None])
    d = np.sqrt(np.maximum(u, 0.0) ** 2 + np.maximum(w, 0.0) ** 2) + np.minimum(np.maximum(u, w), 0.0)
    return d.reshape((len(prisms), *shape))


def _ratio(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """num / den where den ≠ 0, else 0 (a breakpoint that does not exist is put at the segment's start)."""
    nz = den != 0.0
    return np.where(nz, num / np.where(nz, den, 1.0), 0.0)


def segment_prism_clearance(a: ArrayLike, b: ArrayLike, prisms: Prisms) -> np.ndarray:
    """Signed clearance (K, ...) of segments a→b (..., 3) from each prism's solid, exactly (docs/method.md §2.7).

    Outside: the least over edges e of the convex g_e(t) = dist(p_xy(t), e)² + max(w(t), 0)², a quadratic between
    its breakpoints (the foot on e's line passing its ends, z crossing floor and ceiling), so on each piece its
    vertex (found from three values, then g evaluated there) or an end is the piece's least; and on the parts whose
    plan view is in the solid's (between crossings with the edges), the least max(w, 0). A segment that enters the
    solid gets the least d_prism at the middles of the parts inside (negative). Vectorised over prisms, their
    edges (padded to one length) and segments: arrays (K, V, M), M taken in chunks of at most
    :data:`PRISM_CHUNK_ELEMENTS` // (K·V) segments (each segment's result is its own, so chunking changes no bit)."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    shape = a.shape[:-1]
    k_n = len(prisms)
    if not k_n:
        return np.zeros((0, *shape))
    a, b = a.reshape(-1, 3), b.reshape(-1, 3)
    edges = _prism_edges(prisms)
    rows = max(1, PRISM_CHUNK_ELEMENTS // edges[0].size)
    out = np.empty((k_n, len(a)))
    for i in range(0, len(a), rows):
        out[:, i:i + rows] = _segment_prism_chunk(a[i:i + rows], b[i:i + rows], prisms, edges)
    return out.reshape((k_n, *shape))


def _segment_prism_chunk(a: np.ndarray, b: np.ndarray, prisms: Prisms, edges: tuple[np.ndarray, ...]) -> np.ndarray:
    """:func:`segment_prism_clearance` (K, M) of segments a→b (M, 3), the prisms' ``edges`` from
    :func:`_prism_edges`."""
    k_n = len(prisms)
    ax, ay, az = a[:, 0], a[:, 1], a[:, 2]
    dx, dy, dz = b[:, 0] - ax, b[:, 1] - ay, b[:, 2] - az
    Ax, Ay, Bx, By, ex, ey, l2 = edges  # edge ends A, B
    f, h = prisms.floor[:, None], prisms.ceiling[:, None]  # (K, 1)
    keep = prisms.keep_in[:, None]
    f3, h3 = f[..., None], h[..., None]

    def g(t: np.ndarray) -> np.ndarray:  # g_e(t), broadcast over leading axes
        z = az + t * dz
        wo = np.maximum(np.maximum(f3 - z, z - h3), 0.0)
        return _edge_sq(ax + t * dx, ay + t * dy, Ax, Ay, ex, ey, l2) + wo * wo

    with np.errstate(invalid="ignore", divide="ignore"):
        s0 = ((ax - Ax) * ex + (ay - Ay) * ey) / l2
        s1 = (dx * ex + dy * ey) / l2
        tf, th = _ratio(f - az, dz), _ratio(h - az, dz)  # (K, M)
        knots = np.stack(np.broadcast_arrays(np.zeros(1), _ratio(-s0, s1), _ratio(1.0 - s0, s1), tf[:, None],
                                             th[:, None], np.ones(1)))
    knots = np.sort(np.clip(knots, 0.0, 1.0), axis=0)  # (6, K, V, M)
    gk = g(knots)
    lo, hi = knots[:-1], knots[1:]
    gl, gh, gm = gk[:-1], gk[1:], g(0.5 * (lo + hi))
    qa = 2.0 * gl - 4.0 * gm + 2.0 * gh
    qb = -3.0 * gl + 4.0 * gm - gh
    up = qa > 0.0
    vertex = lo + np.clip(-qb / (2.0 * np.where(up, qa, 1.0)), 0.0, 1.0) * (hi - lo)
    piecewise = np.minimum(gk.min(axis=0), np.where(up, g(vertex), np.inf).min(axis=0))  # (K, V, M)
    # the parts of the segment between its crossings with the edges; inside the solid's plan view or not
    oa = ex * (ay - Ay) - ey * (ax - Ax)
    ob = ex * (ay + dy - Ay) - ey * (ax + dx - Ax)
    sa = dx * (Ay - ay) - dy * (Ax - ax)
    sb = dx * (By - ay) - dy * (Bx - ax)
    hit = ((oa > 0.0) != (ob > 0.0)) & ((sa > 0.0) != (sb > 0.0))
    # where the whole segment is between floor and ceiling, g_e is the plan-view distance to e squared: the least
    # is the closed form of two segments (zero where they cross, else an end's distance to the other segment)
    dd = dx * dx + dy * dy
    dd = np.where(dd > 0.0, dd, 1.0)
    ends = np.minimum(np.minimum(_edge_sq(ax, ay, Ax, Ay, ex, ey, l2), _edge_sq(ax + dx, ay + dy, Ax, Ay, ex, ey, l2)),
                      np.minimum(_edge_sq(Ax, Ay, ax, ay, dx, dy, dd), _edge_sq(Bx, By, ax, ay, dx, dy, dd)))
    level = ((f <= np.minimum(az, az + dz)) & (np.maximum(az, az + dz) <= h))[:, None]  # (K, 1, M)
    best = np.where(level, np.where(hit, 0.0, ends), piecewise).min(axis=1)  # (K, M)
    tc = np.sort(np.where(hit, oa / np.where(hit, oa - ob, 1.0), np.inf), axis=1)  # (K, V, M)
    n = np.count_nonzero(hit, axis=1)  # (K, M)
    v_n = tc.shape[1]
    bounds = np.concatenate([np.zeros((1, k_n, len(a))), np.minimum(tc, 1.0).transpose(1, 0, 2),
                             np.ones((1, k_n, len(a)))])  # (V + 2, K, M)
    lo, hi = bounds[:-1], bounds[1:]
    i = np.arange(v_n + 1)[:, None, None]
    in0 = _inside_count(ax, ay, Ax, Ay, Bx, By)
    solid = ((in0[None] ^ (i % 2 == 1)) ^ keep[None]) & (i <= n[None])
    z0, z1 = az + lo * dz, az + hi * dz
    wmin = np.maximum(np.maximum(f - np.maximum(z0, z1), np.minimum(z0, z1) - h), 0.0)
    best = np.minimum(best, np.where(solid, wmin * wmin, np.inf).min(axis=0))
    # the parts inside the solid: in its plan view and between floor and ceiling
    flat = dz == 0.0
    at = (f <= az) & (az <= h)
    tw0 = np.where(flat, np.where(at, 0.0, 1.0), np.maximum(np.minimum(tf, th), 0.0))
    tw1 = np.where(flat, np.where(at, 1.0, 0.0), np.minimum(np.maximum(tf, th), 1.0))
    s_lo, s_hi = np.maximum(lo, tw0), np.minimum(hi, tw1)
    ii, kk, mm = np.nonzero(solid & (s_hi > s_lo))
    out = np.sqrt(best)
    if len(kk):
        tm = 0.5 * (s_lo[ii, kk, mm] + s_hi[ii, kk, mm])
        px, py, pz = ax[mm] + tm * dx[mm], ay[mm] + tm * dy[mm], az[mm] + tm * dz[mm]
        u = -np.sqrt(_edge_sq(px[:, None], py[:, None], Ax[kk, :, 0], Ay[kk, :, 0], ex[kk, :, 0], ey[kk, :, 0],
                              l2[kk, :, 0]).min(axis=1))
        w = np.maximum(f[kk, 0] - pz, pz - h[kk, 0])
        neg = np.full(out.shape, np.inf)
        np.minimum.at(neg, (kk, mm), np.maximum(u, w))
        out = np.where(np.isfinite(neg), neg, out)
    return out


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
