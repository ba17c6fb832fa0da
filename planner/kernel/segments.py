"""Segment tests: a segment's distance to a point, a cylinder, a sphere and a polygon prism (compiled, as
planner.world.geometry computes them), the broad phase's lookup of the obstacles near a segment in the grid, and the
ant colonies' segment_blocked."""

from __future__ import annotations

import math

import numpy as np

from planner.kernel.inputs import KernelInputs, broad_phase
from planner.kernel.jit import called, inline, jit, linked

_GOLDEN = (math.sqrt(5.0) - 1.0) / 2.0


@inline
def seg_point(ax, ay, az, bx, by, bz, px, py, pz):
    """Distance from point p to segment a→b (geometry.segment_point_distance)."""
    return math.sqrt(seg_point_sq(ax, ay, az, bx, by, bz, px, py, pz))


@inline
def seg_point_sq(ax, ay, az, bx, by, bz, px, py, pz):
    """Squared distance from point p to segment a→b."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    wx, wy, wz = px - ax, py - ay, pz - az
    dd = dx * dx + dy * dy + dz * dz
    t = (wx * dx + wy * dy + wz * dz) / (dd if dd > 0.0 else 1.0)
    t = min(max(t, 0.0), 1.0)
    ex, ey, ez = wx - t * dx, wy - t * dy, wz - t * dz
    return ex * ex + ey * ey + ez * ez


@inline
def seg_point_2d(ax, ay, bx, by, px, py):
    return math.sqrt(seg_point_2d_sq(ax, ay, bx, by, px, py))


@inline
def seg_point_2d_sq(ax, ay, bx, by, px, py):
    """Squared plan-view distance from p to segment a→b (its square root is geometry.segment_point_distance_2d)."""
    dx, dy = bx - ax, by - ay
    dd = dx * dx + dy * dy
    wx, wy = px - ax, py - ay
    t = (wx * dx + wy * dy) / (dd if dd > 0.0 else 1.0)
    t = min(max(t, 0.0), 1.0)
    ex, ey = wx - t * dx, wy - t * dy
    return ex * ex + ey * ey


@inline
def _cyl_signed(ax, ay, az, dx, dy, dz, t, cx, cy, r, top):
    """Signed distance of a + t·d from a cylinder with a finite top (geometry.cylinder_signed_distance)."""
    px, py, pz = ax + t * dx, ay + t * dy, az + t * dz
    u = math.hypot(px - cx, py - cy) - r
    w = pz - top
    uo, wo = max(u, 0.0), max(w, 0.0)
    return math.sqrt(uo * uo + wo * wo) + min(max(u, w), 0.0)


@called
def seg_cyl_finite(ax, ay, az, bx, by, bz, cx, cy, r, top, iters):
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


@inline
def _edge_sq(px, py, ax, ay, ex, ey, l2):
    """Squared plan-view distance from p to the edge A + s·E (geometry._edge_sq; ``l2`` = |E|², 1 if zero)."""
    wx = px - ax
    wy = py - ay
    s = min(max((wx * ex + wy * ey) / l2, 0.0), 1.0)
    qx = wx - s * ex
    qy = wy - s * ey
    return qx * qx + qy * qy


@inline
def _edge(v, j, i0, i1):
    """Edge j of the polygon v[i0:i1] (closed): its first end, its second, its vector and |E|² (1 if zero)."""
    px, py = v[j, 0], v[j, 1]
    nj = j + 1 if j + 1 < i1 else i0
    qx, qy = v[nj, 0], v[nj, 1]
    ex, ey = qx - px, qy - py
    l2 = ex * ex + ey * ey
    return px, py, qx, qy, ex, ey, l2 if l2 > 0.0 else 1.0


@inline
def _g(t, ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h):
    """g_e(t) of docs/method.md §2.7: the squared distance of a + t·d to edge e's vertical strip [f, h]."""
    z = az + t * dz
    wo = max(max(f - z, z - h), 0.0)
    return _edge_sq(ax + t * dx, ay + t * dy, px0, py0, ex, ey, l2) + wo * wo


@inline
def _ratio(num, den):
    return num / den if den != 0.0 else 0.0


@linked
def _edge_min(ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h, knots):
    """The least of g_e over [0, 1] (geometry.segment_prism_clearance, step for step): the quadratic pieces between
    the sorted breakpoints, each's vertex from three values, g evaluated there and at the breakpoints."""
    s0 = ((ax - px0) * ex + (ay - py0) * ey) / l2
    s1 = (dx * ex + dy * ey) / l2
    knots[0] = 0.0
    knots[1] = min(max(_ratio(-s0, s1), 0.0), 1.0)
    knots[2] = min(max(_ratio(1.0 - s0, s1), 0.0), 1.0)
    knots[3] = min(max(_ratio(f - az, dz), 0.0), 1.0)
    knots[4] = min(max(_ratio(h - az, dz), 0.0), 1.0)
    knots[5] = 1.0
    for i in range(1, 6):  # insertion sort of six
        v = knots[i]
        j = i
        while j > 0 and knots[j - 1] > v:
            knots[j] = knots[j - 1]
            j -= 1
        knots[j] = v
    gl = _g(knots[0], ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h)
    best = gl
    for i in range(5):
        lo, hi = knots[i], knots[i + 1]
        gh = _g(hi, ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h)
        gm = _g(0.5 * (lo + hi), ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h)
        qa = 2.0 * gl - 4.0 * gm + 2.0 * gh
        qb = -3.0 * gl + 4.0 * gm - gh
        best = min(best, gh)
        if qa > 0.0:
            t = lo + min(max(-qb / (2.0 * qa), 0.0), 1.0) * (hi - lo)
            best = min(best, _g(t, ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h))
        gl = gh
    return best


@called
def seg_prism(ax, ay, az, bx, by, bz, v, i0, i1, f, h, keep, limit, cross, knots):
    """Signed clearance of segment a→b from the prism over polygon vertices v[i0:i1] (V, 2) between f and h (keep:
    a keep-in polygon), as geometry.segment_prism_clearance computes it (docs/method.md §2.7). Edges whose plan
    distance from the segment (bounded below from their midpoints) exceeds ``limit`` or the least so far are
    skipped: a clearance of ``limit`` or more comes back as some value ≥ ``limit`` (inf when nothing is near).
    A segment wholly between floor and ceiling takes the closed form of two segments' plan distance instead of the
    pieces (as the reference does). ``cross`` (≥ i1 − i0) and ``knots`` (6) are scratch."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    limit2 = limit * limit
    best = math.inf
    n = 0
    inside = False
    level = f <= min(az, az + dz) and max(az, az + dz) <= h  # wholly between floor and ceiling: plan view only
    dd = dx * dx + dy * dy
    dd = dd if dd > 0.0 else 1.0
    for j in range(i0, i1):
        px0, py0, qx, qy, ex, ey, l2 = _edge(v, j, i0, i1)
        # containment of a (even-odd, polygons.contains) and the crossings of the segment with this edge
        if (py0 > ay) != (qy > ay):
            dye = qy - py0 if qy != py0 else 1.0
            if ax < px0 + (ay - py0) * (qx - px0) / dye:
                inside = not inside
        oa = ex * (ay - py0) - ey * (ax - px0)
        ob = ex * (ay + dy - py0) - ey * (ax + dx - px0)
        sa = dx * (py0 - ay) - dy * (px0 - ax)
        sb = dx * (qy - ay) - dy * (qx - ax)
        hit = ((oa > 0.0) != (ob > 0.0)) and ((sa > 0.0) != (sb > 0.0))
        if hit:
            t = oa / (oa - ob)
            m = n  # insertion sort, ascending
            while m > 0 and cross[m - 1] > t:
                cross[m] = cross[m - 1]
                m -= 1
            cross[m] = t
            n += 1
        if level:  # the closed form of two segments' distance (zero where they cross): cheaper than bounding it
            if hit:
                best = 0.0
            else:
                best = min(best, min(min(_edge_sq(ax, ay, px0, py0, ex, ey, l2), _edge_sq(ax + dx, ay + dy, px0, py0,
                                                                                         ex, ey, l2)),
                                     min(_edge_sq(px0, py0, ax, ay, dx, dy, dd), _edge_sq(qx, qy, ax, ay, dx, dy, dd))))
            continue
        lb = math.sqrt(seg_point_2d_sq(ax, ay, bx, by, 0.5 * (px0 + qx), 0.5 * (py0 + qy))) - 0.5 * math.sqrt(l2)
        if lb > 0.0 and lb * lb > min(best, limit2) * (1.0 + 1e-9) + 1e-12:
            continue  # the edge is farther than what counts
        best = min(best, _edge_min(ax, ay, az, dx, dy, dz, px0, py0, ex, ey, l2, f, h, knots))
    # the parts between crossings whose plan view is in the solid's: their least max(w, 0), and where they are
    # between floor and ceiling too (inside the solid), d_prism at their middles
    if dz != 0.0:
        tf, th = (f - az) / dz, (h - az) / dz
        tw0, tw1 = max(min(tf, th), 0.0), min(max(tf, th), 1.0)
    else:
        level = f <= az and az <= h
        tw0, tw1 = (0.0, 1.0) if level else (1.0, 0.0)
    neg = math.inf
    for i in range(n + 1):
        if (inside != (i % 2 == 1)) == keep:
            continue
        lo = cross[i - 1] if i > 0 else 0.0
        hi = cross[i] if i < n else 1.0
        z0, z1 = az + lo * dz, az + hi * dz
        wmin = max(max(f - max(z0, z1), min(z0, z1) - h), 0.0)
        best = min(best, wmin * wmin)
        s_lo, s_hi = max(lo, tw0), min(hi, tw1)
        if s_hi > s_lo:
            tm = 0.5 * (s_lo + s_hi)
            px, py, pz = ax + tm * dx, ay + tm * dy, az + tm * dz
            bd = math.inf
            for j in range(i0, i1):
                ex0, ey0, _, _, ex, ey, l2 = _edge(v, j, i0, i1)
                bd = min(bd, _edge_sq(px, py, ex0, ey0, ex, ey, l2))
            neg = min(neg, max(-math.sqrt(bd), max(f - pz, pz - h)))
    return neg if neg < math.inf else math.sqrt(best)


@linked
def prism_lanes(la, v, i0, i1, f, h, keep, m, ws, clr):
    """seg_prism for m segments at once, bit for bit (docs/method.md §2.7): lanes la[:, 0:m] hold ax, ay, az, bx, by,
    bz and the limit (rows 0–6); their clearances go to clr[0:m]. Edge by edge, the segments innermost (SIMD lanes):
    a's containment, the crossings' count, first and last, and the least squared plan distance (ends to edges,
    vertices to the segment: the closed form's four distances, each vertex once). A segment wholly between floor and
    ceiling with at most two crossings is finished from these, the middles of its parts inside measured in a second
    lane pass; any other (rare) goes to seg_prism. ``ws`` (12 rows of ≥ 2m, the most vertices and 6) is scratch."""
    best, tmin, tmax, ncr, ins = ws[0], ws[1], ws[2], ws[3], ws[4]
    qx_, qy_, qb = ws[5], ws[6], ws[7]  # query points (a part's middle) and their least squared edge distance
    owner, qz = ws[8], ws[9]
    for i in range(m):
        best[i] = math.inf
        tmin[i] = math.inf
        tmax[i] = -math.inf
        ncr[i] = 0.0
        ins[i] = 0.0
    for j in range(i0, i1):
        px0, py0, qx, qy, ex, ey, l2 = _edge(v, j, i0, i1)
        dye = qy - py0 if qy != py0 else 1.0
        for i in range(m):  # branch-free: the SIMD pass
            ax, ay = la[0, i], la[1, i]
            dx, dy = la[3, i] - ax, la[4, i] - ay
            dd = dx * dx + dy * dy
            dd = dd if dd > 0.0 else 1.0
            # 0/1 flags as numbers, and no division by a lane's zero: either keeps this loop in SIMD lanes
            up = abs((1.0 if py0 > ay else 0.0) - (1.0 if qy > ay else 0.0))
            ins[i] = abs(ins[i] - up * (1.0 if ax < px0 + (ay - py0) * (qx - px0) / dye else 0.0))
            oa = ex * (ay - py0) - ey * (ax - px0)
            ob = ex * (ay + dy - py0) - ey * (ax + dx - px0)
            sa = dx * (py0 - ay) - dy * (px0 - ax)
            sb = dx * (qy - ay) - dy * (qx - ax)
            hit = abs((1.0 if oa > 0.0 else 0.0) - (1.0 if ob > 0.0 else 0.0)) \
                * abs((1.0 if sa > 0.0 else 0.0) - (1.0 if sb > 0.0 else 0.0))
            den = oa - ob  # not zero where they cross
            t = oa / (den if den != 0.0 else 1.0)
            ncr[i] += hit
            tmin[i] = min(tmin[i], t if hit > 0.5 else math.inf)
            tmax[i] = max(tmax[i], t if hit > 0.5 else -math.inf)
            d = min(min(_edge_sq(ax, ay, px0, py0, ex, ey, l2), _edge_sq(ax + dx, ay + dy, px0, py0, ex, ey, l2)),
                    _edge_sq(px0, py0, ax, ay, dx, dy, dd))
            best[i] = min(best[i], d)
    n_q = 0
    for i in range(m):  # each segment's parts in the solid (seg_prism's second half); middles become queries
        az, bz = la[2, i], la[5, i]
        dz = bz - az
        n = int(ncr[i])
        if not (f <= min(az, az + dz) and max(az, az + dz) <= h) or n > 2:
            clr[i] = math.nan  # finished by seg_prism below
            continue
        b = 0.0 if n > 0 else best[i]
        inside = ins[i] > 0.5
        if dz != 0.0:
            tf, th = (f - az) / dz, (h - az) / dz
            tw0, tw1 = max(min(tf, th), 0.0), min(max(tf, th), 1.0)
        else:
            tw0, tw1 = 0.0, 1.0
        for k in range(n + 1):
            if (inside != (k % 2 == 1)) == keep:
                continue
            lo = 0.0 if k == 0 else (tmin[i] if k == 1 else tmax[i])
            hi = 1.0 if k == n else (tmin[i] if k == 0 else tmax[i])
            z0, z1 = az + lo * dz, az + hi * dz
            wmin = max(max(f - max(z0, z1), min(z0, z1) - h), 0.0)
            b = min(b, wmin * wmin)
            s_lo, s_hi = max(lo, tw0), min(hi, tw1)
            if s_hi > s_lo:
                tm = 0.5 * (s_lo + s_hi)
                ax, ay = la[0, i], la[1, i]
                qx_[n_q] = ax + tm * (la[3, i] - ax)
                qy_[n_q] = ay + tm * (la[4, i] - ay)
                qz[n_q] = az + tm * dz
                owner[n_q] = i
                n_q += 1
        clr[i] = math.sqrt(b)
    if n_q:
        for q in range(n_q):
            qb[q] = math.inf
        for j in range(i0, i1):
            px0, py0, _, _, ex, ey, l2 = _edge(v, j, i0, i1)
            for q in range(n_q):
                qb[q] = min(qb[q], _edge_sq(qx_[q], qy_[q], px0, py0, ex, ey, l2))
        q = 0
        while q < n_q:  # a segment's queries are consecutive: the least of its parts' d_prism replaces sqrt(b)
            i = int(owner[q])
            neg = math.inf
            while q < n_q and int(owner[q]) == i:
                pz = qz[q]
                neg = min(neg, max(-math.sqrt(qb[q]), max(f - pz, pz - h)))
                q += 1
            clr[i] = neg
    for i in range(m):
        if math.isnan(clr[i]):
            clr[i] = seg_prism(la[0, i], la[1, i], la[2, i], la[3, i], la[4, i], la[5, i], v, i0, i1, f, h, keep,
                               la[6, i], ws[10], ws[11])


@inline
def prism_width(start):
    """The most vertices of one polygon, from the prisms' start indices (the crossings' scratch length)."""
    w = 0
    for k in range(start.shape[0] - 1):
        w = max(w, start[k + 1] - start[k])
    return w


@inline
def _near(ax, ay, bx, by, reach, ox, oy, cell, nx, ny, start, items, cx, cy, rad, stamp, token, out):
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


@jit
def _blocked(a, b, d_coll, cyl_x, cyl_y, cyl_r, cyl_top, sph_c, sph_r, rad_c, rad_det, golden_iters, gox, goy, gcell,
             gnx, gny, ob_start, ob_items, ob_x, ob_y, ob_r, pri_v, pri_start, pri_rows):
    """For segments a→b (E, 3): within d_coll of a cylinder, sphere or prism, or inside a radar's range (as
    PlanningProblem.segment_blocked), visiting only the obstacles the broad phase finds within d_coll."""
    n_e = a.shape[0]
    out = np.zeros(n_e, dtype=np.bool_)
    n_cyl = cyl_x.shape[0]
    n_sph = sph_r.shape[0]
    cross = np.empty(max(prism_width(pri_start), 1))
    knots = np.empty(6)
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
            c = seg_point_2d(ax, ay, bx, by, cyl_x[k], cyl_y[k]) - cyl_r[k]
            if math.isfinite(cyl_top[k]) and c < d_coll:
                c = seg_cyl_finite(ax, ay, az, bx, by, bz, cyl_x[k], cyl_y[k], cyl_r[k], cyl_top[k], golden_iters)
            if c < d_coll:
                hit = True
                break
        if not hit:
            for q in range(n_near):
                k = near[q] - n_cyl
                if k < 0 or k >= n_sph:
                    continue
                if seg_point(ax, ay, az, bx, by, bz, sph_c[k, 0], sph_c[k, 1], sph_c[k, 2]) - sph_r[k] < d_coll:
                    hit = True
                    break
        if not hit:
            for q in range(n_near):
                k = near[q] - n_cyl - n_sph
                if k < 0:
                    continue
                f, h, keep, cx, cy, r = pri_rows[k, 0], pri_rows[k, 1], pri_rows[k, 2] > 0.0, pri_rows[k, 3], \
                    pri_rows[k, 4], pri_rows[k, 5]
                if not keep and seg_point_2d_sq(ax, ay, bx, by, cx, cy) > (r + reach) ** 2:
                    continue  # the disc itself is beyond reach
                c = seg_prism(ax, ay, az, bx, by, bz, pri_v, pri_start[k], pri_start[k + 1], f, h, keep, reach, cross,
                              knots)
                if c < d_coll:
                    hit = True
                    break
        if not hit:
            for k in range(rad_det.shape[0]):
                if seg_point(ax, ay, az, bx, by, bz, rad_c[k, 0], rad_c[k, 1], rad_c[k, 2]) < rad_det[k]:
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
                   k.ob_r, k.pri_v, k.pri_start, k.pri_rows)
    return got.reshape(shape[:-1])
