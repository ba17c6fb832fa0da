"""Cubic Bézier smoothing of waypoint paths and its derivatives (docs/method.md §11, paper Properties 1–4).

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


def bezier_point(q0: np.ndarray, q1: np.ndarray, q2: np.ndarray, q3: np.ndarray, t: np.ndarray) -> np.ndarray:
    """B(t) = (1−t)³ Q0 + 3(1−t)²t Q1 + 3(1−t)t² Q2 + t³ Q3 for broadcastable arrays."""
    s = 1.0 - t
    return s**3 * q0 + 3 * s**2 * t * q1 + 3 * s * t**2 * q2 + t**3 * q3


def _evaluate(q0: np.ndarray, q1: np.ndarray, q2: np.ndarray, q3: np.ndarray,
              t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = 1.0 - t
    pos = bezier_point(q0, q1, q2, q3, t)
    d1 = 3 * (s**2 * (q1 - q0) + 2 * s * t * (q2 - q1) + t**2 * (q3 - q2))
    d2 = 6 * (s * (q2 - 2 * q1 + q0) + t * (q3 - 2 * q2 + q1))
    return pos, d1, d2


def bezier_derivatives(ctrl: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Point, first and second derivative of cubic Béziers at parameters t.

    ctrl (..., 4, 3), t (m,) → each (..., m, 3); derivatives are with respect to t ∈ [0, 1].
    """
    q0, q1, q2, q3 = (ctrl[..., i, None, :] for i in range(4))
    return _evaluate(q0, q1, q2, q3, np.asarray(t, dtype=float)[:, None])


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
    # |B'(t)| ≤ 3 · longest control leg, so this many steps keeps samples ≤ spacing apart on the curve
    legs = np.linalg.norm(np.diff(ctrl, axis=1), axis=-1).max(axis=1)
    counts = np.maximum(np.ceil(3.0 * legs / spacing).astype(int), 1)
    seg, t = segment_samples(counts)
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


PEAK_FACTOR = _peak_factor_table()  # G on the uniform grid of cos θ in [−1, 1]; the compiled kernel reads it too


def peak_factor(cos_turn: np.ndarray) -> np.ndarray:
    """G(cos θ) from the table by linear interpolation on its uniform grid (faster than np.interp)."""
    f = (np.clip(cos_turn, -1.0, 1.0) + 1.0) * ((len(_COS_GRID) - 1) / 2.0)
    i = np.minimum(f.astype(np.intp), len(_COS_GRID) - 2)
    w = f - i
    return PEAK_FACTOR[i] * (1.0 - w) + PEAK_FACTOR[i + 1] * w


def peak_curvature(seg_len: np.ndarray | float, cos_turn: np.ndarray | float) -> np.ndarray:
    """Largest curvature (1/m) on the Bézier of a segment of length ``seg_len`` whose direction turns
    by θ (``cos_turn`` = cos θ = d̂_k · d̂_{k+1}) into the next segment; shapes broadcast."""
    c = np.clip(cos_turn, -1.0, 1.0)
    return peak_factor(c) * np.sqrt(1.0 - c * c) / np.maximum(seg_len, _EPS)


def peak_climb(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Largest |flight-path angle| (rad) on the Bézier of a segment with unit direction u followed by v.

    Its tangent runs along w(β) = u + β (v − u), β ∈ [−1/3, 1]. The ratio z/|h| (h the horizontal part)
    has one stationary point β* = (z_u (h_u·d_h) − d_z |h_u|²) / (d_z (h_u·d_h) − z_u |d_h|²) with
    d = v − u, so the peak is at β = −1/3, β = 1 or β* clipped into the range. (..., 3) → (...).
    """
    d = v - u
    ux, uy, uz = u[..., 0], u[..., 1], u[..., 2]
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    hu_dh = ux * dx + uy * dy
    hu2 = ux * ux + uy * uy
    dh2 = dx * dx + dy * dy
    num = uz * hu_dh - dz * hu2
    den = dz * hu_dh - uz * dh2
    beta = np.clip(num / np.where(np.abs(den) > 1e-15, den, np.inf), -1.0 / 3.0, 1.0)
    # |angle| grows with |z| / |h|: compare the ratios squared and take one arctan at the end
    best = np.zeros(u.shape[:-1])
    for bb in (-1.0 / 3.0, 1.0, beta):
        wz = uz + bb * dz
        wx = ux + bb * dx
        wy = uy + bb * dy
        best = np.maximum(best, wz * wz / np.maximum(wx * wx + wy * wy, 1e-300))
    return np.arctan(np.sqrt(best))


def deviation_bound(seg_len: np.ndarray | float, cos_turn: np.ndarray | float) -> np.ndarray:
    """Largest distance of a segment's Bézier from its chord: Q1 lies on the chord and Q2 is offset by
    (r/3) sin θ, so the offset is t²(1−t) r sin θ, at most (4/27) r sin θ (t = 2/3). For turns past 90°
    Q2 also overshoots the chord's end; (4/27) r bounds both. Shapes broadcast → metres."""
    c = np.clip(cos_turn, -1.0, 1.0)
    return (4.0 / 27.0) * seg_len * np.where(c >= 0.0, np.sqrt(1.0 - c * c), 1.0)


def corner_cut_bound(acceptance_radius: float, cos_turn: np.ndarray) -> np.ndarray:
    """How far a vehicle that switches to the next leg at ``acceptance_radius`` before a waypoint strays
    from the two legs meeting there: it flies (about) the chord from A before the corner to A after it,
    whose midpoint is (A/2) sin θ from the nearer leg for a turn θ (A/2 past 90°). Shapes broadcast → m."""
    c = np.clip(cos_turn, -1.0, 1.0)
    return 0.5 * acceptance_radius * np.where(c >= 0.0, np.sqrt(1.0 - c * c), 1.0)


def overshoot_bound(turn_overshoot: float, cos_turn: np.ndarray) -> np.ndarray:
    """How far a path-follower swings past the new leg after a turn θ: ``turn_overshoot`` metres per radian
    (docs/method.md §4.4; 0 for a vehicle that flies the curve). Shapes broadcast → metres."""
    if turn_overshoot <= 0.0:
        return np.zeros_like(np.asarray(cos_turn, dtype=float))
    return turn_overshoot * np.arccos(np.clip(cos_turn, -1.0, 1.0))


def flown_deviation(seg_len: np.ndarray, cos_turn: np.ndarray, acceptance_radius: float,
                    turn_overshoot: float = 0.0) -> np.ndarray:
    """(..., S) metres the flown path may stray from each chord: the Bézier the plan describes, the corner an
    autopilot cuts when it takes a waypoint at its acceptance radius, at either end of the segment, or its swing past
    the segment after the turn at its start (docs/method.md §4.4). ``cos_turn[..., k]`` is the turn at the end of
    segment k; the last axis runs along the route."""
    cut = corner_cut_bound(acceptance_radius, cos_turn)  # at the end of each segment
    after = np.maximum(cut, overshoot_bound(turn_overshoot, cos_turn))  # what the turn does to the next segment
    after_start = np.concatenate([np.zeros_like(after[..., :1]), after[..., :-1]], axis=-1)
    return np.maximum(deviation_bound(seg_len, cos_turn), np.maximum(cut, after_start))


def segment_samples(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split segments into ``counts[k]`` equal steps each: (segment index, parameter t in [0, 1)) per sample."""
    seg = np.repeat(np.arange(len(counts)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    return seg, (np.arange(seg.size) - first) / counts[seg]


def cubic_range(q0: np.ndarray, q1: np.ndarray, q2: np.ndarray, q3: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact min and max over t ∈ [0, 1] of a scalar cubic Bézier with coefficients q0…q3 (arrays).

    Extremes lie at the ends or where the derivative 3[(1−t)² a + 2t(1−t) b + t² c] vanishes.
    """
    a, b, c = q1 - q0, q2 - q1, q3 - q2
    qa = a - 2 * b + c  # derivative/3 = qa t² + qb t + a
    qb = 2 * (b - a)
    disc = qb * qb - 4 * qa * a
    sq = np.sqrt(np.maximum(disc, 0.0))
    lin = np.abs(qa) < 1e-12
    with np.errstate(divide="ignore", invalid="ignore"):
        den = np.where(lin, 1.0, 2 * qa)
        r1 = np.where(lin, -a / np.where(np.abs(qb) > 1e-12, qb, np.inf), (-qb - sq) / den)
        r2 = np.where(lin, r1, (-qb + sq) / den)
    lo, hi = np.minimum(q0, q3), np.maximum(q0, q3)
    for r in (r1, r2):
        ok = (disc >= 0) & (r > 0.0) & (r < 1.0)
        val = bezier_point(q0, q1, q2, q3, np.where(ok, r, 0.0))
        lo = np.where(ok, np.minimum(lo, val), lo)
        hi = np.where(ok, np.maximum(hi, val), hi)
    return lo, hi


def chord_sag(t: np.ndarray) -> float:
    """A bound on how far a cubic Bézier strays from the chords between its samples at parameters ``t``, per metre
    of its largest second difference of control points: (1/8) Δt² max|B''| and |B''| ≤ 6 max |P_{i+2} − 2P_{i+1} + P_i|.
    The cost narrows the band over terrain by this × (1 + the steepest slope) (docs/method.md §5.2)."""
    return 0.75 * float(np.max(np.diff(np.asarray(t, dtype=float)))) ** 2
