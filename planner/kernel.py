"""The cost J of docs/method.md §4–§5 as compiled loops over segment × obstacle × particle (numba).

The numpy implementation in :mod:`planner.problem` is the reference; this kernel computes the same terms,
penalties and violation counts without the numpy temporaries that dominate small swarms (a replan's swarm of
100 × 9 segments spends most of its time in array set-up, not arithmetic). ``FUSEPLAN_KERNEL=numpy`` picks the
reference; without numba installed the reference is used. tests/planner/test_kernel.py holds the two to 1e-9.

Particles are the innermost loop and each such loop writes one array, so the compiler runs it in SIMD lanes;
arctangents, sines and cosines there are branch-free polynomials (:func:`_atan2`, :func:`_sincos`, within a
rounding or two of libm's), because a libm call cannot be vectorised. Each particle still adds its own sums in
the order of one particle at a time, and obstacles skipped by the broad phase or by the swarm's box add exact
zeros, so the settings give the same costs bit for bit (docs/design.md, "Compiled kernels").
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from planner.trajectory.smoothing import PEAK_FACTOR
from planner.world.config import CostWeights, HazardConfig, PenaltyConfig, VehicleLimits
from planner.world.environment import LOITER, PATROL, Environment, Threats
from planner.world.geometry import GOLDEN_ITERS

try:
    from numba import njit
except ImportError:  # pragma: no cover - numba is a dependency; the reference path still works without it
    njit = None

ENV_VAR = "FUSEPLAN_KERNEL"
BROAD_ENV_VAR = "FUSEPLAN_BROAD_PHASE"
GRID_MIN_OBSTACLES = 16  # fewer obstacles: one cell (visiting a few obstacles costs less than finding them)
GRID_CELLS = 64  # broad-phase grid: at most this many cells along the map's longer side
KERNELS = ("compiled", "numpy")
_EPS = 1e-9  # as planner.problem: unit directions
_EPS_CURV = 1e-12  # as planner.trajectory.smoothing: curvature's segment-length floor
_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


def broad_phase() -> bool:
    """Whether the kernels visit only obstacles that can count (the default) or every obstacle
    (``FUSEPLAN_BROAD_PHASE=off``, for benches); the two give the same results bit for bit. The cost skips the
    obstacles out of reach of the swarm's box for each segment; segment_blocked finds obstacles in a uniform grid."""
    want = os.environ.get(BROAD_ENV_VAR, "on").strip().lower() or "on"
    if want not in ("on", "off"):
        raise ValueError(f"{BROAD_ENV_VAR}={want!r}: expected on or off")
    return want == "on"


def chosen() -> str:
    """The kernel evaluations use: ``compiled`` unless FUSEPLAN_KERNEL says ``numpy`` or numba is missing."""
    want = os.environ.get(ENV_VAR, "compiled").strip().lower() or "compiled"
    if want not in KERNELS:
        raise ValueError(f"{ENV_VAR}={want!r}: expected one of {', '.join(KERNELS)}")
    return "compiled" if want == "compiled" and njit is not None else "numpy"


def _jit(fn):  # noqa: ANN001, ANN202
    """Compile with an on-disk cache (no JIT pause after the first run on a machine); identity without numba."""
    return fn if njit is None else njit(cache=True, nogil=True, error_model="numpy")(fn)


def _inline(fn):  # noqa: ANN001, ANN202
    """A helper compiled into its caller (a call passing arrays costs more than the arithmetic inside)."""
    return fn if njit is None else njit(inline="always", error_model="numpy")(fn)


def _linked(fn):  # noqa: ANN001, ANN202
    """A helper left to LLVM to inline where it pays (scalar paths): faster to compile than ``_inline``."""
    return fn if njit is None else njit(error_model="numpy")(fn)


def _called(fn):  # noqa: ANN001, ANN202
    """A helper on a rare or long path, compiled once and called: inlining it into each caller would cost more
    compile time (the first run on a machine) than the call costs at run time."""
    return fn if njit is None else njit(cache=True, nogil=True, error_model="numpy")(fn)


@_inline
def _seg_point(ax, ay, az, bx, by, bz, px, py, pz):  # noqa: ANN001, ANN202
    """Distance from point p to segment a→b (geometry.segment_point_distance)."""
    return math.sqrt(_seg_point_sq(ax, ay, az, bx, by, bz, px, py, pz))


@_inline
def _seg_point_sq(ax, ay, az, bx, by, bz, px, py, pz):  # noqa: ANN001, ANN202
    """Squared distance from point p to segment a→b."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    wx, wy, wz = px - ax, py - ay, pz - az
    dd = dx * dx + dy * dy + dz * dz
    t = (wx * dx + wy * dy + wz * dz) / (dd if dd > 0.0 else 1.0)
    t = min(max(t, 0.0), 1.0)
    ex, ey, ez = wx - t * dx, wy - t * dy, wz - t * dz
    return ex * ex + ey * ey + ez * ez


@_inline
def _seg_point_2d(ax, ay, bx, by, px, py):  # noqa: ANN001, ANN202
    return math.sqrt(_seg_point_2d_sq(ax, ay, bx, by, px, py))


@_inline
def _seg_point_2d_sq(ax, ay, bx, by, px, py):  # noqa: ANN001, ANN202
    """Squared plan-view distance from p to segment a→b (its square root is geometry.segment_point_distance_2d)."""
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    wx, wy = px - ax, py - ay
    t = (wx * dx + wy * dy) / (dd if dd > 0.0 else 1.0)
    t = min(max(t, 0.0), 1.0)
    ex, ey = wx - t * dx, wy - t * dy
    return ex * ex + ey * ey


@_inline
def _cyl_signed(ax, ay, az, dx, dy, dz, t, cx, cy, r, top):  # noqa: ANN001, ANN202
    """Signed distance of a + t·d from a cylinder with a finite top (geometry.cylinder_signed_distance)."""
    px, py, pz = ax + t * dx, ay + t * dy, az + t * dz
    u = math.hypot(px - cx, py - cy) - r
    w = pz - top
    uo, wo = max(u, 0.0), max(w, 0.0)
    return math.sqrt(uo * uo + wo * wo) + min(max(u, w), 0.0)


@_called
def _seg_cyl_finite(ax, ay, az, bx, by, bz, cx, cy, r, top, iters):  # noqa: ANN001, ANN202
    """Golden-section minimum over the segment, step for step as geometry.segment_cylinder_clearance."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    lo, hi = 0.0, 1.0
    x1 = hi - _GOLDEN * (hi - lo)
    x2 = lo + _GOLDEN * (hi - lo)
    f1 = _cyl_signed(ax, ay, az, dx, dy, dz, x1, cx, cy, r, top)
    f2 = _cyl_signed(ax, ay, az, dx, dy, dz, x2, cx, cy, r, top)
    for _ in range(iters):
        if f1 <= f2:
            hi = x2
            xn = hi - _GOLDEN * (hi - lo)
            fn = _cyl_signed(ax, ay, az, dx, dy, dz, xn, cx, cy, r, top)
            x2, x1 = x1, xn
            f2, f1 = f1, fn
        else:
            lo = x1
            xn = lo + _GOLDEN * (hi - lo)
            fn = _cyl_signed(ax, ay, az, dx, dy, dz, xn, cx, cy, r, top)
            x1, x2 = x2, xn
            f1, f2 = f2, fn
    f0 = _cyl_signed(ax, ay, az, dx, dy, dz, 0.0, cx, cy, r, top)
    f_1 = _cyl_signed(ax, ay, az, dx, dy, dz, 1.0, cx, cy, r, top)
    return min(min(f1, f2), min(f0, f_1))


@_inline
def _ground(x, y, has_terrain, tx0, ty0, tdx, tdy, h):  # noqa: ANN001, ANN202
    """Bilinear ground height (terrain.Terrain.height_at); zero on flat terrain."""
    if not has_terrain:
        return 0.0
    ny, nx = h.shape
    fx = min(max((x - tx0) / tdx, 0.0), nx - 1.0)
    fy = min(max((y - ty0) / tdy, 0.0), ny - 1.0)
    i0 = min(int(fx), nx - 2)
    j0 = min(int(fy), ny - 2)
    wx = fx - i0
    wy = fy - j0
    return ((h[j0, i0] * (1 - wx) + h[j0, i0 + 1] * wx) * (1 - wy)
            + (h[j0 + 1, i0] * (1 - wx) + h[j0 + 1, i0 + 1] * wx) * wy)


@_inline
def _bezier(q0, q1, q2, q3, t):  # noqa: ANN001, ANN202
    s = 1.0 - t
    return s**3 * q0 + 3 * s**2 * t * q1 + 3 * s * t**2 * q2 + t**3 * q3


@_linked
def _cubic_range(q0, q1, q2, q3):  # noqa: ANN001, ANN202
    """Exact min and max of a scalar cubic Bézier on [0, 1] (smoothing.cubic_range)."""
    a, b, c = q1 - q0, q2 - q1, q3 - q2
    qa = a - 2 * b + c
    qb = 2 * (b - a)
    disc = qb * qb - 4 * qa * a
    sq = math.sqrt(max(disc, 0.0))
    if abs(qa) < 1e-12:
        r1 = -a / qb if abs(qb) > 1e-12 else 0.0  # numpy divides by inf: ±0, outside (0, 1) either way
        r2 = r1
    else:
        r1 = (-qb - sq) / (2 * qa)
        r2 = (-qb + sq) / (2 * qa)
    lo, hi = min(q0, q3), max(q0, q3)
    for r in (r1, r2):
        if disc >= 0 and 0.0 < r < 1.0:
            val = _bezier(q0, q1, q2, q3, r)
            lo = min(lo, val)
            hi = max(hi, val)
    return lo, hi


@_inline
def _peak_factor(c, table):  # noqa: ANN001, ANN202
    n = table.shape[0]
    f = (min(max(c, -1.0), 1.0) + 1.0) * ((n - 1) / 2.0)
    i = min(int(f), n - 2)
    w = f - i
    return table[i] * (1.0 - w) + table[i + 1] * w


@_inline
def _peak_curvature(seg_len, cos_turn, table):  # noqa: ANN001, ANN202
    c = min(max(cos_turn, -1.0), 1.0)
    return _peak_factor(c, table) * math.sqrt(1.0 - c * c) / max(seg_len, _EPS_CURV)


@_inline
def _sin_or_one(cos_turn):  # noqa: ANN001, ANN202
    """sin θ for turns up to 90°, 1 past it (smoothing.deviation_bound / corner_cut_bound)."""
    c = min(max(cos_turn, -1.0), 1.0)
    return math.sqrt(1.0 - c * c) if c >= 0.0 else 1.0


@_inline
def _after_turn(acc_r, overshoot, cos_turn):  # noqa: ANN001, ANN202
    """What a turn does to the segment after it: the corner's cut or the swing past it, the larger
    (smoothing.corner_cut_bound, overshoot_bound)."""
    cut = 0.5 * acc_r * _sin_or_one(cos_turn)
    if overshoot <= 0.0:
        return cut
    return max(cut, overshoot * math.acos(min(max(cos_turn, -1.0), 1.0)))


@_inline
def _peak_climb(ux, uy, uz, vx, vy, vz):  # noqa: ANN001, ANN202
    """tan² of the largest |flight-path angle| on a segment's Bézier (smoothing.peak_climb)."""
    dx, dy, dz = vx - ux, vy - uy, vz - uz
    hu_dh = ux * dx + uy * dy
    hu2 = ux * ux + uy * uy
    dh2 = dx * dx + dy * dy
    num = uz * hu_dh - dz * hu2
    den = dz * hu_dh - uz * dh2
    beta = num / den if abs(den) > 1e-15 else 0.0
    beta = min(max(beta, -1.0 / 3.0), 1.0)
    best = max(0.0, _tan2_at(ux, uy, uz, dx, dy, dz, -1.0 / 3.0))  # the ends of the range, then the stationary point
    best = max(best, _tan2_at(ux, uy, uz, dx, dy, dz, 1.0))
    return max(best, _tan2_at(ux, uy, uz, dx, dy, dz, beta))  # tan²: the caller takes atan only near the limit


@_inline
def _tan2_at(ux, uy, uz, dx, dy, dz, bb):  # noqa: ANN001, ANN202
    wz = uz + bb * dz
    wx = ux + bb * dx
    wy = uy + bb * dy
    return wz * wz / max(wx * wx + wy * wy, 1e-300)


@_inline
def _near(ax, ay, bx, by, reach, ox, oy, cell, nx, ny, start, items, cx, cy, rad, stamp, token, out):  # noqa: ANN001, ANN202
    """Indices (ascending, into ``out``; returns how many) of the obstacles whose plan-view discs come within
    ``reach`` (per axis) of the segment a→b. Visits the cells under the segment swept by a ±reach square, row by
    row (a diagonal segment's bounding box would be mostly empty cells); ``stamp`` marks obstacles seen for
    ``token``. A disc within reach has a point of its box within reach of the segment, in a cell visited here."""
    if nx == 1 and ny == 1:  # one cell (broad phase off, or few obstacles): every obstacle, in order
        for k in range(start[1]):
            out[k] = items[k]
        return start[1]
    x_lo, x_hi = min(ax, bx) - reach, max(ax, bx) + reach
    y_lo, y_hi = min(ay, by) - reach, max(ay, by) + reach
    j0 = min(max(int(math.floor((y_lo - oy) / cell)), 0), ny - 1)
    j1 = min(max(int(math.floor((y_hi - oy) / cell)), 0), ny - 1)
    dy = by - ay
    n = 0
    for j in range(j0, j1 + 1):
        # the part of the segment whose y is within reach of row j (edge rows reach to infinity, as clamped)
        r_lo = oy + j * cell - reach if j > 0 else -math.inf
        r_hi = oy + (j + 1) * cell + reach if j < ny - 1 else math.inf
        if dy != 0.0:
            t0, t1 = (r_lo - ay) / dy, (r_hi - ay) / dy
            t0, t1 = max(min(t0, t1), 0.0), min(max(t0, t1), 1.0)
            if t0 > t1:
                continue
        else:
            t0, t1 = 0.0, 1.0
        xa, xb = ax + t0 * (bx - ax), ax + t1 * (bx - ax)
        i0 = min(max(int(math.floor((min(xa, xb) - reach - ox) / cell)), 0), nx - 1)
        i1 = min(max(int(math.floor((max(xa, xb) + reach - ox) / cell)), 0), nx - 1)
        for i in range(i0, i1 + 1):
            c = j * nx + i
            for q in range(start[c], start[c + 1]):
                k = items[q]
                if stamp[k] == token:
                    continue
                stamp[k] = token
                r = rad[k]
                if cx[k] + r < x_lo or cx[k] - r > x_hi or cy[k] + r < y_lo or cy[k] - r > y_hi:
                    continue
                m = n  # insertion sort: the obstacles are summed in index order, as without the broad phase
                while m > 0 and out[m - 1] > k:
                    out[m] = out[m - 1]
                    m -= 1
                out[m] = k
                n += 1
    return n


@_inline
def _horner(c, w):  # noqa: ANN001, ANN202
    """c[0] + c[1]·w + … + c[-1]·w^(n−1), by Horner's rule from the highest coefficient (the polynomials below)."""
    a = c[len(c) - 1]
    for k in range(len(c) - 2, -1, -1):
        a = a * w + c[k]
    return a


# atan(z) = z·A(z²) for |z| ≤ tan(π/8): A interpolates atan(√w)/√w at 12 Chebyshev nodes of [0, tan²(π/8)] (its
# relative error there is 2.2e-16, one rounding; tests/planner/test_kernel.py holds _atan2 to math.atan2)
_ATAN = (1.0, -0.3333333333333312, 0.19999999999940893, -0.14285714279250245, 0.11111110744919658,
         -0.09090896809064027, 0.07692045330902225, -0.06662951813629191, 0.05846878297330872, -0.05035102456601552,
         0.03796525745386593, -0.017805397205419446)
_TAN_PI_8 = math.tan(math.pi / 8.0)
_NEAR_LIMIT = 1e-12  # rad: a turn this close to its limit is measured with libm's atan2 (see _cost)


@_inline
def _atan2(y, x):  # noqa: ANN001, ANN202
    """math.atan2 (to a rounding or two) without a libm call and without branches, so that a loop over particles
    runs in SIMD lanes: the ratio of the smaller to the larger coordinate, reduced below tan(π/8) by
    atan t = π/4 + atan((t − 1)/(t + 1)), then the polynomial, then the octant."""
    ax, ay = abs(x), abs(y)
    mx, mn = max(ax, ay), min(ax, ay)
    big = mn > _TAN_PI_8 * mx
    num = mn - mx if big else mn
    den = mn + mx if big else mx
    z = num / (den if den > 0.0 else 1.0)
    w = z * z
    r = z * _horner(_ATAN, w)
    r = r + 0.25 * math.pi if big else r
    r = 0.5 * math.pi - r if ay > ax else r
    r = math.pi - r if x < 0.0 else r
    return -r if y < 0.0 else r


# sin r = r·S(r²) and cos r = C(r²) for |r| ≤ π/4, interpolated at 8 Chebyshev nodes of [0, π²/16] as _ATAN (each
# within 2.2e-16 there); angles come to that range by whole quarter turns, π/2 in three parts (Cody and Waite)
_SIN = (1.0, -0.16666666666666666, 0.008333333333333321, -0.00019841269841253478, 2.7557319213562225e-06,
        -2.5052104779095043e-08, 1.6058352428871255e-10, -7.578090160922686e-13)
_COS = (1.0, -0.5, 0.04166666666666645, -0.0013888888888861095, 2.4801587283881152e-05, -2.7557313097790086e-07,
        2.0875582380663952e-09, -1.1353379638297575e-11)
_PIO2_HI = math.ldexp(round(math.ldexp(math.pi / 2.0, 29)), -29)  # 30 bits: n·_PIO2_HI is exact for small n
_PIO2_MID = math.pi / 2.0 - _PIO2_HI  # exact: the rest of the double nearest π/2
_PIO2_LO = 6.123233995736766e-17  # π/2 minus that double


@_inline
def _sincos(a):  # noqa: ANN001, ANN202
    """(sin a, cos a) to a rounding or two for |a| up to a few turns, branch-free (see _atan2): a = n·π/2 + r,
    |r| ≤ π/4, then the quadrant n mod 4 swaps and signs the two polynomials (in floats: no vector int64)."""
    n = np.floor(a * (2.0 / math.pi) + 0.5)
    r = ((a - n * _PIO2_HI) - n * _PIO2_MID) - n * _PIO2_LO
    w = r * r
    sn = r * _horner(_SIN, w)
    cs = _horner(_COS, w)
    odd = n - 2.0 * np.floor(0.5 * n)  # 1 in quadrants 1 and 3: sine and cosine swap
    m = np.floor(0.5 * n)
    flip_s = m - 2.0 * np.floor(0.5 * m)  # 1 in quadrants 2 and 3: the sine changes sign
    m = np.floor(0.5 * (n + 1.0))
    flip_c = m - 2.0 * np.floor(0.5 * m)  # 1 in quadrants 1 and 2: the cosine changes sign
    s = cs if odd > 0.5 else sn
    c = sn if odd > 0.5 else cs
    return (-s if flip_s > 0.5 else s), (-c if flip_c > 0.5 else c)


@_inline
def _add_violations(excess, s, limit, pen_c, rate, pen, viol, category):  # noqa: ANN001, ANN202
    """Each particle whose ``excess[s] − limit`` is positive adds a violation of that depth: the penalty and the
    count in two loops (a loop writing one array runs in SIMD lanes; adding a zero leaves a sum as it was)."""
    n_p = excess.shape[1]
    for p in range(n_p):
        depth = excess[s, p] - limit
        pen[p] += pen_c + rate * depth if depth > 0.0 else 0.0
    for p in range(n_p):
        viol[category, p] += 1 if excess[s, p] - limit > 0.0 else 0


@_inline
def _box_beyond(x_lo, x_hi, y_lo, y_hi, cx, cy, dist):  # noqa: ANN001, ANN202
    """Whether the point (cx, cy) is farther than ``dist`` from the box."""
    ex = max(max(x_lo - cx, cx - x_hi), 0.0)
    ey = max(max(y_lo - cy, cy - y_hi), 0.0)
    return ex * ex + ey * ey > dist * dist


@_inline
def _roofed_cylinder_term(pt, s, p, cx, cy, r, top, d_safe, dev, gap_cap, pen_c, per_m, iters, soft, pen, viol):  # noqa: ANN001, ANN202
    """Particle p's segment s against one cylinder with a finite ``top``, one particle at a time: J2's soft term
    into ``soft[p]``, a collision into ``pen[p]``/``viol[0, p]``; near the wall, the roof by golden section."""
    ax, ay, az = pt[s, 0, p], pt[s, 1, p], pt[s, 2, p]
    bx, by, bz = pt[s + 1, 0, p], pt[s + 1, 1, p], pt[s + 1, 2, p]
    reach = (d_safe + dev) * (1.0 + 1e-9) + 1e-6
    d2 = _seg_point_2d_sq(ax, ay, bx, by, cx, cy)
    if d2 > (r + reach) * (r + reach):  # beyond reach: an exact zero, no root needed
        return
    c = math.sqrt(d2) - r
    if c < d_safe + dev:
        c = _seg_cyl_finite(ax, ay, az, bx, by, bz, cx, cy, r, top, iters)
    c -= dev
    g = d_safe - c
    depth = g - gap_cap
    if depth > 0.0:
        viol[0, p] += 1
        pen[p] += pen_c + per_m * depth
    g = min(max(g, 0.0), gap_cap)
    soft[p] += g * g


@_called
def _threat_terms(pt, s, p, seg_len, s0, dev, thr, threat_t, start_time, cruise, max_speed, d_safe, gap_cap,
                  pen_c, per_m, soft, pen, viol):  # noqa: ANN001, ANN202
    """Particle p's segment s against every moving threat at the times it flies its samples (§4.6)."""
    ax, ay, az = pt[s, 0, p], pt[s, 1, p], pt[s, 2, p]
    bx, by, bz = pt[s + 1, 0, p], pt[s + 1, 1, p], pt[s + 1, 2, p]
    n_t = threat_t.shape[0]
    gap = seg_len / (n_t - 1)
    margin = dev + 0.5 * gap * (1.0 + max_speed / cruise)
    for m in range(n_t):
        tt = threat_t[m]
        px, py, pz = ax + tt * (bx - ax), ay + tt * (by - ay), az + tt * (bz - az)
        time = start_time + (s0 + tt * seg_len) / cruise
        for k in range(thr.shape[0]):  # centre and radius at this time (Threats.positions, .radii)
            kind, rad, t_ref = thr[k, 0], thr[k, 1], thr[k, 3]
            if kind == LOITER:  # a1 circle radius, a2 angular rate, a3 phase
                ang = thr[k, 9] + thr[k, 8] * time
                cx = thr[k, 4] + thr[k, 7] * math.cos(ang)
                cy = thr[k, 5] + thr[k, 7] * math.sin(ang)
                cz = thr[k, 6]
            elif kind == PATROL:  # a1..a3 unit direction A→B, a4 length, a5 speed
                along = (thr[k, 11] * time) % (2 * thr[k, 10])
                if along > thr[k, 10]:
                    along = 2 * thr[k, 10] - along
                cx = thr[k, 4] + thr[k, 7] * along
                cy = thr[k, 5] + thr[k, 8] * along
                cz = thr[k, 6] + thr[k, 9] * along
            else:  # track: a1..a3 velocity from t_ref; the radius grows with prediction time
                dt = time - t_ref
                cx = thr[k, 4] + thr[k, 7] * dt
                cy = thr[k, 5] + thr[k, 8] * dt
                cz = thr[k, 6] + thr[k, 9] * dt
                rad = rad + thr[k, 2] * max(dt, 0.0)
            ex, ey, ez = px - cx, py - cy, pz - cz
            c = math.sqrt(ex * ex + ey * ey + ez * ez) - rad - margin
            g = d_safe - c
            depth = g - gap_cap
            if depth > 0.0:
                viol[0, p] += 1
                pen[p] += pen_c + per_m * depth
            g = min(max(g, 0.0), gap_cap)
            soft[p] += g * g


@_called
def _terrain_terms(pt, seg, q2, s, p, terrain_t, slope, z_min, z_max, tx0, ty0, tdx, tdy, terrain_h, pen_c, per_m,
                   pen, viol):  # noqa: ANN001, ANN202
    """Particle p's curve on segment s against the band above the terrain, at its samples (§4.7)."""
    q1x = pt[s, 0, p] + seg[s, 0, p] / 3.0
    q1y = pt[s, 1, p] + seg[s, 1, p] / 3.0
    q1z = pt[s, 2, p] + seg[s, 2, p] / 3.0
    ddx, ddy, ddz = q1x - pt[s, 0, p], q1y - pt[s, 1, p], q1z - pt[s, 2, p]
    gap = math.sqrt(ddx * ddx + ddy * ddy + ddz * ddz) * (3.0 / (terrain_t.shape[0] - 1))
    margin = 0.5 * slope * gap
    for m in range(terrain_t.shape[0]):
        tt = terrain_t[m]
        x = _bezier(pt[s, 0, p], q1x, q2[s, 0, p], pt[s + 1, 0, p], tt)
        y = _bezier(pt[s, 1, p], q1y, q2[s, 1, p], pt[s + 1, 1, p], tt)
        z = _bezier(pt[s, 2, p], q1z, q2[s, 2, p], pt[s + 1, 2, p], tt)
        z = z - _ground(x, y, True, tx0, ty0, tdx, tdy, terrain_h)
        depth = max(z_min + margin - z, z - z_max)
        if depth > 0.0:
            viol[1, p] += 1
            pen[p] += pen_c + per_m * depth


@_jit
def _cost(paths, acc_r, overshoot, max_turn, r_min, max_climb, cruise, d_safe, d_coll, pen_c, per_m, per_rad,
          w_length, w_hazard, w_altitude, w_smoothness, w_destination, z_min, z_max, size_x, size_y, direct,
          has_heading, heading, timed, start_time, max_speed, thr, has_terrain, tx0, ty0, tdx, tdy, slope, terrain_h,
          cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, rad_w, peak_table, threat_t, terrain_t,
          golden_iters, broad):  # noqa: ANN001, ANN202
    """terms (P, 5), penalty (P,), violations (P, 5) and the weighted total (P,) for paths (P, N, 3), from the
    fields of :class:`KernelInputs` (see :func:`evaluate`); ``thr`` holds the threats' laws, a row each.

    Particles are the innermost loop (the swarm is transposed to waypoint × axis × particle first), so the common
    passes run in SIMD lanes; each particle's own sums are still added term by term in the order of one particle
    at a time: segment, then obstacle, then category."""
    n_p, n_pts = paths.shape[0], paths.shape[1]
    n_s = n_pts - 1
    pt = np.empty((n_pts, 3, n_p))  # the swarm, particles innermost
    for p in range(n_p):
        for w in range(n_pts):
            for i in range(3):
                pt[w, i, p] = paths[p, w, i]
    seg = np.empty((n_s, 3, n_p))
    u = np.empty((n_s, 3, n_p))
    seg_len = np.empty((n_s, n_p))
    cos_t = np.empty((n_s, n_p))
    dev = np.empty((n_s, n_p))
    q2 = np.empty((n_s, 3, n_p))
    s0 = np.empty((n_s, n_p))
    gam = np.empty((n_s, n_p))
    work = np.empty((n_s, n_p))
    j1 = np.zeros(n_p)
    j3 = np.zeros(n_p)
    j4 = np.zeros(n_p)
    soft_cyl = np.zeros(n_p)
    soft_sph = np.zeros(n_p)
    soft_rad = np.zeros(n_p)
    soft_thr = np.zeros(n_p)
    cum = np.zeros(n_p)
    pen = np.zeros(n_p)
    viol = np.zeros((5, n_p), dtype=np.int64)  # collision, altitude, bounds, turn, climb
    n_cyl = cyl_x.shape[0]
    n_sph = sph_r.shape[0]
    climb_tan2 = math.tan(max_climb) ** 2 * (1.0 - 1e-9) if max_climb < 0.5 * math.pi else math.inf
    peak_max = peak_table.max()
    gap_cap = d_safe - d_coll
    # -- segments, unit directions, turn cosines, the flown curve's deviation (§4.4) -------------------------
    # (each loop over particles writes one array: a loop writing several is left unvectorised by the compiler)
    for s in range(n_s):
        for i in range(3):
            for p in range(n_p):
                seg[s, i, p] = pt[s + 1, i, p] - pt[s, i, p]
        for p in range(n_p):
            seg_len[s, p] = math.sqrt(seg[s, 0, p] * seg[s, 0, p] + seg[s, 1, p] * seg[s, 1, p]
                                      + seg[s, 2, p] * seg[s, 2, p])
        for p in range(n_p):
            j1[p] += seg_len[s, p]
        for i in range(3):
            for p in range(n_p):
                u[s, i, p] = seg[s, i, p] / max(seg_len[s, p], _EPS)
    for s in range(n_s):
        nxt = s + 1 if s + 1 < n_s else n_s - 1  # v: the next direction; the last segment stays straight
        for p in range(n_p):
            cos_t[s, p] = u[s, 0, p] * u[nxt, 0, p] + u[s, 1, p] * u[nxt, 1, p] + u[s, 2, p] * u[nxt, 2, p]
        for p in range(n_p):  # the chord's deviation: the curve's bulge, either corner's cut or the swing past
            so = _sin_or_one(cos_t[s, p])  # it after the turn at its start, the largest
            prev = _after_turn(acc_r, overshoot, cos_t[s - 1, p]) if s > 0 else 0.0
            dev[s, p] = max((4.0 / 27.0) * seg_len[s, p] * so, max(0.5 * acc_r * so, prev))
        for i in range(3):
            for p in range(n_p):
                q2[s, i, p] = pt[s + 1, i, p] - (seg_len[s, p] / 3.0) * u[nxt, i, p]
    if timed:  # the distance flown before each segment, for the threats' times
        for s in range(n_s):
            for p in range(n_p):
                cum[p] += seg_len[s, p]
            for p in range(n_p):
                s0[s, p] = cum[p] - seg_len[s, p]
    if has_heading:
        for p in range(n_p):
            c0 = u[0, 0, p] * heading[0] + u[0, 1, p] * heading[1] + u[0, 2, p] * heading[2]
            dev[0, p] = max(dev[0, p], _after_turn(acc_r, overshoot, c0))
    # -- J2 hazard (§4.3, §4.5, §4.6) -------------------------------------------------------------------------
    box = np.empty((n_pts, 4))  # plan-view box of each waypoint over the swarm: x_lo, x_hi, y_lo, y_hi
    for w in range(n_pts):
        for i in range(2):
            lo, hi = math.inf, -math.inf
            for p in range(n_p):
                lo = min(lo, pt[w, i, p])
                hi = max(hi, pt[w, i, p])
            box[w, 2 * i], box[w, 2 * i + 1] = lo, hi
    for s in range(n_s):
        # the broad phase: an obstacle adds to J2 only within d_safe + dev of a chord (in plan view). A converging
        # swarm's segments s share a small box, and obstacles beyond every particle's reach from it add exact zeros
        # for all of them: they are skipped, and the sums stay bit for bit those without skipping (method.md §4.3)
        reach = math.inf
        if broad:  # FUSEPLAN_BROAD_PHASE
            dev_hi = 0.0
            for p in range(n_p):
                dev_hi = max(dev_hi, dev[s, p])
            reach = (d_safe + dev_hi) * (1.0 + 1e-9) + 1e-6
        x_lo, x_hi = min(box[s, 0], box[s + 1, 0]), max(box[s, 1], box[s + 1, 1])
        y_lo, y_hi = min(box[s, 2], box[s + 1, 2]), max(box[s, 3], box[s + 1, 3])
        for k in range(n_cyl):
            cx, cy, r, top = cyl_x[k], cyl_y[k], cyl_r[k], cyl_top[k]
            if _box_beyond(x_lo, x_hi, y_lo, y_hi, cx, cy, r + reach):
                continue
            if math.isfinite(top):  # a roof: the golden-section clearance near it, one particle at a time
                for p in range(n_p):
                    _roofed_cylinder_term(pt, s, p, cx, cy, r, top, d_safe, dev[s, p], gap_cap, pen_c, per_m,
                                          golden_iters, soft_cyl, pen, viol)
                continue
            for p in range(n_p):  # beyond reach g is clipped to an exact zero: adding it changes no sum
                c = math.sqrt(_seg_point_2d_sq(pt[s, 0, p], pt[s, 1, p], pt[s + 1, 0, p], pt[s + 1, 1, p], cx,
                                               cy)) - r - dev[s, p]
                g = d_safe - c
                depth = g - gap_cap
                hit = depth > 0.0
                viol[0, p] += 1 if hit else 0
                pen[p] += pen_c + per_m * depth if hit else 0.0
                g = min(max(g, 0.0), gap_cap)
                soft_cyl[p] += g * g
        for k in range(n_sph):
            cx, cy, cz, r = sph_c[k, 0], sph_c[k, 1], sph_c[k, 2], sph_r[k]
            if _box_beyond(x_lo, x_hi, y_lo, y_hi, cx, cy, r + reach):  # plan view: nearer than in 3-D
                continue
            for p in range(n_p):
                c = math.sqrt(_seg_point_sq(pt[s, 0, p], pt[s, 1, p], pt[s, 2, p], pt[s + 1, 0, p],
                                            pt[s + 1, 1, p], pt[s + 1, 2, p], cx, cy, cz)) - r - dev[s, p]
                g = d_safe - c
                depth = g - gap_cap
                hit = depth > 0.0
                viol[0, p] += 1 if hit else 0
                pen[p] += pen_c + per_m * depth if hit else 0.0
                g = min(max(g, 0.0), gap_cap)
                soft_sph[p] += g * g
        for k in range(rad_det.shape[0]):
            cx, cy, cz, det, wt = rad_c[k, 0], rad_c[k, 1], rad_c[k, 2], rad_det[k], rad_w[k]
            for p in range(n_p):
                d = math.sqrt(_seg_point_sq(pt[s, 0, p], pt[s, 1, p], pt[s, 2, p], pt[s + 1, 0, p], pt[s + 1, 1, p],
                                            pt[s + 1, 2, p], cx, cy, cz))
                depth = det - (d - dev[s, p])
                hit = depth > 0.0
                viol[0, p] += 1 if hit else 0
                pen[p] += pen_c + per_m * depth if hit else 0.0
                soft_rad[p] += wt * (det / max(d, det)) ** 4
        if timed:
            for p in range(n_p):
                _threat_terms(pt, s, p, seg_len[s, p], s0[s, p], dev[s, p], thr, threat_t, start_time, cruise,
                              max_speed, d_safe, gap_cap, pen_c, per_m, soft_thr, pen, viol)
    # -- J3 altitude: mid-band distance of interior waypoints; band violations of the curve (§4.7) -----------
    mid, half = 0.5 * (z_min + z_max), 0.5 * (z_max - z_min)
    for w in range(1, n_pts - 1):
        if has_terrain:
            for p in range(n_p):
                h = pt[w, 2, p] - _ground(pt[w, 0, p], pt[w, 1, p], has_terrain, tx0, ty0, tdx, tdy, terrain_h)
                j3[p] += abs(h - mid) / half
        else:
            for p in range(n_p):
                j3[p] += abs(pt[w, 2, p] - mid) / half
    if has_terrain:
        for s in range(n_s):
            for p in range(n_p):
                _terrain_terms(pt, seg, q2, s, p, terrain_t, slope, z_min, z_max, tx0, ty0, tdx, tdy, terrain_h,
                               pen_c, per_m, pen, viol)
    else:  # the curve lies in its control points' range: only where that leaves the band is the exact range needed
        for s in range(n_s):
            for p in range(n_p):
                z0, z3 = pt[s, 2, p], pt[s + 1, 2, p]
                z1, z2 = z0 + seg[s, 2, p] / 3.0, q2[s, 2, p]
                lo = min(min(z0, z3), min(z1, z2))
                hi = max(max(z0, z3), max(z1, z2))
                work[s, p] = 1.0 if (lo < z_min) | (hi > z_max) else 0.0
        for s in range(n_s):
            for p in range(n_p):
                if work[s, p] == 0.0:
                    continue
                z0, z3 = pt[s, 2, p], pt[s + 1, 2, p]
                lo, hi = _cubic_range(z0, z0 + seg[s, 2, p] / 3.0, q2[s, 2, p], z3)
                depth = max(z_min - lo, hi - z_max)
                if depth > 0.0:
                    viol[1, p] += 1
                    pen[p] += pen_c + per_m * depth
    # -- bounds: the curve lies in the hull of a, Q1 (on the chord), Q2 and b ----------------------------------
    for s in range(n_s):
        for p in range(n_p):
            lo_x = min(min(pt[s, 0, p], pt[s + 1, 0, p]), q2[s, 0, p])
            lo_y = min(min(pt[s, 1, p], pt[s + 1, 1, p]), q2[s, 1, p])
            hi_x = max(max(pt[s, 0, p], pt[s + 1, 0, p]), q2[s, 0, p])
            hi_y = max(max(pt[s, 1, p], pt[s + 1, 1, p]), q2[s, 1, p])
            work[s, p] = max(max(-lo_x, hi_x - size_x), max(-lo_y, hi_y - size_y))
        _add_violations(work, s, 0.0, pen_c, per_m, pen, viol, 2)
    # -- J4 smoothness: turns and climb changes; turn, curvature and climb limits (§4.4, §11) ----------------
    for s in range(n_s):
        for p in range(n_p):
            x, y = seg[s, 0, p], seg[s, 1, p]
            gam[s, p] = _atan2(seg[s, 2, p], math.sqrt(x * x + y * y))
    for s in range(n_s - 1):
        for p in range(n_p):
            x0, y0 = seg[s, 0, p], seg[s, 1, p]
            x1, y1 = seg[s + 1, 0, p], seg[s + 1, 1, p]
            work[s, p] = abs(_atan2(x0 * y1 - y0 * x1, x0 * x1 + y0 * y1))
    for s in range(n_s - 1):  # at the limit itself, libm's rounding decides, as in the reference
        for p in range(n_p):
            if abs(work[s, p] - max_turn) < _NEAR_LIMIT:
                x0, y0 = seg[s, 0, p], seg[s, 1, p]
                x1, y1 = seg[s + 1, 0, p], seg[s + 1, 1, p]
                work[s, p] = abs(math.atan2(x0 * y1 - y0 * x1, x0 * x1 + y0 * y1))
    for s in range(n_s - 1):
        for p in range(n_p):
            over = max(work[s, p] - max_turn, 0.0)
            j4[p] += work[s, p] + abs(gam[s + 1, p] - gam[s, p]) + over**2
        _add_violations(work, s, max_turn, pen_c, per_rad, pen, viol, 3)
    for s in range(n_s):  # with G at its largest (rounding is monotone): where even that is within the limit, so is G
        for p in range(n_p):
            c = min(max(cos_t[s, p], -1.0), 1.0)
            work[s, p] = peak_max * math.sqrt(1.0 - c * c) / max(seg_len[s, p], _EPS_CURV) * r_min - 1.0
    for s in range(n_s):
        for p in range(n_p):
            if work[s, p] <= 0.0:
                continue
            depth = _peak_curvature(seg_len[s, p], cos_t[s, p], peak_table) * r_min - 1.0
            if depth > 0.0:
                viol[3, p] += 1
                pen[p] += pen_c + per_rad * depth
    for s in range(n_s):
        nxt = s + 1 if s + 1 < n_s else n_s - 1
        for p in range(n_p):
            work[s, p] = _peak_climb(u[s, 0, p], u[s, 1, p], u[s, 2, p], u[nxt, 0, p], u[nxt, 1, p], u[nxt, 2, p])
    for s in range(n_s):
        for p in range(n_p):
            tan2 = work[s, p]  # tan² of the peak climb (the buffer is free again)
            if tan2 < climb_tan2:  # well inside the limit (atan is monotone): skip the arctangent
                continue
            depth = math.atan(math.sqrt(tan2)) - max_climb  # libm's, as the reference: particles sit on this bound
            if depth > 0.0:
                viol[4, p] += 1
                pen[p] += pen_c + per_rad * depth
    if has_heading:
        hx, hy = heading[0], heading[1]
        for p in range(n_p):
            turn0 = abs(math.atan2(hx * seg[0, 1, p] - hy * seg[0, 0, p], hx * seg[0, 0, p] + hy * seg[0, 1, p]))
            over0 = max(turn0 - max_turn, 0.0)
            j4[p] += turn0 + over0**2
            if over0 > 0.0:
                viol[3, p] += 1
                pen[p] += pen_c + per_rad * over0
            c0 = u[0, 0, p] * heading[0] + u[0, 1, p] * heading[1] + u[0, 2, p] * heading[2]
            depth = _peak_curvature(seg_len[0, p], c0, peak_table) * r_min - 1.0
            if depth > 0.0:
                viol[3, p] += 1
                pen[p] += pen_c + per_rad * depth
    terms = np.empty((n_p, 5))
    violations = np.empty((n_p, 5), dtype=np.int64)
    total = np.empty(n_p)
    inv_direct = max(direct, _EPS)
    for p in range(n_p):
        terms[p, 0] = j1[p]
        terms[p, 1] = soft_cyl[p] / d_safe + soft_sph[p] / d_safe + soft_rad[p] + soft_thr[p] / d_safe
        terms[p, 2] = j3[p]
        terms[p, 3] = j4[p]
        terms[p, 4] = seg_len[n_s - 1, p] / inv_direct
        for i in range(5):
            violations[p, i] = viol[i, p]
        total[p] = (pen[p] + w_length * terms[p, 0] + w_hazard * terms[p, 1] + w_altitude * terms[p, 2]
                    + w_smoothness * terms[p, 3] + w_destination * terms[p, 4])  # the reference's order
    return terms, pen, violations, total


def _threat_rows(thr: Threats) -> np.ndarray:
    """Threats (K, 12): kind, radius, radius growth, t_ref, p0, then per kind the law's constants, computed as
    Threats.positions computes them (so the kernel's centres match the reference's to the last bit)."""
    rows = np.zeros((len(thr), 12))
    rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = thr.kind, thr.radius, thr.radius_growth, thr.t_ref
    rows[:, 4:7] = thr.p0
    for k in range(len(thr)):  # a handful of threats, once per problem
        if thr.kind[k] == LOITER:
            r = thr.circle_radius[k]
            rows[k, 7:10] = r, thr.direction[k] * thr.speed[k] / (r if r > 0 else 1.0), thr.phase[k]
        elif thr.kind[k] == PATROL:
            ab = thr.p1[k] - thr.p0[k]
            length = float(np.linalg.norm(ab))
            safe = length if length > 0 else 1.0
            rows[k, 7:12] = *(ab / safe), safe, thr.speed[k]
        else:
            rows[k, 7:10] = thr.p1[k]
    return rows


def _f64(a, shape: tuple[int, ...] = (-1,)) -> np.ndarray:  # noqa: ANN001
    """A contiguous, writeable float64 copy: one compiled signature for every problem."""
    return np.array(a, dtype=np.float64, order="C").reshape(shape)


@dataclass(frozen=True, eq=False)
class ObstacleGrid:
    """The broad phase's uniform grid over the map (cells of ``cell`` metres from x0, y0) and, per cell, the
    obstacles (cylinders, then spheres) whose plan-view discs reach it; one cell holding everything when off."""

    x0: float
    y0: float
    cell: float
    nx: int
    ny: int
    start: np.ndarray  # (nx·ny + 1,) int64: cell c holds items[start[c]:start[c + 1]], ascending
    items: np.ndarray  # int64 indices into KernelInputs.ob_x, ob_y, ob_r

    @classmethod
    def over(cls, size_x: float, size_y: float, x: np.ndarray, y: np.ndarray, r: np.ndarray,
             on: bool) -> ObstacleGrid:
        """The grid for obstacles of plan-view centres x, y and radii r on a size_x × size_y map. About one
        obstacle per cell (cells of √(area / obstacles)), at most GRID_CELLS along the longer side: finer cells
        cost more cell visits per segment than the distances they save. Off-map parts go to the edge cells, as
        the query clamps too."""
        if not on or len(x) < GRID_MIN_OBSTACLES:
            ox, oy, cell, nx, ny = 0.0, 0.0, 1e300, 1, 1
        else:
            ox, oy = 0.0, 0.0
            cell = max(max(size_x, size_y, 1.0) / GRID_CELLS, math.sqrt(max(size_x * size_y, 1.0) / len(x)))
            nx, ny = max(math.ceil(size_x / cell), 1), max(math.ceil(size_y / cell), 1)
        lists: list[list[int]] = [[] for _ in range(nx * ny)]
        for k in range(len(x)):  # once per problem, over the obstacles
            i0, i1 = (min(max(int(math.floor((v - ox) / cell)), 0), nx - 1) for v in (x[k] - r[k], x[k] + r[k]))
            j0, j1 = (min(max(int(math.floor((v - oy) / cell)), 0), ny - 1) for v in (y[k] - r[k], y[k] + r[k]))
            for j in range(j0, j1 + 1):
                for i in range(i0, i1 + 1):
                    lists[j * nx + i].append(k)
        start = np.zeros(nx * ny + 1, dtype=np.int64)
        start[1:] = np.cumsum([len(c) for c in lists])
        items = np.array([k for c in lists for k in c], dtype=np.int64)
        return cls(ox, oy, float(cell), int(nx), int(ny), start, items)


@dataclass(frozen=True, eq=False)
class KernelInputs:
    """Everything the compiled kernel reads of one problem, by name, made once per problem
    (:attr:`planner.problem.PlanningProblem.kernel_inputs`): arrays contiguous and writeable, so that every
    problem runs the same compiled code, and the sample parameters and tables the reference uses."""

    # the vehicle (VehicleLimits)
    acceptance_radius: float
    turn_overshoot: float  # m per radian of turn
    max_turn: float
    min_turn_radius: float
    max_climb: float
    cruise_speed: float
    # clearances and the penalty (HazardConfig, PenaltyConfig)
    d_safe: float
    d_coll: float
    penalty_constant: float
    penalty_per_metre: float
    penalty_per_radian: float
    # b1…b5 (CostWeights): the total adds them in this order, as the reference does
    weight_length: float
    weight_hazard: float
    weight_altitude: float
    weight_smoothness: float
    weight_destination: float
    # the map and the route
    z_min: float
    z_max: float
    size_x: float
    size_y: float
    direct_distance: float
    has_heading: bool
    heading: np.ndarray  # (3,) the start heading; zeros without one
    # moving threats, met in time only when timed (PlanningProblem.timed_threats)
    timed: bool
    start_time: float  # s; 0 when not timed
    threat_max_speed: float
    threats: np.ndarray  # (K, 12): see _threat_rows
    # terrain (terrain.Terrain); a flat ground without
    has_terrain: bool
    terrain_x0: float
    terrain_y0: float
    terrain_dx: float
    terrain_dy: float
    terrain_slope: float  # Terrain.max_slope
    terrain_heights: np.ndarray  # (ny, nx); zeros (2, 2) without terrain
    # static obstacles
    cyl_x: np.ndarray
    cyl_y: np.ndarray
    cyl_r: np.ndarray
    cyl_top: np.ndarray
    sph_c: np.ndarray  # (K, 3)
    sph_r: np.ndarray
    rad_c: np.ndarray  # (K, 3)
    rad_det: np.ndarray
    rad_w: np.ndarray
    # the broad phase: cylinders then spheres in plan view, and their grids (FUSEPLAN_BROAD_PHASE on, off)
    ob_x: np.ndarray
    ob_y: np.ndarray
    ob_r: np.ndarray
    grid: ObstacleGrid
    one_cell: ObstacleGrid
    # what the reference samples and tabulates, shared so that the two compute the same thing
    peak_factor: np.ndarray  # smoothing.PEAK_FACTOR: G(cos θ)
    threat_t: np.ndarray  # sample parameters per segment for the moving threats
    terrain_t: np.ndarray  # and for the terrain
    golden_iters: int  # geometry.GOLDEN_ITERS

    @classmethod
    def build(cls, env: Environment, vehicle: VehicleLimits, hazard: HazardConfig, penalty: PenaltyConfig,
              weights: CostWeights, direct_distance: float, start_time: float | None,
              start_heading: np.ndarray | None, threat_t: np.ndarray, terrain_t: np.ndarray) -> KernelInputs:
        """The inputs of a problem; ``start_time`` None when moving threats do not count (none, or no time)."""
        ter, cyl, sph, rad = env.terrain, env.cylinders, env.spheres, env.radars
        ob_x = _f64(np.concatenate([cyl.x, sph.center[:, 0]]))  # cylinders then spheres: one grid for both
        ob_y = _f64(np.concatenate([cyl.y, sph.center[:, 1]]))
        ob_r = _f64(np.concatenate([cyl.radius, sph.radius]))
        return cls(
            acceptance_radius=float(vehicle.acceptance_radius), turn_overshoot=float(vehicle.turn_overshoot),
            max_turn=float(vehicle.max_turn), min_turn_radius=float(vehicle.min_turn_radius),
            max_climb=float(vehicle.max_climb), cruise_speed=float(vehicle.cruise_speed),
            d_safe=float(hazard.d_safe), d_coll=float(hazard.d_coll), penalty_constant=float(penalty.constant),
            penalty_per_metre=float(penalty.per_metre), penalty_per_radian=float(penalty.per_radian),
            weight_length=float(weights.length), weight_hazard=float(weights.hazard),
            weight_altitude=float(weights.altitude), weight_smoothness=float(weights.smoothness),
            weight_destination=float(weights.destination),
            z_min=float(env.z_min), z_max=float(env.z_max), size_x=float(env.size_x), size_y=float(env.size_y),
            direct_distance=float(direct_distance),
            has_heading=start_heading is not None,
            heading=_f64(start_heading if start_heading is not None else np.zeros(3)),
            timed=start_time is not None, start_time=float(start_time) if start_time is not None else 0.0,
            threat_max_speed=float(env.threats.max_speed), threats=_threat_rows(env.threats),
            has_terrain=ter is not None,
            terrain_x0=float(ter.x0) if ter is not None else 0.0, terrain_y0=float(ter.y0) if ter is not None else 0.0,
            terrain_dx=float(ter.dx) if ter is not None else 1.0, terrain_dy=float(ter.dy) if ter is not None else 1.0,
            terrain_slope=float(ter.max_slope) if ter is not None else 0.0,
            terrain_heights=_f64(ter.heights, ter.heights.shape) if ter is not None else np.zeros((2, 2)),
            cyl_x=_f64(cyl.x), cyl_y=_f64(cyl.y), cyl_r=_f64(cyl.radius), cyl_top=_f64(cyl.top),
            sph_c=_f64(sph.center, (-1, 3)), sph_r=_f64(sph.radius),
            rad_c=_f64(rad.center, (-1, 3)), rad_det=_f64(rad.r_det), rad_w=_f64(rad.soft_weight),
            ob_x=ob_x, ob_y=ob_y, ob_r=ob_r,
            grid=ObstacleGrid.over(env.size_x, env.size_y, ob_x, ob_y, ob_r, True),
            one_cell=ObstacleGrid.over(env.size_x, env.size_y, ob_x, ob_y, ob_r, False),
            peak_factor=_f64(PEAK_FACTOR), threat_t=_f64(threat_t), terrain_t=_f64(terrain_t),
            golden_iters=int(GOLDEN_ITERS),
        )


def evaluate(inputs: KernelInputs, paths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unweighted terms (P, 5) J1…J5, penalty (P,), violation counts (P, 5) in CATEGORIES order and the weighted
    total (P,) for paths (P, N, 3) metres, from the compiled kernel."""
    paths = np.asarray(paths, dtype=np.float64)
    if not (paths.flags.c_contiguous and paths.flags.writeable):  # one signature: C-ordered and writeable
        paths = np.array(paths, dtype=np.float64, order="C")
    k = inputs
    return _cost(paths, k.acceptance_radius, k.turn_overshoot, k.max_turn, k.min_turn_radius, k.max_climb,
                 k.cruise_speed, k.d_safe, k.d_coll, k.penalty_constant, k.penalty_per_metre, k.penalty_per_radian,
                 k.weight_length, k.weight_hazard, k.weight_altitude, k.weight_smoothness, k.weight_destination,
                 k.z_min, k.z_max, k.size_x, k.size_y, k.direct_distance, k.has_heading, k.heading, k.timed,
                 k.start_time, k.threat_max_speed, k.threats, k.has_terrain, k.terrain_x0, k.terrain_y0,
                 k.terrain_dx, k.terrain_dy, k.terrain_slope, k.terrain_heights, k.cyl_x, k.cyl_y, k.cyl_r, k.cyl_top,
                 k.sph_c, k.sph_r, k.rad_c, k.rad_det, k.rad_w, k.peak_factor, k.threat_t, k.terrain_t,
                 k.golden_iters, broad_phase())


# -- the swarm's own per-iteration work: decoding spherical particles and the PSO update -------------------------
@_jit
def _decode_spherical(x, start, goal):  # noqa: ANN001, ANN202
    """Paths (P, n + 2, 3) from spherical particles (P, n, 3), as geometry.spherical_to_cartesian + start/goal:
    the steps summed in order from the start (the reference's cumsum, then start + sum). Sines and cosines are
    _sincos's, particles innermost so that they run in SIMD lanes."""
    n_p, n = x.shape[0], x.shape[1]
    xt = np.empty((3, n, n_p))
    for p in range(n_p):
        for k in range(n):
            for i in range(3):
                xt[i, k, p] = x[p, k, i]
    step = np.empty((3, n, n_p))
    for k in range(n):
        for p in range(n_p):
            r = xt[0, k, p]
            s_psi, c_psi = _sincos(xt[1, k, p])
            s_phi, c_phi = _sincos(xt[2, k, p])
            step[0, k, p] = r * c_psi * c_phi
            step[1, k, p] = r * c_psi * s_phi
            step[2, k, p] = r * s_psi
    out = np.empty((n_p, n + 2, 3))
    for p in range(n_p):
        for i in range(3):
            out[p, 0, i] = start[i]
            out[p, n + 1, i] = goal[i]
            acc = 0.0
            for k in range(n):
                acc += step[i, k, p]
                out[p, k + 1, i] = start[i] + acc
    return out


def decode_spherical(x: np.ndarray, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Compiled :meth:`planner.search.encoding.Encoding.decode` for the spherical encoding (docs/method.md §3.1)."""
    return _decode_spherical(np.ascontiguousarray(x, dtype=np.float64), np.asarray(start, dtype=np.float64),
                             np.asarray(goal, dtype=np.float64))


@_jit
def _pso_step(x, v, pbest, gbest, w, c1, c2, lo, hi, vmax, reflection, r1, r2):  # noqa: ANN001, ANN202
    """planner.search.spso.pso_step element by element, the same operations in the same order (so bit for bit), on
    flattened particles (P, m) and bounds (m,); branch-free, so each particle's coordinates run in SIMD lanes."""
    n_p, m = x.shape
    x_new = np.empty_like(x)
    v_new = np.empty_like(v)
    for p in range(n_p):
        wp = w[p]
        for j in range(m):
            xi = x[p, j]
            vi = wp * v[p, j] + c1 * r1[p, j] * (pbest[p, j] - xi) + c2 * r2[p, j] * (gbest[j] - xi)
            vi = min(max(vi, -vmax[j]), vmax[j])
            xi = xi + vi
            out = (xi < lo[j]) | (xi > hi[j])
            x_new[p, j] = min(max(xi, lo[j]), hi[j])  # inside the box: xi itself
            v_new[p, j] = -vi if reflection and out else vi
    return x_new, v_new


def pso_step(x: np.ndarray, v: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, w: float | np.ndarray, c1: float,
             c2: float, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray, reflection: bool, r1: np.ndarray,
             r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled :func:`planner.search.spso.pso_step` for swarms (P, n, 3); ``w`` a scalar or (P, 1, 1)."""
    n_p = len(x)

    def flat(a: np.ndarray) -> np.ndarray:
        return np.ascontiguousarray(a, dtype=np.float64).reshape(n_p, -1)

    def box(a: np.ndarray | float) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        if a.shape != lo.shape:
            a = np.broadcast_to(a, lo.shape)
        return np.ascontiguousarray(a).reshape(-1)

    ww = np.full(n_p, w, dtype=np.float64) if np.ndim(w) == 0 else flat(w).reshape(-1)
    xn, vn = _pso_step(flat(x), flat(v), flat(pbest), box(gbest), ww, float(c1), float(c2), box(lo), box(hi),
                       box(vmax), bool(reflection), flat(r1), flat(r2))
    return xn.reshape(x.shape), vn.reshape(x.shape)


# -- which lattice edges are hopeless (the ant colonies' segment_blocked) ------------------------------------------
@_jit
def _blocked(a, b, d_coll, cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, golden_iters, gox, goy, gcell,
             gnx, gny, ob_start, ob_items, ob_x, ob_y, ob_r):  # noqa: ANN001, ANN202
    """For segments a→b (E, 3): within d_coll of a cylinder or sphere, or inside a radar's range (as
    PlanningProblem.segment_blocked), visiting only the obstacles the broad phase finds within d_coll."""
    n_e = a.shape[0]
    out = np.zeros(n_e, dtype=np.bool_)
    n_cyl = cyl_x.shape[0]
    near = np.empty(ob_x.shape[0], dtype=np.int64)
    stamp = np.full(ob_x.shape[0], -1, dtype=np.int64)
    reach = d_coll * (1.0 + 1e-9) + 1e-6
    for e in range(n_e):
        ax, ay, az, bx, by, bz = a[e, 0], a[e, 1], a[e, 2], b[e, 0], b[e, 1], b[e, 2]
        hit = False
        n_near = _near(ax, ay, bx, by, reach, gox, goy, gcell, gnx, gny, ob_start, ob_items, ob_x, ob_y, ob_r, stamp,
                       e, near)
        for q in range(n_near):
            k = near[q]
            if k >= n_cyl:
                break
            c = _seg_point_2d(ax, ay, bx, by, cyl_x[k], cyl_y[k]) - cyl_r[k]
            if math.isfinite(cyl_top[k]) and c < d_coll:
                c = _seg_cyl_finite(ax, ay, az, bx, by, bz, cyl_x[k], cyl_y[k], cyl_r[k], cyl_top[k], golden_iters)
            if c < d_coll:
                hit = True
                break
        if not hit:
            for q in range(n_near):
                k = near[q] - n_cyl
                if k < 0:
                    continue
                if _seg_point(ax, ay, az, bx, by, bz, sph_c[k, 0], sph_c[k, 1], sph_c[k, 2]) - sph_r[k] < d_coll:
                    hit = True
                    break
        if not hit:
            for k in range(rad_det.shape[0]):
                if _seg_point(ax, ay, az, bx, by, bz, rad_c[k, 0], rad_c[k, 1], rad_c[k, 2]) < rad_det[k]:
                    hit = True
                    break
        out[e] = hit
    return out


def segment_blocked(inputs: KernelInputs, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Compiled :meth:`planner.problem.PlanningProblem.segment_blocked` for segments a→b (..., 3)."""
    k = inputs
    g = k.grid if broad_phase() else k.one_cell
    shape = np.broadcast_shapes(np.shape(a), np.shape(b))
    flat_a = np.ascontiguousarray(np.broadcast_to(a, shape), dtype=np.float64).reshape(-1, 3)
    flat_b = np.ascontiguousarray(np.broadcast_to(b, shape), dtype=np.float64).reshape(-1, 3)
    got = _blocked(flat_a, flat_b, k.d_coll, k.cyl_x, k.cyl_y, k.cyl_r, k.cyl_top, k.sph_c, k.sph_r, k.rad_c,
                   k.rad_det, k.golden_iters, g.x0, g.y0, g.cell, g.nx, g.ny, g.start, g.items, k.ob_x, k.ob_y,
                   k.ob_r)
    return got.reshape(shape[:-1])


def warm_up(problem) -> None:  # noqa: ANN001
    """Compile (first run on a machine) or load from the disk cache every compiled function, on ``problem``'s
    arrays: the replan worker calls it before the flight so that no replan pays for it."""
    if chosen() != "compiled":
        return
    line = np.linspace(problem.start, problem.goal, 4)[None]
    problem.evaluate(line)  # through the problem, which holds the sample parameters
    problem.segment_blocked(line[:, :-1], line[:, 1:])
    x = np.zeros((1, 2, 3))
    decode_spherical(x, problem.start, problem.goal)
    box = np.ones((2, 3))
    pso_step(x, x, x, x[0], 0.5, 1.0, 1.0, -box, box, box, True, x, x)
