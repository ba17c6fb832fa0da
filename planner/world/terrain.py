"""Terrain as a regular DEM grid with vectorised bilinear lookup (docs/method.md §2.5)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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

    @property
    def max_height(self) -> float:
        return float(self.heights.max())

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
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
