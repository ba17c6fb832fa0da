"""The planning environment as arrays: bounds, altitude band, obstacles, terrain, dynamic threats (docs/method.md §2).

Every obstacle family is stored column-wise so the cost can broadcast over all obstacles at once.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from planner.world.polygons import counter_clockwise, enclosing_circle
from planner.world.terrain import Terrain

BOLTZMANN = 1.380649e-23  # J/K


def _frozen(a: object, shape_tail: tuple[int, ...] = ()) -> np.ndarray:
    arr = np.array(a, dtype=float).reshape((-1, *shape_tail))
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Cylinders:
    """Vertical no-fly cylinders from the ground to ``top`` (``inf`` = unlimited); ``z_ref`` is for drawing."""

    x: np.ndarray
    y: np.ndarray
    radius: np.ndarray
    top: np.ndarray
    z_ref: np.ndarray

    if TYPE_CHECKING:  # the columns are taken as any array-like and stored as read-only arrays (__post_init__)
        def __init__(self, x: ArrayLike, y: ArrayLike, radius: ArrayLike, top: ArrayLike, z_ref: ArrayLike) -> None:
            ...

    def __post_init__(self) -> None:
        for name in ("x", "y", "radius", "top", "z_ref"):
            object.__setattr__(self, name, _frozen(getattr(self, name)))

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def empty(cls) -> Cylinders:
        return cls([], [], [], [], [])


@dataclass(frozen=True, eq=False)
class Spheres:
    """Spherical (or, centred on the ground, hemispherical) no-fly zones: forbidden where ‖p − c‖ < R."""

    center: np.ndarray  # (k, 3)
    radius: np.ndarray  # (k,)

    if TYPE_CHECKING:  # as Cylinders
        def __init__(self, center: ArrayLike, radius: ArrayLike) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _frozen(self.center, (3,)))
        object.__setattr__(self, "radius", _frozen(self.radius))

    def __len__(self) -> int:
        return len(self.radius)

    @classmethod
    def empty(cls) -> Spheres:
        return cls(np.zeros((0, 3)), [])


@dataclass(frozen=True, eq=False)
class Prisms:
    """Vertical polygon prisms (docs/method.md §2.7): no-fly where the plan-view point is inside polygon k and
    ``floor[k] ≤ z ≤ ceiling[k]`` (heights above home; ``-inf`` from the ground, ``inf`` unlimited). A
    ``keep_in`` polygon (an inclusion fence) is the other way round: no-fly *outside* it, at every height (its
    floor and ceiling are ``-inf`` and ``inf``), so its plan-view signed distance changes sign.

    The polygons' vertices are packed, counter-clockwise, into ``vertices`` (V, 2): polygon k is
    ``vertices[start[k]:start[k + 1]]``, closed implicitly. ``cx``, ``cy``, ``r`` are a disc around each polygon
    (the broad phase's, as a cylinder's own disc is). Build with :meth:`from_polygons`.
    """

    vertices: np.ndarray  # (V, 2)
    start: np.ndarray  # (k + 1,) int
    floor: np.ndarray  # (k,)
    ceiling: np.ndarray  # (k,)
    keep_in: np.ndarray = None  # type: ignore[assignment]  # (k,) bool; None: none is (an array after __post_init__)
    cx: np.ndarray = field(init=False)
    cy: np.ndarray = field(init=False)
    r: np.ndarray = field(init=False)

    if TYPE_CHECKING:  # as Cylinders
        def __init__(self, vertices: ArrayLike, start: ArrayLike, floor: ArrayLike, ceiling: ArrayLike,
                     keep_in: ArrayLike | None = None) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "vertices", _frozen(self.vertices, (2,)))
        start = np.array(self.start, dtype=np.int64).reshape(-1)
        start.setflags(write=False)
        object.__setattr__(self, "start", start)
        object.__setattr__(self, "floor", _frozen(self.floor))
        object.__setattr__(self, "ceiling", _frozen(self.ceiling))
        keep_in = np.zeros(len(self), dtype=bool) if self.keep_in is None else np.array(self.keep_in, dtype=bool)
        keep_in = keep_in.reshape(-1)
        keep_in.setflags(write=False)
        object.__setattr__(self, "keep_in", keep_in)
        if not (np.all(np.isneginf(self.floor[keep_in])) and np.all(np.isposinf(self.ceiling[keep_in]))):
            raise ValueError("a keep-in polygon has no floor or ceiling (-inf, inf)")
        discs = [enclosing_circle(self.polygon(k)) for k in range(len(self))]
        for i, name in enumerate(("cx", "cy", "r")):
            object.__setattr__(self, name, _frozen([d[i] for d in discs]))

    def __len__(self) -> int:
        return len(self.start) - 1

    def polygon(self, k: int) -> np.ndarray:
        """Polygon k's vertices (V_k, 2), counter-clockwise."""
        return self.vertices[self.start[k]:self.start[k + 1]]

    def edges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every polygon's edges: their start points (E, 2), end points (E, 2) and the prism each belongs to (E,)."""
        ends = np.empty_like(self.vertices)
        for k in range(len(self)):
            i, j = self.start[k], self.start[k + 1]
            ends[i:j] = np.roll(self.vertices[i:j], -1, axis=0)
        owner = np.repeat(np.arange(len(self)), np.diff(self.start))
        return self.vertices, ends, owner

    @cached_property
    def padded(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every polygon's edges as rows of equal length (K, V_max): start x, y and end x, y. A shorter polygon is
        padded with zero-length edges at its first vertex, which cross nothing, count in no containment test and
        are never nearer than the polygon's own edges, so the rows can be reduced whole (vectorised over prisms)."""
        n = np.diff(self.start)
        width = int(n.max(initial=1))
        col = np.arange(width)
        i = np.where(col[None] < n[:, None], self.start[:-1, None] + col[None], self.start[:-1, None])
        j = np.where(col[None] + 1 < n[:, None], i + 1, self.start[:-1, None])
        v = self.vertices if len(self.vertices) else np.zeros((1, 2))
        i, j = np.minimum(i, len(v) - 1), np.minimum(j, len(v) - 1)
        out = (v[i, 0], v[i, 1], v[j, 0], v[j, 1])
        for a in out:
            a.setflags(write=False)
        return out

    @classmethod
    def from_polygons(cls, polygons: list[np.ndarray], floor: ArrayLike, ceiling: ArrayLike,
                      keep_in: ArrayLike | None = None) -> Prisms:
        """Prisms from simple polygons (each (V_k, 2), either orientation; a closing duplicate vertex is dropped)."""
        rings = [counter_clockwise(p) for p in polygons]
        start = np.concatenate([[0], np.cumsum([len(p) for p in rings], dtype=np.int64)])
        vertices = np.concatenate(rings) if rings else np.zeros((0, 2))
        return cls(vertices, start, floor, ceiling, keep_in)

    @classmethod
    def empty(cls) -> Prisms:
        return cls(np.zeros((0, 2)), [0], [], [])


def radar_detection_range(
    pt_w: float, gain: float, wavelength_m: float, rcs_m2: float, ts_k: float, bn_hz: float,
    loss: float, snr_threshold: float,
) -> float:
    """Range where SNR(R) = P_t G² λ² σ / ((4π)³ k T_s B_n L R⁴) equals the threshold (docs/method.md §2.4,
    paper Eq. (1))."""
    num = pt_w * gain**2 * wavelength_m**2 * rcs_m2
    den = (4 * math.pi) ** 3 * BOLTZMANN * ts_k * bn_hz * loss * snr_threshold
    return (num / den) ** 0.25


@dataclass(frozen=True, eq=False)
class Radars:
    """Radar sites: inside ``r_det`` a hard violation; outside a soft cost ``soft_weight · (r_det / R)⁴``.

    The soft term is paper Eq. (2)'s α / R⁴ with α = soft_weight · r_det⁴, so it equals ``soft_weight`` at
    the detection range and is unit-free (docs/method.md §4.5).
    """

    center: np.ndarray  # (k, 3)
    r_det: np.ndarray  # (k,)
    soft_weight: np.ndarray  # (k,)

    if TYPE_CHECKING:  # as Cylinders
        def __init__(self, center: ArrayLike, r_det: ArrayLike, soft_weight: ArrayLike) -> None: ...

    def __post_init__(self) -> None:
        object.__setattr__(self, "center", _frozen(self.center, (3,)))
        object.__setattr__(self, "r_det", _frozen(self.r_det))
        object.__setattr__(self, "soft_weight", _frozen(self.soft_weight))

    def __len__(self) -> int:
        return len(self.r_det)

    @classmethod
    def empty(cls) -> Radars:
        return cls(np.zeros((0, 3)), [], [])


LOITER, PATROL, TRACK = 0, 1, 2
THREAT_KINDS = {"loiter": LOITER, "patrol": PATROL, "track": TRACK}


@dataclass(frozen=True)
class Threat:
    """One dynamic threat: a sphere of ``radius`` moving on a known law (docs/method.md §2.6).

    loiter: ``p0`` = circle centre, ``circle_radius``, ``speed`` (m/s), ``phase`` (rad at t=0),
            ``direction`` +1 counter-clockwise / −1 clockwise.
    patrol: back and forth between ``p0`` and ``p1`` at ``speed``, starting at ``p0`` at t=0.
    track:  ``p0`` at time ``t_ref`` moving with velocity ``p1`` (m/s); radius grows by ``radius_growth``
            m per second of prediction.
    """

    id: str
    kind: str
    radius: float
    p0: tuple[float, float, float]
    p1: tuple[float, float, float] = (0.0, 0.0, 0.0)
    speed: float = 0.0
    circle_radius: float = 0.0
    phase: float = 0.0
    direction: float = 1.0
    t_ref: float = 0.0
    radius_growth: float = 0.0


@dataclass(frozen=True, eq=False)
class Threats:
    """All dynamic threats as arrays, so positions at many times are computed in one broadcast."""

    items: tuple[Threat, ...] = ()
    kind: np.ndarray = field(init=False)
    radius: np.ndarray = field(init=False)
    p0: np.ndarray = field(init=False)
    p1: np.ndarray = field(init=False)
    speed: np.ndarray = field(init=False)
    circle_radius: np.ndarray = field(init=False)
    phase: np.ndarray = field(init=False)
    direction: np.ndarray = field(init=False)
    t_ref: np.ndarray = field(init=False)
    radius_growth: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        it = self.items
        cols = {
            "kind": [THREAT_KINDS[t.kind] for t in it],
            "radius": [t.radius for t in it],
            "speed": [t.speed for t in it],
            "circle_radius": [t.circle_radius for t in it],
            "phase": [t.phase for t in it],
            "direction": [t.direction for t in it],
            "t_ref": [t.t_ref for t in it],
            "radius_growth": [t.radius_growth for t in it],
        }
        for name, values in cols.items():
            object.__setattr__(self, name, _frozen(values))
        object.__setattr__(self, "p0", _frozen([t.p0 for t in it], (3,)))
        object.__setattr__(self, "p1", _frozen([t.p1 for t in it], (3,)))

    def __len__(self) -> int:
        return len(self.items)

    @property
    def max_speed(self) -> float:
        """Fastest any threat moves (m/s); bounds how far one goes between two time samples."""
        if not len(self):
            return 0.0
        track = np.linalg.norm(self.p1, axis=-1)
        return float(np.max(np.where(self.kind == TRACK, track, self.speed)))

    def grown(self, margin_m: float) -> Threats:
        """The same threats with every radius larger by ``margin_m`` (a replan keeps its own margin from them)."""
        return Threats(tuple(dataclasses.replace(t, radius=t.radius + margin_m) for t in self.items))

    def positions(self, t: ArrayLike) -> np.ndarray:
        """Threat centres at times ``t`` (any shape S, seconds) → (k, *S, 3) metres ENU.

        Each law is computed only for the threats that follow it (one broadcast per kind, not per threat).
        """
        t = np.asarray(t, dtype=float)
        out = np.empty((len(self), *t.shape, 3))
        ex = (slice(None),) + (None,) * t.ndim  # broadcast threat axis over t's axes
        kind = self.kind
        i = np.flatnonzero(kind == LOITER)
        if i.size:
            r = self.circle_radius[i]
            omega = self.direction[i] * self.speed[i] / np.where(r > 0, r, 1.0)
            ang = self.phase[i][ex] + omega[ex] * t
            out[i, ..., 0] = self.p0[i, 0][ex] + r[ex] * np.cos(ang)
            out[i, ..., 1] = self.p0[i, 1][ex] + r[ex] * np.sin(ang)
            out[i, ..., 2] = self.p0[i, 2][ex]
        i = np.flatnonzero(kind == PATROL)
        if i.size:  # triangle wave along A→B
            ab = self.p1[i] - self.p0[i]
            length = np.linalg.norm(ab, axis=-1)
            safe_len = np.where(length > 0, length, 1.0)
            s = np.mod(self.speed[i][ex] * t, 2 * safe_len[ex])
            u = np.where(s <= safe_len[ex], s, 2 * safe_len[ex] - s)
            out[i] = self.p0[i][ex] + (ab / safe_len[:, None])[ex] * u[..., None]
        i = np.flatnonzero(kind == TRACK)
        if i.size:  # constant velocity from t_ref
            out[i] = self.p0[i][ex] + self.p1[i][ex] * (t - self.t_ref[i][ex])[..., None]
        return out

    def radii(self, t: ArrayLike) -> np.ndarray:
        """Threat radii at times ``t`` → (k, *S); track uncertainty grows with prediction time."""
        t = np.asarray(t, dtype=float)
        ex = (slice(None),) + (None,) * t.ndim
        grow = self.radius_growth[ex] * np.maximum(t - self.t_ref[ex], 0.0)
        return self.radius[ex] + np.where(self.kind[ex] == TRACK, grow, 0.0)


@dataclass(frozen=True, eq=False)
class Environment:
    """Everything static or scripted that a route must respect; ENU metres, origin at home (docs/method.md §1.1, §2)."""

    size_x: float  # bounds: x ∈ [0, size_x]
    size_y: float  # y ∈ [0, size_y]
    z_min: float  # altitude band above terrain
    z_max: float
    cylinders: Cylinders = field(default_factory=Cylinders.empty)
    spheres: Spheres = field(default_factory=Spheres.empty)
    radars: Radars = field(default_factory=Radars.empty)
    prisms: Prisms = field(default_factory=Prisms.empty)
    terrain: Terrain | None = None
    threats: Threats = field(default_factory=Threats)

    def ground(self, x: ArrayLike, y: ArrayLike) -> np.ndarray:
        """Ground height at (x, y); zero on flat terrain."""
        if self.terrain is None:
            return np.zeros(np.broadcast_shapes(np.shape(x), np.shape(y)))
        return self.terrain.height_at(x, y)

    def height_range(self, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Least and greatest height above the ground (E,) along straight segments a→b (E, 3), exactly
        (:meth:`Terrain.clearance_range`; on flat ground the ends' heights)."""
        a = np.asarray(a, dtype=float).reshape(-1, 3)
        b = np.asarray(b, dtype=float).reshape(-1, 3)
        if self.terrain is None:
            return np.minimum(a[:, 2], b[:, 2]), np.maximum(a[:, 2], b[:, 2])
        return self.terrain.clearance_range(a, b)

    def band_depth(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Metres (E,) by which straight segments a→b leave the altitude band at their worst point (≤ 0: inside),
        exactly over the terrain: the one band test of the roadmap, its guides and the checker."""
        lo, hi = self.height_range(a, b)
        return np.maximum(self.z_min - lo, hi - self.z_max)
