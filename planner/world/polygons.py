"""Plan-view polygons: orientation, simplicity, containment and distance (docs/method.md §2.7).

Pure functions on (V, 2) vertex arrays in metres, the polygon closed implicitly (the last vertex joins the first).
They validate the polygons a scenario or an importer brings, and are the reference the compiled prism tests follow.
"""

from __future__ import annotations

import numpy as np


def signed_area(v: np.ndarray) -> float:
    """Shoelace area (m²) of polygon ``v`` (V, 2): positive when its vertices run counter-clockwise."""
    v = np.asarray(v, dtype=float)
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def counter_clockwise(v: np.ndarray) -> np.ndarray:
    """Polygon ``v`` with its vertices counter-clockwise, the closing duplicate (if any) dropped."""
    v = np.asarray(v, dtype=float).reshape(-1, 2)
    if len(v) > 1 and np.array_equal(v[0], v[-1]):
        v = v[:-1]
    return v if signed_area(v) >= 0.0 else v[::-1].copy()


def _orient(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Twice the signed area of triangles a, b, c (..., 2): > 0 when c is left of a→b."""
    return (b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0])


def _on_segment(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Whether c, collinear with a→b, lies on it."""
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    return np.all((c >= lo) & (c <= hi), axis=-1)


def simplicity_problem(v: np.ndarray) -> str | None:
    """Why polygon ``v`` (V, 2) is not a simple polygon, or None when it is: fewer than three distinct vertices, a
    repeated vertex, zero area, or two edges that touch or cross other than where neighbours meet."""
    v = np.asarray(v, dtype=float).reshape(-1, 2)
    if len(v) > 1 and np.array_equal(v[0], v[-1]):
        v = v[:-1]
    n = len(v)
    if n < 3:
        return f"{n} vertices (a polygon needs at least 3)"
    if not np.all(np.isfinite(v)):
        return "a vertex is not a finite number"
    if len(np.unique(v, axis=0)) < n:
        return "a vertex is repeated"
    a, b = v, np.roll(v, -1, axis=0)
    i, j = np.triu_indices(n, k=1)
    adjacent = (j == i + 1) | ((i == 0) & (j == n - 1))
    i, j = i[~adjacent], j[~adjacent]
    p1, p2, q1, q2 = a[i], b[i], a[j], b[j]
    d1, d2 = _orient(q1, q2, p1), _orient(q1, q2, p2)
    d3, d4 = _orient(p1, p2, q1), _orient(p1, p2, q2)
    cross = (d1 * d2 < 0) & (d3 * d4 < 0)
    touch = ((d1 == 0) & _on_segment(q1, q2, p1)) | ((d2 == 0) & _on_segment(q1, q2, p2)) \
        | ((d3 == 0) & _on_segment(p1, p2, q1)) | ((d4 == 0) & _on_segment(p1, p2, q2))
    bad = np.flatnonzero(cross | touch)
    if len(bad):
        k = bad[0]
        return f"it intersects itself (edge {i[k]} meets edge {j[k]})"
    if abs(signed_area(v)) <= 1e-9 * max(1.0, float(np.ptp(v)) ** 2):
        return "its area is zero"
    return None


def contains(v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Whether points ``p`` (..., 2) are inside polygon ``v`` (V, 2), by the even-odd crossing rule (a point on an
    edge may count either way)."""
    v = np.asarray(v, dtype=float)
    p = np.asarray(p, dtype=float)
    a, b = v, np.roll(v, -1, axis=0)
    px, py = p[..., 0, None], p[..., 1, None]
    straddles = (a[:, 1] > py) != (b[:, 1] > py)
    dy = np.where(b[:, 1] != a[:, 1], b[:, 1] - a[:, 1], 1.0)
    x_at = a[:, 0] + (py - a[:, 1]) * (b[:, 0] - a[:, 0]) / dy
    return (np.count_nonzero(straddles & (px < x_at), axis=-1) % 2) == 1


def boundary_distance(v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Distance (m) from points ``p`` (..., 2) to the edges of polygon ``v`` (V, 2)."""
    v = np.asarray(v, dtype=float)
    p = np.asarray(p, dtype=float)[..., None, :]
    a, b = v, np.roll(v, -1, axis=0)
    d = b - a
    dd = np.einsum("ij,ij->i", d, d)
    t = np.clip(np.einsum("...ij,ij->...i", p - a, d) / np.where(dd > 0, dd, 1.0), 0.0, 1.0)
    foot = a + t[..., None] * d
    return np.min(np.linalg.norm(p - foot, axis=-1), axis=-1)


def signed_distance(v: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Signed plan-view distance (m) from points ``p`` (..., 2) to polygon ``v``: negative inside."""
    d = boundary_distance(v, p)
    return np.where(contains(v, p), -d, d)


def enclosing_circle(v: np.ndarray) -> tuple[float, float, float]:
    """A circle (x, y, radius) around polygon ``v``: centred on its vertices' bounding box, the broad phase's disc."""
    v = np.asarray(v, dtype=float)
    c = 0.5 * (v.min(axis=0) + v.max(axis=0))
    return float(c[0]), float(c[1]), float(np.max(np.linalg.norm(v - c, axis=1)))
