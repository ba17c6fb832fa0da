"""The cost J of docs/method.md §4–§5 as one compiled loop over particle × segment × obstacle (numba).

The numpy implementation in :mod:`planner.problem` is the reference; this kernel computes the same terms,
penalties and violation counts without the numpy temporaries that dominate small swarms (a replan's swarm of
100 × 9 segments spends most of its time in array set-up, not arithmetic). ``FUSEPLAN_KERNEL=numpy`` picks the
reference; without numba installed the reference is used. tests/planner/test_kernel.py holds the two to 1e-9.
"""

from __future__ import annotations

import math
import os

import numpy as np

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
_LOITER, _PATROL, _TRACK = 0, 1, 2  # planner.world.environment's threat kinds


def broad_phase() -> bool:
    """Whether the kernel visits only obstacles near each segment (a uniform grid, the default) or every obstacle
    (``FUSEPLAN_BROAD_PHASE=off``, for benches); the two give the same costs bit for bit."""
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


@_inline
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


@_inline
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
    best = 0.0
    for bb in (-1.0 / 3.0, 1.0, beta):
        wz = uz + bb * dz
        wx = ux + bb * dx
        wy = uy + bb * dy
        best = max(best, wz * wz / max(wx * wx + wy * wy, 1e-300))
    return best  # tan² of the angle: the caller takes atan only when it may exceed the limit


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


@_jit
def _cost(paths, sc, heading, cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, rad_w,
          terrain_h, thr, peak_table, threat_t, terrain_t, golden_iters, grid, ob_x, ob_y, ob_r, ob_start,
          ob_items):  # noqa: ANN001, ANN202
    """terms (P, 5), penalty (P,), violations (P, 5) for paths (P, N, 3); ``sc`` holds the scalars and ``thr`` the
    threats' laws, a row each (see _arrays)."""
    (acc_r, d_safe, d_coll, pen_c, per_m, per_rad, max_turn, r_min, max_climb, z_min, z_max, size_x, size_y,
     direct, cruise, start_time, timed, max_speed, has_heading, has_terrain, tx0, ty0, tdx, tdy, slope) = (
        sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6], sc[7], sc[8], sc[9], sc[10], sc[11], sc[12], sc[13], sc[14],
        sc[15], sc[16] > 0, sc[17], sc[18] > 0, sc[19] > 0, sc[20], sc[21], sc[22], sc[23], sc[24])
    n_p, n_pts = paths.shape[0], paths.shape[1]
    n_s = n_pts - 1
    terms = np.zeros((n_p, 5))
    pen = np.zeros(n_p)
    viol = np.zeros((n_p, 5), dtype=np.int64)  # collision, altitude, bounds, turn, climb
    seg = np.empty((n_s, 3))
    u = np.empty((n_s, 3))
    v = np.empty((n_s, 3))
    seg_len = np.empty(n_s)
    cos_t = np.empty(n_s)
    dev = np.empty(n_s)
    q2 = np.empty((n_s, 3))
    s0 = np.empty(n_s)
    gam = np.empty(n_s)
    n_cyl = cyl_x.shape[0]
    near = np.empty(ob_x.shape[0], dtype=np.int64)
    stamp = np.full(ob_x.shape[0], -1, dtype=np.int64)
    gox, goy, gcell, gnx, gny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
    climb_tan2 = math.tan(max_climb) ** 2 * (1.0 - 1e-9) if max_climb < 0.5 * math.pi else math.inf
    gap_cap = d_safe - d_coll
    n_thr_t = threat_t.shape[0]
    n_ter_t = terrain_t.shape[0]
    for p in range(n_p):
        pp = paths[p]
        penalty = 0.0
        # -- segments, unit directions, turn cosines, the flown curve's deviation (§4.4) ---------------
        j1 = 0.0
        for s in range(n_s):
            for i in range(3):
                seg[s, i] = pp[s + 1, i] - pp[s, i]
            seg_len[s] = math.sqrt(seg[s, 0] * seg[s, 0] + seg[s, 1] * seg[s, 1] + seg[s, 2] * seg[s, 2])
            j1 += seg_len[s]
            inv = max(seg_len[s], _EPS)
            for i in range(3):
                u[s, i] = seg[s, i] / inv
        cum = 0.0
        for s in range(n_s):
            nxt = s + 1 if s + 1 < n_s else n_s - 1
            for i in range(3):
                v[s, i] = u[nxt, i]
            cos_t[s] = u[s, 0] * v[s, 0] + u[s, 1] * v[s, 1] + u[s, 2] * v[s, 2]
            cum += seg_len[s]
            s0[s] = cum - seg_len[s]
        prev_cut = 0.0
        for s in range(n_s):
            so = _sin_or_one(cos_t[s])
            cut = 0.5 * acc_r * so
            dev[s] = max((4.0 / 27.0) * seg_len[s] * so, max(cut, prev_cut))
            prev_cut = cut
            for i in range(3):
                q2[s, i] = pp[s + 1, i] - (seg_len[s] / 3.0) * v[s, i]
        if has_heading:
            c0 = u[0, 0] * heading[0] + u[0, 1] * heading[1] + u[0, 2] * heading[2]
            dev[0] = max(dev[0], 0.5 * acc_r * _sin_or_one(c0))
        # -- J2 hazard (§4.3, §4.5, §4.6) ---------------------------------------------------------------
        soft_cyl = 0.0
        soft_sph = 0.0
        soft_rad = 0.0
        soft_thr = 0.0
        for s in range(n_s):
            ax, ay, az = pp[s, 0], pp[s, 1], pp[s, 2]
            bx, by, bz = pp[s + 1, 0], pp[s + 1, 1], pp[s + 1, 2]
            # an obstacle adds to J2 only within d_safe + dev of the chord (in plan view): the others add exact
            # zeros, so the broad phase skips them and keeps the sums bit for bit (docs/method.md §4.3)
            reach = (d_safe + dev[s]) * (1.0 + 1e-9) + 1e-6
            token = p * n_s + s
            # cylinders and spheres share the grid: indices below n_cyl are cylinders, the rest spheres, each family
            # in its own index order
            n_near = _near(ax, ay, bx, by, reach, gox, goy, gcell, gnx, gny, ob_start, ob_items, ob_x, ob_y, ob_r,
                           stamp, token, near)
            for q in range(n_near):
                k = near[q]
                if k >= n_cyl:
                    break
                d2 = _seg_point_2d_sq(ax, ay, bx, by, cyl_x[k], cyl_y[k])
                if d2 > (cyl_r[k] + reach) * (cyl_r[k] + reach):  # beyond reach: an exact zero, no root needed
                    continue
                c = math.sqrt(d2) - cyl_r[k]
                if math.isfinite(cyl_top[k]) and c < d_safe + dev[s]:
                    c = _seg_cyl_finite(ax, ay, az, bx, by, bz, cyl_x[k], cyl_y[k], cyl_r[k], cyl_top[k],
                                        golden_iters)
                c -= dev[s]
                g = d_safe - c
                depth = g - gap_cap
                if depth > 0.0:
                    viol[p, 0] += 1
                    penalty += pen_c + per_m * depth
                g = min(max(g, 0.0), gap_cap)
                soft_cyl += g * g
            for q in range(n_near):
                k = near[q] - n_cyl
                if k < 0:
                    continue
                d2 = _seg_point_sq(ax, ay, az, bx, by, bz, sph_c[k, 0], sph_c[k, 1], sph_c[k, 2])
                if d2 > (sph_r[k] + reach) * (sph_r[k] + reach):
                    continue
                c = math.sqrt(d2) - sph_r[k] - dev[s]
                g = d_safe - c
                depth = g - gap_cap
                if depth > 0.0:
                    viol[p, 0] += 1
                    penalty += pen_c + per_m * depth
                g = min(max(g, 0.0), gap_cap)
                soft_sph += g * g
            for k in range(rad_det.shape[0]):
                d = _seg_point(ax, ay, az, bx, by, bz, rad_c[k, 0], rad_c[k, 1], rad_c[k, 2])
                depth = rad_det[k] - (d - dev[s])
                if depth > 0.0:
                    viol[p, 0] += 1
                    penalty += pen_c + per_m * depth
                soft_rad += rad_w[k] * (rad_det[k] / max(d, rad_det[k])) ** 4
            if timed:
                gap = seg_len[s] / (n_thr_t - 1)
                margin = dev[s] + 0.5 * gap * (1.0 + max_speed / cruise)
                for m in range(n_thr_t):
                    tt = threat_t[m]
                    px, py, pz = ax + tt * (bx - ax), ay + tt * (by - ay), az + tt * (bz - az)
                    time = start_time + (s0[s] + tt * seg_len[s]) / cruise
                    for k in range(thr.shape[0]):  # centre and radius at this time (Threats.positions, .radii)
                        kind, rad, t_ref = thr[k, 0], thr[k, 1], thr[k, 3]
                        if kind == _LOITER:  # a1 circle radius, a2 angular rate, a3 phase
                            ang = thr[k, 9] + thr[k, 8] * time
                            cx = thr[k, 4] + thr[k, 7] * math.cos(ang)
                            cy = thr[k, 5] + thr[k, 7] * math.sin(ang)
                            cz = thr[k, 6]
                        elif kind == _PATROL:  # a1..a3 unit direction A→B, a4 length, a5 speed
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
                            viol[p, 0] += 1
                            penalty += pen_c + per_m * depth
                        g = min(max(g, 0.0), gap_cap)
                        soft_thr += g * g
        j2 = soft_cyl / d_safe + soft_sph / d_safe + soft_rad + soft_thr / d_safe
        # -- J3 altitude: mid-band distance of interior waypoints; band violations of the curve (§4.7) ---
        mid, half = 0.5 * (z_min + z_max), 0.5 * (z_max - z_min)
        j3 = 0.0
        for w in range(1, n_pts - 1):
            h = pp[w, 2] - _ground(pp[w, 0], pp[w, 1], has_terrain, tx0, ty0, tdx, tdy, terrain_h)
            j3 += abs(h - mid) / half
        for s in range(n_s):
            z0 = pp[s, 2]
            z1 = z0 + seg[s, 2] / 3.0
            z2 = q2[s, 2]
            z3 = pp[s + 1, 2]
            if not has_terrain:
                lo = min(min(z0, z3), min(z1, z2))
                hi = max(max(z0, z3), max(z1, z2))
                if lo < z_min or hi > z_max:
                    lo, hi = _cubic_range(z0, z1, z2, z3)
                depth = max(z_min - lo, hi - z_max)
                if depth > 0.0:
                    viol[p, 1] += 1
                    penalty += pen_c + per_m * depth
            else:
                q1x = pp[s, 0] + seg[s, 0] / 3.0
                q1y = pp[s, 1] + seg[s, 1] / 3.0
                q1z = pp[s, 2] + seg[s, 2] / 3.0
                ddx, ddy, ddz = q1x - pp[s, 0], q1y - pp[s, 1], q1z - pp[s, 2]
                gap = math.sqrt(ddx * ddx + ddy * ddy + ddz * ddz) * (3.0 / (n_ter_t - 1))
                margin = 0.5 * slope * gap
                for m in range(n_ter_t):
                    tt = terrain_t[m]
                    x = _bezier(pp[s, 0], q1x, q2[s, 0], pp[s + 1, 0], tt)
                    y = _bezier(pp[s, 1], q1y, q2[s, 1], pp[s + 1, 1], tt)
                    z = _bezier(pp[s, 2], q1z, q2[s, 2], pp[s + 1, 2], tt)
                    z = z - _ground(x, y, has_terrain, tx0, ty0, tdx, tdy, terrain_h)
                    depth = max(z_min + margin - z, z - z_max)
                    if depth > 0.0:
                        viol[p, 1] += 1
                        penalty += pen_c + per_m * depth
        # -- bounds: the curve lies in the hull of a, Q1 (on the chord), Q2 and b -------------------------
        for s in range(n_s):
            lo_x = min(min(pp[s, 0], pp[s + 1, 0]), q2[s, 0])
            lo_y = min(min(pp[s, 1], pp[s + 1, 1]), q2[s, 1])
            hi_x = max(max(pp[s, 0], pp[s + 1, 0]), q2[s, 0])
            hi_y = max(max(pp[s, 1], pp[s + 1, 1]), q2[s, 1])
            depth = max(max(-lo_x, hi_x - size_x), max(-lo_y, hi_y - size_y))
            if depth > 0.0:
                viol[p, 2] += 1
                penalty += pen_c + per_m * depth
        # -- J4 smoothness: turns and climb changes; turn, curvature and climb limits (§4.4, §11) -------
        j4 = 0.0
        for s in range(n_s):
            gam[s] = math.atan2(seg[s, 2], math.hypot(seg[s, 0], seg[s, 1]))
        for s in range(n_s - 1):
            x0, y0 = seg[s, 0], seg[s, 1]
            x1, y1 = seg[s + 1, 0], seg[s + 1, 1]
            turn = abs(math.atan2(x0 * y1 - y0 * x1, x0 * x1 + y0 * y1))
            over = max(turn - max_turn, 0.0)
            j4 += turn + abs(gam[s + 1] - gam[s]) + over**2
            if over > 0.0:
                viol[p, 3] += 1
                penalty += pen_c + per_rad * over
        for s in range(n_s):
            depth = _peak_curvature(seg_len[s], cos_t[s], peak_table) * r_min - 1.0
            if depth > 0.0:
                viol[p, 3] += 1
                penalty += pen_c + per_rad * depth
        for s in range(n_s):
            tan2 = _peak_climb(u[s, 0], u[s, 1], u[s, 2], v[s, 0], v[s, 1], v[s, 2])
            if tan2 < climb_tan2:  # well inside the limit (atan is monotone): skip the arctangent
                continue
            depth = math.atan(math.sqrt(tan2)) - max_climb
            if depth > 0.0:
                viol[p, 4] += 1
                penalty += pen_c + per_rad * depth
        if has_heading:
            hx, hy = heading[0], heading[1]
            turn0 = abs(math.atan2(hx * seg[0, 1] - hy * seg[0, 0], hx * seg[0, 0] + hy * seg[0, 1]))
            over0 = max(turn0 - max_turn, 0.0)
            j4 += turn0 + over0**2
            if over0 > 0.0:
                viol[p, 3] += 1
                penalty += pen_c + per_rad * over0
            c0 = u[0, 0] * heading[0] + u[0, 1] * heading[1] + u[0, 2] * heading[2]
            depth = _peak_curvature(seg_len[0], c0, peak_table) * r_min - 1.0
            if depth > 0.0:
                viol[p, 3] += 1
                penalty += pen_c + per_rad * depth
        j5 = seg_len[n_s - 1] / max(direct, _EPS)
        terms[p, 0], terms[p, 1], terms[p, 2], terms[p, 3], terms[p, 4] = j1, j2, j3, j4, j5
        pen[p] = penalty
    return terms, pen, viol


def _threat_rows(thr) -> np.ndarray:  # noqa: ANN001
    """Threats (K, 12): kind, radius, radius growth, t_ref, p0, then per kind the law's constants, computed as
    Threats.positions computes them (so the kernel's centres match the reference's to the last bit)."""
    rows = np.zeros((len(thr), 12))
    rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = thr.kind, thr.radius, thr.radius_growth, thr.t_ref
    rows[:, 4:7] = thr.p0
    for k in range(len(thr)):  # a handful of threats, once per problem
        if thr.kind[k] == _LOITER:
            r = thr.circle_radius[k]
            rows[k, 7:10] = r, thr.direction[k] * thr.speed[k] / (r if r > 0 else 1.0), thr.phase[k]
        elif thr.kind[k] == _PATROL:
            ab = thr.p1[k] - thr.p0[k]
            length = float(np.linalg.norm(ab))
            safe = length if length > 0 else 1.0
            rows[k, 7:12] = *(ab / safe), safe, thr.speed[k]
        else:
            rows[k, 7:10] = thr.p1[k]
    return rows


def _grid(size_x: float, size_y: float, obstacles: int, on: bool) -> np.ndarray:
    """Broad-phase grid (origin x, origin y, cell, nx, ny) over the map; one cell holding everything when off.
    About one obstacle per cell (cells of √(area / obstacles)), at most GRID_CELLS along the longer side: finer
    cells cost more cell visits per segment than the distances they save."""
    if not on or obstacles < GRID_MIN_OBSTACLES:
        return np.array([0.0, 0.0, 1e300, 1.0, 1.0])
    cell = max(max(size_x, size_y, 1.0) / GRID_CELLS, math.sqrt(max(size_x * size_y, 1.0) / obstacles))
    return np.array([0.0, 0.0, cell, max(math.ceil(size_x / cell), 1), max(math.ceil(size_y / cell), 1)], dtype=float)


def _cells(grid: np.ndarray, x: np.ndarray, y: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compressed rows (start (cells + 1,), items) of the obstacles whose plan-view discs (centre x, y, radius r)
    reach each cell, ascending within a cell; off-map parts go to the edge cells, as the query clamps too."""
    ox, oy, cell, nx, ny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
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
    return start, items


def _arrays(problem, threat_t: np.ndarray, terrain_t: np.ndarray, broad: bool) -> tuple:  # noqa: ANN001
    """Everything the kernel reads from a problem, as contiguous float arrays (made once per problem)."""
    from planner.trajectory.smoothing import _PEAK_FACTOR  # the same G(cos θ) table as the reference
    from planner.world.geometry import GOLDEN_ITERS

    env, veh, hz, pen = problem.env, problem.vehicle, problem.hazard, problem.penalty
    ter, thr = env.terrain, env.threats
    timed = problem.timed_threats
    heading = problem.start_heading
    scalars = np.array([
        veh.acceptance_radius, hz.d_safe, hz.d_coll, pen.constant, pen.per_metre, pen.per_radian, veh.max_turn,
        veh.min_turn_radius, veh.max_climb, env.z_min, env.z_max, env.size_x, env.size_y,
        problem.direct_distance, veh.cruise_speed, problem.start_time if timed else 0.0, float(timed),
        thr.max_speed, float(heading is not None), float(ter is not None),
        ter.x0 if ter is not None else 0.0, ter.y0 if ter is not None else 0.0,
        ter.dx if ter is not None else 1.0, ter.dy if ter is not None else 1.0, problem._terrain_slope,
    ], dtype=float)

    def f(a, shape=(-1,)):  # noqa: ANN001, ANN202 - a writeable copy: one compiled signature for every problem
        return np.array(a, dtype=np.float64, order="C").reshape(shape)

    cyl, sph, rad = env.cylinders, env.spheres, env.radars
    grid = _grid(env.size_x, env.size_y, len(cyl.x) + len(sph.radius), broad)
    ob_x = f(np.concatenate([cyl.x, sph.center[:, 0]]))  # cylinders then spheres: one grid for both
    ob_y = f(np.concatenate([cyl.y, sph.center[:, 1]]))
    ob_r = f(np.concatenate([cyl.radius, sph.radius]))
    return (
        scalars, f(heading if heading is not None else np.zeros(3)),
        f(cyl.x), f(cyl.y), f(cyl.radius), f(cyl.top), f(sph.center, (-1, 3)), f(sph.radius),
        f(rad.center, (-1, 3)), f(rad.r_det), f(rad.soft_weight),
        f(ter.heights, ter.heights.shape) if ter is not None else np.zeros((2, 2)),
        _threat_rows(thr),
        f(_PEAK_FACTOR), f(threat_t), f(terrain_t), np.int64(GOLDEN_ITERS),
        grid, ob_x, ob_y, ob_r, *_cells(grid, ob_x, ob_y, ob_r),
    )


def _packed(problem, threat_t: np.ndarray, terrain_t: np.ndarray) -> tuple:  # noqa: ANN001
    """(broad phase on, the kernel's arrays) for ``problem``, made once per problem and broad-phase setting; the
    sample parameters are the reference's constants, so the first caller's are everyone's."""
    broad = broad_phase()
    cache = problem.__dict__.get("_kernel_arrays")
    if cache is None or cache[0] != broad:
        cache = (broad, _arrays(problem, threat_t, terrain_t, broad))
        object.__setattr__(problem, "_kernel_arrays", cache)
    return cache


def evaluate(
    problem, paths: np.ndarray, threat_t: np.ndarray, terrain_t: np.ndarray  # noqa: ANN001
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unweighted terms (P, 5) J1…J5, penalty (P,) and violation counts (P, 5) in CATEGORIES order for paths
    (P, N, 3) metres, from the compiled kernel; ``threat_t``/``terrain_t`` are the reference's sample parameters."""
    packed = _packed(problem, threat_t, terrain_t)[1]
    paths = np.asarray(paths, dtype=np.float64)
    if not (paths.flags.c_contiguous and paths.flags.writeable):  # one signature: C-ordered and writeable
        paths = np.array(paths, dtype=np.float64, order="C")
    return _cost(paths, *packed)


# -- the swarm's own per-iteration work: decoding spherical particles and the PSO update -------------------------
@_jit
def _decode_spherical(x, start, goal):  # noqa: ANN001, ANN202
    """Paths (P, n + 2, 3) from spherical particles (P, n, 3), as geometry.spherical_to_cartesian + start/goal:
    the steps summed in order from the start (the reference's cumsum, then start + sum)."""
    n_p, n = x.shape[0], x.shape[1]
    out = np.empty((n_p, n + 2, 3))
    for p in range(n_p):
        for i in range(3):
            out[p, 0, i] = start[i]
            out[p, n + 1, i] = goal[i]
        sx = sy = sz = 0.0
        for k in range(n):
            r, psi, phi = x[p, k, 0], x[p, k, 1], x[p, k, 2]
            cpsi = math.cos(psi)
            sx += r * cpsi * math.cos(phi)
            sy += r * cpsi * math.sin(phi)
            sz += r * math.sin(psi)
            out[p, k + 1, 0] = start[0] + sx
            out[p, k + 1, 1] = start[1] + sy
            out[p, k + 1, 2] = start[2] + sz
    return out


def decode_spherical(x: np.ndarray, start: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Compiled :meth:`planner.search.encoding.Encoding.decode` for the spherical encoding (docs/method.md §3.1)."""
    return _decode_spherical(np.ascontiguousarray(x, dtype=np.float64), np.asarray(start, dtype=np.float64),
                             np.asarray(goal, dtype=np.float64))


@_jit
def _pso_step(x, v, pbest, gbest, w, c1, c2, lo, hi, vmax, reflection, r1, r2):  # noqa: ANN001, ANN202
    """planner.search.spso.pso_step element by element, the same operations in the same order (so bit for bit)."""
    n_p, n, d = x.shape
    x_new = np.empty_like(x)
    v_new = np.empty_like(v)
    for p in range(n_p):
        wp = w[p]
        for k in range(n):
            for i in range(d):
                xi = x[p, k, i]
                vi = (wp * v[p, k, i] + c1 * r1[p, k, i] * (pbest[p, k, i] - xi)
                      + c2 * r2[p, k, i] * (gbest[k, i] - xi))
                vi = min(max(vi, -vmax[k, i]), vmax[k, i])
                xi = xi + vi
                if xi < lo[k, i] or xi > hi[k, i]:
                    xi = min(max(xi, lo[k, i]), hi[k, i])
                    if reflection:
                        vi = -vi
                x_new[p, k, i] = xi
                v_new[p, k, i] = vi
    return x_new, v_new


def pso_step(x: np.ndarray, v: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, w: float | np.ndarray, c1: float,
             c2: float, lo: np.ndarray, hi: np.ndarray, vmax: np.ndarray, reflection: bool, r1: np.ndarray,
             r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Compiled :func:`planner.search.spso.pso_step` for swarms (P, n, 3); ``w`` a scalar or (P, 1, 1)."""
    c = np.ascontiguousarray
    ww = np.broadcast_to(np.asarray(w, dtype=np.float64).reshape(-1), (len(x),)).copy()
    return _pso_step(c(x), c(v), c(pbest), c(gbest), ww, float(c1), float(c2), c(lo), c(hi),
                     c(np.broadcast_to(vmax, lo.shape)), bool(reflection), c(r1), c(r2))


# -- which lattice edges are hopeless (the ant colonies' segment_blocked) ------------------------------------------
@_jit
def _blocked(a, b, d_coll, cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, golden_iters, grid,
             ob_x, ob_y, ob_r, ob_start, ob_items):  # noqa: ANN001, ANN202
    """For segments a→b (E, 3): within d_coll of a cylinder or sphere, or inside a radar's range (as
    PlanningProblem.segment_blocked), visiting only the obstacles the broad phase finds within d_coll."""
    n_e = a.shape[0]
    out = np.zeros(n_e, dtype=np.bool_)
    n_cyl = cyl_x.shape[0]
    near = np.empty(ob_x.shape[0], dtype=np.int64)
    stamp = np.full(ob_x.shape[0], -1, dtype=np.int64)
    gox, goy, gcell, gnx, gny = grid[0], grid[1], grid[2], int(grid[3]), int(grid[4])
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


def segment_blocked(problem, a: np.ndarray, b: np.ndarray, threat_t: np.ndarray,  # noqa: ANN001
                    terrain_t: np.ndarray) -> np.ndarray:
    """Compiled :meth:`planner.problem.PlanningProblem.segment_blocked` for segments a→b (..., 3); the sample
    parameters as for :func:`evaluate` (the problem's packed arrays are shared)."""
    _, packed = _packed(problem, threat_t, terrain_t)
    (_, _, cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, _, _, _, _, _, _, golden, grid, *obs) = packed
    shape = np.broadcast_shapes(np.shape(a), np.shape(b))
    flat_a = np.ascontiguousarray(np.broadcast_to(a, shape), dtype=np.float64).reshape(-1, 3)
    flat_b = np.ascontiguousarray(np.broadcast_to(b, shape), dtype=np.float64).reshape(-1, 3)
    got = _blocked(flat_a, flat_b, float(problem.hazard.d_coll), cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c,
                   rad_det, golden, grid, *obs)
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
