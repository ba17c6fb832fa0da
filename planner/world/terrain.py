"""Terrain as a regular DEM grid with vectorised bilinear lookup (docs/method.md §2.5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


@dataclass(frozen=True, eq=False)
class Terrain:
    """Heights (m above home) on a regular grid.

    ``heights[j, i]`` is the ground height at ``x = x0 + i·dx``, ``y = y0 + j·dy`` (row j north-going).
    Points outside the grid take the nearest edge value.
    """

    x0: float
    y0: float
    dx: float
    dy: float
    heights: np.ndarray  # (ny, nx), metres

    def __post_init__(self) -> None:
        h = np.array(self.heights, dtype=float)
        if h.ndim != 2 or min(h.shape) < 2:
            raise ValueError("terrain grid must be 2-D with at least 2×2 samples")
        if not np.all(np.isfinite(h)):
            raise ValueError("terrain grid has non-finite heights")
        if self.dx <= 0 or self.dy <= 0:
            raise ValueError("terrain spacing must be positive")
        h.setflags(write=False)
        object.__setattr__(self, "heights", h)

    @property
    def max_slope(self) -> float:
        """Upper bound of |∇h| of the bilinear surface (rise per horizontal metre): per cell the
        gradient is a blend of its edge slopes, so the largest x and y edge slopes bound it."""
        gx = np.abs(np.diff(self.heights, axis=1)).max() / self.dx
        gy = np.abs(np.diff(self.heights, axis=0)).max() / self.dy
        return float(np.hypot(gx, gy))

    def slope_blocks(self, block: int) -> np.ndarray:
        """Upper bounds of |∇h| (nby, nbx) over blocks of ``block`` × ``block`` cells (block (J, I) holds cells
        j // block = J, i // block = I): per cell, the larger of its two x edge slopes and of its two y edge slopes,
        combined as :attr:`max_slope` is. A chord's ground departs from the line between its ends by at most the
        largest bound over the blocks under it times its horizontal length."""
        h = self.heights
        gx = np.abs(np.diff(h, axis=1)) / self.dx  # (ny, nx − 1): x edges
        gy = np.abs(np.diff(h, axis=0)) / self.dy  # (ny − 1, nx): y edges
        cell = np.hypot(np.maximum(gx[:-1], gx[1:]), np.maximum(gy[:, :-1], gy[:, 1:]))  # (ny − 1, nx − 1)
        ny, nx = cell.shape
        nby, nbx = -(-ny // block), -(-nx // block)
        padded = np.zeros((nby * block, nbx * block))
        padded[:ny, :nx] = cell
        return padded.reshape(nby, block, nbx, block).max(axis=(1, 3))

    @property
    def max_height(self) -> float:
        return float(self.heights.max())

    def height_at(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Bilinear ground height at points (x, y) of any matching shape → same shape, metres."""
        ny, nx = self.heights.shape
        fx = np.clip((np.asarray(x, dtype=float) - self.x0) / self.dx, 0.0, nx - 1.0)
        fy = np.clip((np.asarray(y, dtype=float) - self.y0) / self.dy, 0.0, ny - 1.0)
        i0 = np.minimum(fx.astype(np.intp), nx - 2)
        j0 = np.minimum(fy.astype(np.intp), ny - 2)
        tx = fx - i0
        ty = fy - j0
        h = self.heights
        h00 = h[j0, i0]
        h01 = h[j0, i0 + 1]
        h10 = h[j0 + 1, i0]
        h11 = h[j0 + 1, i0 + 1]
        return (h00 * (1 - tx) + h01 * tx) * (1 - ty) + (h10 * (1 - tx) + h11 * tx) * ty

    def clearance_range(self, a: np.ndarray, b: np.ndarray, chunk: int = 20_000) -> tuple[np.ndarray, np.ndarray]:
        """Least and greatest height above the ground (E,) along straight segments a→b (E, 3), exactly for the
        bilinear surface (docs/method.md §2.5): along a segment the ground is bilinear in each cell it crosses,
        so the height above it is a quadratic between two grid-line crossings, whose extremes are at the
        crossings or at its vertex. One test for the roadmap's edges, its guides and the checker's chords."""
        a = np.asarray(a, dtype=float).reshape(-1, 3)
        b = np.asarray(b, dtype=float).reshape(-1, 3)
        lo = np.empty(len(a))
        hi = np.empty(len(a))
        for s in range(0, len(a), chunk):  # bounded temporaries: (chunk, crossings) per array
            lo[s:s + chunk], hi[s:s + chunk] = self._clearance_range(a[s:s + chunk], b[s:s + chunk])
        return lo, hi

    def _clearance_range(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ny, nx = self.heights.shape
        cuts = [np.zeros((len(a), 1)), np.ones((len(a), 1))]
        for axis, origin, step, n in ((0, self.x0, self.dx, nx), (1, self.y0, self.dy, ny)):
            fa = np.clip((a[:, axis] - origin) / step, 0.0, n - 1.0)  # grid coordinates; outside, the edge value
            fb = np.clip((b[:, axis] - origin) / step, 0.0, n - 1.0)
            first = np.ceil(np.minimum(fa, fb))  # grid lines strictly inside or on the span, in grid units
            count = (np.floor(np.maximum(fa, fb)) - first + 1).clip(0).astype(np.intp)
            k = int(count.max(initial=0))
            if not k:
                continue
            line = first[:, None] + np.arange(k)  # (E, k), past ``count``: padding
            span = b[:, axis] - a[:, axis]
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (origin + line * step - a[:, axis, None]) / span[:, None]
            keep = (np.arange(k) < count[:, None]) & np.isfinite(t)
            cuts.append(np.where(keep, np.clip(t, 0.0, 1.0), 1.0))
        t = np.sort(np.concatenate(cuts, axis=1), axis=1)  # (E, m) breakpoints, 0 first and 1 last
        mid = 0.5 * (t[:, :-1] + t[:, 1:])

        def height(tt: np.ndarray) -> np.ndarray:
            p = a[:, None, :] + tt[..., None] * (b - a)[:, None, :]
            return p[..., 2] - self.height_at(p[..., 0], p[..., 1])

        f, fm = height(t), height(mid)
        f0, f1 = f[:, :-1], f[:, 1:]
        # the quadratic through (0, f0), (½, fm), (1, f1) on each piece: f0 + B s + A s²; its vertex if inside
        big_a = 2.0 * f0 - 4.0 * fm + 2.0 * f1
        big_b = -3.0 * f0 + 4.0 * fm - f1
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(np.abs(big_a) > 1e-12, -big_b / (2.0 * big_a), 0.0)
        s = np.clip(np.nan_to_num(s), 0.0, 1.0)
        vertex = f0 + big_b * s + big_a * s * s
        lo = np.minimum(f.min(axis=1), vertex.min(axis=1, initial=np.inf))
        hi = np.maximum(f.max(axis=1), vertex.max(axis=1, initial=-np.inf))
        return lo, hi
