"""Fast maths for the kernel's loops over particles: branch-free polynomial arctangent, sine and cosine (within a
rounding or two of libm's, which a loop cannot vectorise), Horner's rule, Bézier points and exact ranges, and the
peak-curvature factor G read from its table."""

from __future__ import annotations

import math

import numpy as np

from planner.kernel.jit import inline, linked


@inline
def horner(c, w):
    """c[0] + c[1]·w + … + c[-1]·w^(n−1), by Horner's rule from the highest coefficient (the polynomials below)."""
    a = c[len(c) - 1]
    for k in range(len(c) - 2, -1, -1):
        a = a * w + c[k]
    return a


# atan(z) = z·A(z²) for |z| ≤ tan(π/8): A interpolates atan(√w)/√w at 12 Chebyshev nodes of [0, tan²(π/8)] (its
# relative error there is 2.2e-16, one rounding; tests/planner/test_kernel.py holds fast_atan2 to math.atan2)
_ATAN = (1.0, -0.3333333333333312, 0.19999999999940893, -0.14285714279250245, 0.11111110744919658,
         -0.09090896809064027, 0.07692045330902225, -0.06662951813629191, 0.05846878297330872, -0.05035102456601552,
         0.03796525745386593, -0.017805397205419446)
_TAN_PI_8 = math.tan(math.pi / 8.0)


@inline
def fast_atan2(y, x):
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
    r = z * horner(_ATAN, w)
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


@inline
def fast_sincos(a):
    """(sin a, cos a) to a rounding or two for |a| up to a few turns, branch-free (see fast_atan2): a = n·π/2 + r,
    |r| ≤ π/4, then the quadrant n mod 4 swaps and signs the two polynomials (in floats: no vector int64)."""
    n = np.floor(a * (2.0 / math.pi) + 0.5)
    r = ((a - n * _PIO2_HI) - n * _PIO2_MID) - n * _PIO2_LO
    w = r * r
    sn = r * horner(_SIN, w)
    cs = horner(_COS, w)
    odd = n - 2.0 * np.floor(0.5 * n)  # 1 in quadrants 1 and 3: sine and cosine swap
    m = np.floor(0.5 * n)
    flip_s = m - 2.0 * np.floor(0.5 * m)  # 1 in quadrants 2 and 3: the sine changes sign
    m = np.floor(0.5 * (n + 1.0))
    flip_c = m - 2.0 * np.floor(0.5 * m)  # 1 in quadrants 1 and 2: the cosine changes sign
    s = cs if odd > 0.5 else sn
    c = sn if odd > 0.5 else cs
    return (-s if flip_s > 0.5 else s), (-c if flip_c > 0.5 else c)


@inline
def bezier(q0, q1, q2, q3, t):
    """One coordinate of a cubic Bézier of control values q0…q3 at t (smoothing.bezier_point)."""
    s = 1.0 - t
    return s**3 * q0 + 3 * s**2 * t * q1 + 3 * s * t**2 * q2 + t**3 * q3


@linked
def cubic_range(q0, q1, q2, q3):
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
            val = bezier(q0, q1, q2, q3, r)
            lo = min(lo, val)
            hi = max(hi, val)
    return lo, hi


@inline
def peak_factor(c, table):
    """G(c) for c = cos θ, interpolated in its table on a uniform grid of [−1, 1] (smoothing.peak_factor)."""
    n = table.shape[0]
    f = (min(max(c, -1.0), 1.0) + 1.0) * ((n - 1) / 2.0)
    i = min(int(f), n - 2)
    w = f - i
    return table[i] * (1.0 - w) + table[i + 1] * w
