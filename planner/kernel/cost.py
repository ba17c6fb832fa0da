"""The cost J of docs/method.md §4–§5 for a swarm of paths in one compiled pass, and its terms' helpers.

Particles are the innermost loop and each such loop writes one array, so the compiler runs it in SIMD lanes (its
arctangents are planner.kernel.fastmath's). Each particle still adds its own sums in the order of one particle at
a time, and obstacles skipped by the broad phase or by the swarm's box add exact zeros, so the settings give the
same costs bit for bit (docs/design.md, "Compiled kernels")."""

from __future__ import annotations

import functools
import math

import numpy as np

from planner.kernel.fastmath import bezier, cubic_range, fast_atan2, peak_factor
from planner.kernel.inputs import SLOPE_BLOCK, KernelInputs, broad_phase
from planner.kernel.jit import called, inline, jit
from planner.kernel.segments import prism_lanes, prism_width, seg_cyl_finite, seg_point_2d_sq, seg_point_sq
from planner.world.environment import LOITER, PATROL

_EPS = 1e-9  # as planner.problem: unit directions
_EPS_CURV = 1e-12  # as planner.trajectory.smoothing: curvature's segment-length floor
_NEAR_LIMIT = 1e-12  # rad: a turn this close to its limit is measured with libm's atan2 (see _cost)


@inline
def _ground(x, y, has_terrain, tx0, ty0, tdx, tdy, h):
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


@inline
def _peak_curvature(seg_len, cos_turn, table):
    c = min(max(cos_turn, -1.0), 1.0)
    return peak_factor(c, table) * math.sqrt(1.0 - c * c) / max(seg_len, _EPS_CURV)


@inline
def _sin_or_one(cos_turn):
    """sin θ for turns up to 90°, 1 past it (smoothing.deviation_bound / corner_cut_bound)."""
    c = min(max(cos_turn, -1.0), 1.0)
    return math.sqrt(1.0 - c * c) if c >= 0.0 else 1.0


@inline
def _after_turn(acc_r, overshoot, cos_turn):
    """What a turn does to the segment after it: the corner's cut or the swing past it, the larger
    (smoothing.corner_cut_bound, overshoot_bound)."""
    cut = 0.5 * acc_r * _sin_or_one(cos_turn)
    if overshoot <= 0.0:
        return cut
    return max(cut, overshoot * math.acos(min(max(cos_turn, -1.0), 1.0)))


@inline
def _peak_climb(ux, uy, uz, vx, vy, vz):
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


@inline
def _tan2_at(ux, uy, uz, dx, dy, dz, bb):
    wz = uz + bb * dz
    wx = ux + bb * dx
    wy = uy + bb * dy
    return wz * wz / max(wx * wx + wy * wy, 1e-300)


@inline
def _add_violations(excess, s, limit, pen_c, rate, pen, viol, category):
    """Each particle whose ``excess[s] − limit`` is positive adds a violation of that depth: the penalty and the
    count in two loops (a loop writing one array runs in SIMD lanes; adding a zero leaves a sum as it was)."""
    n_p = excess.shape[1]
    for p in range(n_p):
        depth = excess[s, p] - limit
        pen[p] += pen_c + rate * depth if depth > 0.0 else 0.0
    for p in range(n_p):
        viol[category, p] += 1 if excess[s, p] - limit > 0.0 else 0


@inline
def _box_beyond(x_lo, x_hi, y_lo, y_hi, cx, cy, dist):
    """Whether the point (cx, cy) is farther than ``dist`` from the box."""
    ex = max(max(x_lo - cx, cx - x_hi), 0.0)
    ey = max(max(y_lo - cy, cy - y_hi), 0.0)
    return ex * ex + ey * ey > dist * dist


@inline
def _hazard(c, p, d_safe, gap_cap, pen_c, per_m, soft, pen, viol):
    """Particle p's hazard term for one clearance c (§4.3): a collision past the soft cap, the clipped gap squared."""
    g = d_safe - c
    depth = g - gap_cap
    if depth > 0.0:
        viol[0, p] += 1
        pen[p] += pen_c + per_m * depth
    g = min(max(g, 0.0), gap_cap)
    soft[p] += g * g


@inline
def _roofed_cylinder_term(pt, s, p, cx, cy, r, top, d_safe, dev, gap_cap, pen_c, per_m, iters, soft, pen, viol):
    """Particle p's segment s against one cylinder with a finite ``top``, one particle at a time: J2's soft term
    into ``soft[p]``, a collision into ``pen[p]``/``viol[0, p]``; near the wall, the roof by golden section."""
    ax, ay, az = pt[s, 0, p], pt[s, 1, p], pt[s, 2, p]
    bx, by, bz = pt[s + 1, 0, p], pt[s + 1, 1, p], pt[s + 1, 2, p]
    reach = (d_safe + dev) * (1.0 + 1e-9) + 1e-6
    d2 = seg_point_2d_sq(ax, ay, bx, by, cx, cy)
    if d2 > (r + reach) * (r + reach):  # beyond reach: an exact zero, no root needed
        return
    c = math.sqrt(d2) - r
    if c < d_safe + dev:
        c = seg_cyl_finite(ax, ay, az, bx, by, bz, cx, cy, r, top, iters)
    _hazard(c - dev, p, d_safe, gap_cap, pen_c, per_m, soft, pen, viol)


@called
def _threat_terms(pt, s, p, seg_len, s0, dev, thr, threat_t, start_time, cruise, max_speed, d_safe, gap_cap,
                  pen_c, per_m, soft, pen, viol):
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
            _hazard(math.sqrt(ex * ex + ey * ey + ez * ez) - rad - margin, p, d_safe, gap_cap, pen_c, per_m,
                    soft, pen, viol)


@inline
def _above(ax, ay, az, dx, dy, dz, t, tx0, ty0, tdx, tdy, h):
    """Height above the ground of a + t (b − a)."""
    return az + t * dz - _ground(ax + t * dx, ay + t * dy, True, tx0, ty0, tdx, tdy, h)


@inline
def _lines(a, b, origin, step, n):
    """The first and last grid line (grid units) that a span a..b meets along one axis, the grid clamped."""
    fa = min(max((a - origin) / step, 0.0), n - 1.0)
    fb = min(max((b - origin) / step, 0.0), n - 1.0)
    return math.ceil(min(fa, fb)), math.floor(max(fa, fb))


@called
def _chord_range(ax, ay, az, bx, by, bz, tx0, ty0, tdx, tdy, h):
    """Least and greatest height above the bilinear ground along the segment a→b, exactly: Terrain.clearance_range
    (docs/method.md §15.1), piece by piece between the grid lines in the order the segment meets them."""
    ny, nx = h.shape
    dx, dy, dz = bx - ax, by - ay, bz - az
    x_first, x_last = _lines(ax, bx, tx0, tdx, nx)
    y_first, y_last = _lines(ay, by, ty0, tdy, ny)
    nxc = x_last - x_first + 1 if dx != 0.0 else 0
    nyc = y_last - y_first + 1 if dy != 0.0 else 0
    ix = 0
    iy = 0
    t0 = 0.0
    f0 = _above(ax, ay, az, dx, dy, dz, 0.0, tx0, ty0, tdx, tdy, h)
    lo = f0
    hi = f0
    while True:
        tx = 2.0
        if ix < nxc:
            k = x_first + ix if dx > 0.0 else x_last - ix
            tx = min(max((tx0 + k * tdx - ax) / dx, 0.0), 1.0)
        ty = 2.0
        if iy < nyc:
            k = y_first + iy if dy > 0.0 else y_last - iy
            ty = min(max((ty0 + k * tdy - ay) / dy, 0.0), 1.0)
        if tx <= ty and tx <= 1.0:
            t1 = tx
            ix += 1
        elif ty <= 1.0:
            t1 = ty
            iy += 1
        else:
            t1 = 1.0
        f1 = _above(ax, ay, az, dx, dy, dz, t1, tx0, ty0, tdx, tdy, h)
        fm = _above(ax, ay, az, dx, dy, dz, 0.5 * (t0 + t1), tx0, ty0, tdx, tdy, h)
        qa = 2.0 * f0 - 4.0 * fm + 2.0 * f1  # the quadratic through the piece's ends and middle, and its vertex
        qb = -3.0 * f0 + 4.0 * fm - f1
        w = min(max(-qb / (2.0 * qa), 0.0), 1.0) if abs(qa) > 1e-12 else 0.0
        v = f0 + qb * w + qa * w * w
        lo = min(lo, min(f1, v))
        hi = max(hi, max(f1, v))
        if t1 >= 1.0 and ix >= nxc and iy >= nyc:
            break
        t0 = t1
        f0 = f1
    return lo, hi


@inline
def _local_slope(ax, ay, bx, by, tx0, ty0, tdx, tdy, nx, ny, slopes):
    """The largest bound of |∇h| over the slope blocks under the box of a chord a→b (Terrain.slope_blocks)."""
    i0 = min(int(min(max((min(ax, bx) - tx0) / tdx, 0.0), nx - 2.0)), nx - 2) // SLOPE_BLOCK
    i1 = min(int(min(max((max(ax, bx) - tx0) / tdx, 0.0), nx - 2.0)), nx - 2) // SLOPE_BLOCK
    j0 = min(int(min(max((min(ay, by) - ty0) / tdy, 0.0), ny - 2.0)), ny - 2) // SLOPE_BLOCK
    j1 = min(int(min(max((max(ay, by) - ty0) / tdy, 0.0), ny - 2.0)), ny - 2) // SLOPE_BLOCK
    out = 0.0
    for j in range(j0, j1 + 1):
        for i in range(i0, i1 + 1):
            out = max(out, slopes[j, i])
    return out


@called
def _terrain_terms(pt, seg, q2, s, p, terrain_t, slopes, max_slope, sag, z_min, z_max, tx0, ty0, tdx, tdy,
                   terrain_h, pen_c, per_m, pen, viol):
    """Particle p's curve on segment s against the band above the terrain: each chord between two of its samples,
    exactly over the ground (_chord_range: the roadmap's and the checker's test, §4.7, §15.1). A chord whose ends
    are inside the band by more than the local slope bound × its horizontal length cannot leave it (the ground
    departs from the line between its ends by at most that) and is not worked out: same result, less time."""
    ny, nx = terrain_h.shape
    q1x = pt[s, 0, p] + seg[s, 0, p] / 3.0
    q1y = pt[s, 1, p] + seg[s, 1, p] / 3.0
    q1z = pt[s, 2, p] + seg[s, 2, p] / 3.0
    # the curve strays from a chord by at most sag × its largest second difference (the band is narrowed by that,
    # and by what the ground can differ under it: × (1 + the steepest slope))
    ax, ay, az = q2[s, 0, p] - 2.0 * q1x + pt[s, 0, p], q2[s, 1, p] - 2.0 * q1y + pt[s, 1, p], \
        q2[s, 2, p] - 2.0 * q1z + pt[s, 2, p]
    bx, by, bz = pt[s + 1, 0, p] - 2.0 * q2[s, 0, p] + q1x, pt[s + 1, 1, p] - 2.0 * q2[s, 1, p] + q1y, \
        pt[s + 1, 2, p] - 2.0 * q2[s, 2, p] + q1z
    second = max(math.sqrt(ax * ax + ay * ay + az * az), math.sqrt(bx * bx + by * by + bz * bz))
    margin = sag * (1.0 + max_slope) * second
    lo_z, hi_z = z_min + margin, z_max - margin
    px, py, pz, ph = 0.0, 0.0, 0.0, 0.0
    for m in range(terrain_t.shape[0]):
        tt = terrain_t[m]
        x = bezier(pt[s, 0, p], q1x, q2[s, 0, p], pt[s + 1, 0, p], tt)
        y = bezier(pt[s, 1, p], q1y, q2[s, 1, p], pt[s + 1, 1, p], tt)
        z = bezier(pt[s, 2, p], q1z, q2[s, 2, p], pt[s + 1, 2, p], tt)
        h = z - _ground(x, y, True, tx0, ty0, tdx, tdy, terrain_h)
        if m > 0:
            slope = _local_slope(px, py, x, y, tx0, ty0, tdx, tdy, nx, ny, slopes)
            room = slope * math.sqrt((x - px) * (x - px) + (y - py) * (y - py))
            if min(ph, h) - lo_z <= room or hi_z - max(ph, h) <= room:
                lo, hi = _chord_range(px, py, pz, x, y, z, tx0, ty0, tdx, tdy, terrain_h)
                depth = max(lo_z - lo, hi - hi_z)
                if depth > 0.0:
                    viol[1, p] += 1
                    pen[p] += pen_c + per_m * depth
        px, py, pz, ph = x, y, z, h


@called
def _terrain_band(pt, seg, q2, terrain_t, slopes, max_slope, sag, z_min, z_max, tx0, ty0, tdx, tdy, terrain_h,
                  pen_c, per_m, pen, viol):
    """Every particle's curve on every segment against the band above the terrain (_terrain_terms), segment by
    segment as in _cost: one call from it, whose loop keeps few values live around each particle's call."""
    for s in range(pt.shape[0] - 1):
        for p in range(pt.shape[2]):
            _terrain_terms(pt, seg, q2, s, p, terrain_t, slopes, max_slope, sag, z_min, z_max, tx0, ty0, tdx, tdy,
                           terrain_h, pen_c, per_m, pen, viol)


@jit
def _cost(paths, acc_r, overshoot, max_turn, r_min, max_climb, cruise, d_safe, d_coll, pen_c, per_m, per_rad,
          w_length, w_hazard, w_altitude, w_smoothness, w_destination, z_min, z_max, size_x, size_y, direct,
          has_heading, heading, timed, start_time, max_speed, thr, has_terrain, tx0, ty0, tdx, tdy, slopes, max_slope,
          sag, terrain_h,
          cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, rad_w, pri_v, pri_start, pri_rows, peak_table,
          threat_t, terrain_t, golden_iters, broad):
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
    soft_pri = np.zeros(n_p)
    cum = np.zeros(n_p)
    pen = np.zeros(n_p)
    viol = np.zeros((5, n_p), dtype=np.int64)  # collision, altitude, bounds, turn, climb
    n_cyl = cyl_x.shape[0]
    n_sph = sph_r.shape[0]
    n_pri = pri_rows.shape[0]
    lane = np.empty((7, n_p))  # the near particles' segments against one prism (prism_lanes), and scratch
    lane_p = np.empty(n_p, dtype=np.int64)
    near_i = np.empty(n_p, dtype=np.int64)
    clr = np.empty(n_p)
    pri_ws = np.empty((12, max(2 * n_p, prism_width(pri_start), 6)))
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
                c = math.sqrt(seg_point_2d_sq(pt[s, 0, p], pt[s, 1, p], pt[s + 1, 0, p], pt[s + 1, 1, p], cx,
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
                c = math.sqrt(seg_point_sq(pt[s, 0, p], pt[s, 1, p], pt[s, 2, p], pt[s + 1, 0, p],
                                            pt[s + 1, 1, p], pt[s + 1, 2, p], cx, cy, cz)) - r - dev[s, p]
                g = d_safe - c
                depth = g - gap_cap
                hit = depth > 0.0
                viol[0, p] += 1 if hit else 0
                pen[p] += pen_c + per_m * depth if hit else 0.0
                g = min(max(g, 0.0), gap_cap)
                soft_sph[p] += g * g
        for k in range(n_pri):  # polygon prisms (§2.7): a keep-in polygon is near every segment
            f, h, keep, cx, cy, r = pri_rows[k, 0], pri_rows[k, 1], pri_rows[k, 2] > 0.0, pri_rows[k, 3], \
                pri_rows[k, 4], pri_rows[k, 5]
            if not keep and _box_beyond(x_lo, x_hi, y_lo, y_hi, cx, cy, r + reach):
                continue
            m = 0
            if keep:
                for p in range(n_p):
                    lane_p[p] = p
                m = n_p
            else:
                for p in range(n_p):  # beyond a particle's reach the clearance adds an exact zero, as a cylinder's
                    reach_p = (d_safe + dev[s, p]) * (1.0 + 1e-9) + 1e-6  # its disc beyond: no edge is looked at
                    lim = r + reach_p
                    near_i[p] = 0 if seg_point_2d_sq(pt[s, 0, p], pt[s, 1, p], pt[s + 1, 0, p], pt[s + 1, 1, p], cx,
                                                     cy) > lim * lim else 1
                for p in range(n_p):  # the near particles, in order (no branch: every p written, m moved by 0/1)
                    lane_p[m] = p
                    m += near_i[p]
                if m == 0:
                    continue
            for q in range(m):  # their segments, gathered into lanes
                p = lane_p[q]
                for i in range(3):
                    lane[i, q] = pt[s, i, p]
                    lane[3 + i, q] = pt[s + 1, i, p]
                lane[6, q] = (d_safe + dev[s, p]) * (1.0 + 1e-9) + 1e-6
            prism_lanes(lane, pri_v, pri_start[k], pri_start[k + 1], f, h, keep, m, pri_ws, clr)
            for i in range(m):
                if clr[i] < lane[6, i]:  # at or beyond reach the term is an exact zero
                    p = lane_p[i]
                    _hazard(clr[i] - dev[s, p], p, d_safe, gap_cap, pen_c, per_m, soft_pri, pen, viol)
        for k in range(rad_det.shape[0]):
            cx, cy, cz, det, wt = rad_c[k, 0], rad_c[k, 1], rad_c[k, 2], rad_det[k], rad_w[k]
            for p in range(n_p):
                d = math.sqrt(seg_point_sq(pt[s, 0, p], pt[s, 1, p], pt[s, 2, p], pt[s + 1, 0, p], pt[s + 1, 1, p],
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
        _terrain_band(pt, seg, q2, terrain_t, slopes, max_slope, sag, z_min, z_max, tx0, ty0, tdx, tdy, terrain_h,
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
                lo, hi = cubic_range(z0, z0 + seg[s, 2, p] / 3.0, q2[s, 2, p], z3)
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
            gam[s, p] = fast_atan2(seg[s, 2, p], math.sqrt(x * x + y * y))
    for s in range(n_s - 1):
        for p in range(n_p):
            x0, y0 = seg[s, 0, p], seg[s, 1, p]
            x1, y1 = seg[s + 1, 0, p], seg[s + 1, 1, p]
            work[s, p] = abs(fast_atan2(x0 * y1 - y0 * x1, x0 * x1 + y0 * y1))
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
        terms[p, 1] = (soft_cyl[p] / d_safe + soft_sph[p] / d_safe + soft_rad[p] + soft_thr[p] / d_safe
                       + soft_pri[p] / d_safe)  # prisms last: without any, the sum is as it was, bit for bit
        terms[p, 2] = j3[p]
        terms[p, 3] = j4[p]
        terms[p, 4] = seg_len[n_s - 1, p] / inv_direct
        for i in range(5):
            violations[p, i] = viol[i, p]
        total[p] = (pen[p] + w_length * terms[p, 0] + w_hazard * terms[p, 1] + w_altitude * terms[p, 2]
                    + w_smoothness * terms[p, 3] + w_destination * terms[p, 4])  # the reference's order
    return terms, pen, violations, total


@functools.lru_cache(maxsize=2)
def _arguments(k: KernelInputs) -> tuple:
    """_cost's arguments after the paths, by name from ``k``: made once per problem (a search evaluates one problem
    many times), which saves a third of a microsecond a call."""
    return (k.acceptance_radius, k.turn_overshoot, k.max_turn, k.min_turn_radius, k.max_climb, k.cruise_speed,
            k.d_safe, k.d_coll, k.penalty_constant, k.penalty_per_metre, k.penalty_per_radian, k.weight_length,
            k.weight_hazard, k.weight_altitude, k.weight_smoothness, k.weight_destination, k.z_min, k.z_max,
            k.size_x, k.size_y, k.direct_distance, k.has_heading, k.heading, k.timed, k.start_time,
            k.threat_max_speed, k.threats, k.has_terrain, k.terrain_x0, k.terrain_y0, k.terrain_dx, k.terrain_dy,
            k.terrain_slopes, k.terrain_slope, k.terrain_sag, k.terrain_heights,
            k.cyl_x, k.cyl_y, k.cyl_r, k.cyl_top, k.sph_c, k.sph_r, k.rad_c,
            k.rad_det, k.rad_w, k.pri_v, k.pri_start, k.pri_rows, k.peak_table, k.threat_t, k.terrain_t, k.golden_iters)


def evaluate(inputs: KernelInputs, paths: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Unweighted terms (P, 5) J1…J5, penalty (P,), violation counts (P, 5) in CATEGORIES order and the weighted
    total (P,) for paths (P, N, 3) metres, from the compiled kernel."""
    paths = np.asarray(paths, dtype=np.float64)
    if not (paths.flags.c_contiguous and paths.flags.writeable):  # one signature: C-ordered and writeable
        paths = np.array(paths, dtype=np.float64, order="C")
    return _cost(paths, *_arguments(inputs), broad_phase())
