"""Cubic Bézier smoothing of waypoint paths and its derivatives (SPEC §6, §P Properties 1–4).

Segment k from P_k to P_{k+1} (length r_k, unit direction d̂_k) gets the control points
Q0 = P_k, Q1 = P_k + (r_k/3) d̂_k, Q2 = P_{k+1} − (r_k/3) d̂_{k+1}, Q3 = P_{k+1}; the last segment uses its
own direction at both ends, so it stays straight. Tangents at waypoints equal the segment directions
(Property 1), and the curvature near P_{k+1} grows as 4 sin θ / r_k for a turn θ there.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def bezier_controls(paths: np.ndarray) -> np.ndarray:
    """Control points for every segment: paths (..., N, 3) → (..., N−1, 4, 3) metres."""
    a = paths[..., :-1, :]
    b = paths[..., 1:, :]
    d = b - a
    r = np.linalg.norm(d, axis=-1, keepdims=True)
    u = d / np.maximum(r, _EPS)
    u_next = np.concatenate([u[..., 1:, :], u[..., -1:, :]], axis=-2)
    return np.stack([a, a + r / 3.0 * u, b - r / 3.0 * u_next, b], axis=-2)


def _evaluate(q0, q1, q2, q3, t):  # noqa: ANN001, ANN202 - broadcastable arrays
    s = 1.0 - t
    pos = s**3 * q0 + 3 * s**2 * t * q1 + 3 * s * t**2 * q2 + t**3 * q3
    d1 = 3 * (s**2 * (q1 - q0) + 2 * s * t * (q2 - q1) + t**2 * (q3 - q2))
    d2 = 6 * (s * (q2 - 2 * q1 + q0) + t * (q3 - 2 * q2 + q1))
    return pos, d1, d2


def bezier_derivatives(ctrl: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point, first and second derivative of cubic Béziers at parameters t.

    ctrl (..., 4, 3), t (m,) → each (..., m, 3); derivatives are with respect to t ∈ [0, 1].
    """
    q = [ctrl[..., i, None, :] for i in range(4)]
    return _evaluate(*q, np.asarray(t, dtype=float)[:, None])


def curvature(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
    """κ = ‖B' × B''‖ / ‖B'‖³ (1/m) for derivative arrays (..., 3) → (...)."""
    cross = np.linalg.norm(np.cross(d1, d2), axis=-1)
    speed = np.linalg.norm(d1, axis=-1)
    return cross / np.maximum(speed, _EPS) ** 3


def climb_angle(v: np.ndarray) -> np.ndarray:
    """Flight-path angle of direction vectors (..., 3) → radians, positive up."""
    return np.arctan2(v[..., 2], np.hypot(v[..., 0], v[..., 1]))


def sample_trajectory(waypoints: np.ndarray, spacing: float) -> dict[str, np.ndarray]:
    """Sample the smoothed trajectory of one path roughly every ``spacing`` metres.

    waypoints (N, 3) → dict with ``points`` (M, 3), ``tangent`` (M, 3) (d/dt), ``curvature`` (M,),
    ``segment`` (M,) index of the Bézier segment, ``s`` (M,) arc length from the start (m).
    """
    ctrl = bezier_controls(np.asarray(waypoints, dtype=float))  # (S, 4, 3)
    chord = np.linalg.norm(ctrl[:, 3] - ctrl[:, 0], axis=-1)
    counts = np.maximum(np.ceil(chord / spacing).astype(int), 1)
    seg = np.repeat(np.arange(len(ctrl)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    t = (np.arange(seg.size) - first) / counts[seg]
    seg = np.append(seg, len(ctrl) - 1)
    t = np.append(t, 1.0)
    q = ctrl[seg]  # (M, 4, 3)
    pos, d1, d2 = _evaluate(q[:, 0], q[:, 1], q[:, 2], q[:, 3], t[:, None])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pos, axis=0), axis=-1))])
    return {"points": pos, "tangent": d1, "curvature": curvature(d1, d2), "segment": seg, "s": arc}


# --- closed forms used by the cost ------------------------------------------------------------------
# With u = d̂_k, v = d̂_{k+1} and r = r_k the segment's Bézier has B'(t) = r (α u + β v) with
# α = (1−t)(1+3t), β = t(3t−2), α + β = 1, and B''(t) = 2r (1−3t)(u − v). Hence
# κ(t) = 2 |1−3t| sin θ / (r ‖α u + β v‖³): the peak depends on θ alone, κ_max = G(cos θ) sin θ / r
# (G = 4 for small turns; it grows as the turn sharpens). G is tabulated once here.
_T_FINE = np.linspace(1.0 / 3.0, 1.0, 4001)
_COS_GRID = np.linspace(-1.0, 1.0, 2001)


def _peak_factor_table() -> np.ndarray:
    al = (1 - _T_FINE) * (1 + 3 * _T_FINE)
    be = _T_FINE * (3 * _T_FINE - 2)
    norm2 = al**2 + be**2 + 2 * al * be * _COS_GRID[:, None]
    return (2 * (3 * _T_FINE - 1) / np.maximum(norm2, 1e-12) ** 1.5).max(axis=1)


_PEAK_FACTOR = _peak_factor_table()


def peak_factor(cos_turn: np.ndarray) -> np.ndarray:
    """G(cos θ) from the table by linear interpolation on its uniform grid (faster than np.interp)."""
    f = (np.clip(cos_turn, -1.0, 1.0) + 1.0) * ((len(_COS_GRID) - 1) / 2.0)
    i = np.minimum(f.astype(np.intp), len(_COS_GRID) - 2)
    w = f - i
    return _PEAK_FACTOR[i] * (1.0 - w) + _PEAK_FACTOR[i + 1] * w


def peak_curvature(seg_len: np.ndarray, cos_turn: np.ndarray) -> np.ndarray:
    """Largest curvature (1/m) on the Bézier of a segment of length ``seg_len`` whose direction turns
    by θ (``cos_turn`` = cos θ = d̂_k · d̂_{k+1}) into the next segment; shapes broadcast."""
    c = np.clip(cos_turn, -1.0, 1.0)
    return peak_factor(c) * np.sqrt(1.0 - c * c) / np.maximum(seg_len, _EPS)


def extrapolated_direction(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The Bézier tangent runs along u + β(v − u) for β ∈ [−1/3, 1]; this is its β = −1/3 end,
    (4u − v)/3, which with u and v bounds the curve's climb angle for the shallow angles flown."""
    return (4.0 * u - v) / 3.0
