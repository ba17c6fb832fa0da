"""The swarm's own per-iteration work, compiled: spherical particles decoded to paths, and the PSO update."""

from __future__ import annotations

import numpy as np

from planner.kernel.fastmath import fast_sincos
from planner.kernel.jit import jit


@jit
def _decode_spherical(x, start, goal):
    """Paths (P, n + 2, 3) from spherical particles (P, n, 3), as geometry.spherical_to_cartesian + start/goal:
    the steps summed in order from the start (the reference's cumsum, then start + sum). Sines and cosines are
    fast_sincos's, particles innermost so that they run in SIMD lanes."""
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
            s_psi, c_psi = fast_sincos(xt[1, k, p])
            s_phi, c_phi = fast_sincos(xt[2, k, p])
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


@jit
def _pso_step(x, v, pbest, gbest, w, c1, c2, lo, hi, vmax, reflection, r1, r2):
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

    def flat(a: np.ndarray | float) -> np.ndarray:
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
