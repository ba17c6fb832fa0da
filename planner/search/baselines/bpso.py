"""Binary PSO (Kennedy & Eberhart 1997) over a lattice of waypoint choices: a baseline of the fusion
comparison.

Lattice (:class:`Lattice`). Waypoint k = 1…n sits on the straight S→G line at along-track fraction
k / (n + 1); its bits choose where it moves off that point:

* ``bits_cross`` bits pick one of C = 2^bits_cross cross-track offsets, evenly spaced over
  ±corridor_frac·‖SG‖ along the horizontal unit normal of S→G (the horizontal direction of S→G turned
  +90°; the x axis if S and G are stacked vertically). The resulting (x, y) is clipped into the region.
* ``bits_alt`` bits pick one of A = 2^bits_alt heights, evenly spaced over the altitude band
  [z_min, z_max], above the ground at that (clipped) (x, y) (``env.ground``).

A particle is an array (n, bits_cross + bits_alt) of 0/1 floats: per waypoint the cross-track bits, then
the altitude bits, most significant first. Each group is a **reflected Gray code**: neighbouring lattice
cells differ in one bit, so the small moves a converging swarm makes are one flip away (plain binary has
Hamming cliffs, e.g. 01111 → 10000 needs five flips to move one cell). So all-zero bits are cell 0 (the
−corridor, z_min corner) and the far corner C − 1 / A − 1 is the Gray word 100…0, not 111…1.
Warm-start paths are encoded to the nearest lattice cell per waypoint (Euclidean, over all C·A cells).

Update per bit: v ← w v + c1 r1 (pbest − x) + c2 r2 (gbest − x), |v| ≤ v_max; bit = 1 if U(0, 1) <
sigmoid(v). w is fixed at the shared w0 (1.0, the 1997 algorithm has no inertia): with the damped
schedule v would decay to 0, where sigmoid(0) = ½ turns a converged swarm back into random bits.
c1, c2 and the budget come from :class:`SPSOConfig`; the lattice and v_max from :class:`BPSOConfig`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search.spso import pso_velocity
from planner.search.swarm import OptimiserResult, SwarmState, initial_swarm, run_swarm
from planner.world.config import BPSOConfig, SPSOConfig


def gray_to_index(bits: np.ndarray) -> np.ndarray:
    """Gray-coded bits (…, B), most significant first → integer index (…)."""
    binary = np.cumsum(bits.astype(np.int64), axis=-1) % 2  # b_i = g_0 xor … xor g_i
    weights = 1 << np.arange(bits.shape[-1] - 1, -1, -1, dtype=np.int64)
    return binary @ weights


def index_to_gray(index: np.ndarray, n_bits: int) -> np.ndarray:
    """Integer index (…) → Gray-coded bits (…, n_bits) as 0/1 floats, most significant first."""
    index = np.asarray(index, dtype=np.int64)
    gray = index ^ (index >> 1)
    shifts = np.arange(n_bits - 1, -1, -1, dtype=np.int64)
    return ((gray[..., None] >> shifts) & 1).astype(float)


@dataclass(frozen=True, eq=False)
class Lattice:
    """Waypoint cells ``cells`` (n, C, A, 3) ENU metres and the bit ↔ path maps (module docstring)."""

    start: np.ndarray
    goal: np.ndarray
    cells: np.ndarray  # (n, C, A, 3)
    bits_cross: int
    bits_alt: int

    @property
    def n(self) -> int:
        return self.cells.shape[0]

    @property
    def n_bits(self) -> int:
        return self.bits_cross + self.bits_alt

    @property
    def lo(self) -> np.ndarray:
        return np.zeros((self.n, self.n_bits))

    @property
    def hi(self) -> np.ndarray:
        return np.ones((self.n, self.n_bits))

    def decode_bits(self, bits: np.ndarray) -> np.ndarray:
        """Bits (P, n, bits_cross + bits_alt) → paths (P, n + 2, 3) including start and goal."""
        ic = gray_to_index(bits[..., : self.bits_cross])  # (P, n)
        ia = gray_to_index(bits[..., self.bits_cross :])
        pts = self.cells[np.arange(self.n), ic, ia]  # (P, n, 3)
        p = len(bits)
        s = np.broadcast_to(self.start, (p, 1, 3))
        g = np.broadcast_to(self.goal, (p, 1, 3))
        return np.concatenate([s, pts, g], axis=1)

    decode = decode_bits  # the name the shared swarm loop uses

    def encode(self, paths: np.ndarray) -> np.ndarray:
        """Paths (k, n + 2, 3) → bits (k, n, B) of the nearest cell to each interior waypoint."""
        inner = np.asarray(paths, dtype=float)[:, 1:-1]  # (k, n, 3)
        n, c, a, _ = self.cells.shape
        flat = self.cells.reshape(n, c * a, 3)
        d2 = np.sum((inner[:, :, None, :] - flat[None]) ** 2, axis=-1)  # (k, n, C·A)
        ic, ia = np.divmod(np.argmin(d2, axis=-1), a)
        return np.concatenate([index_to_gray(ic, self.bits_cross), index_to_gray(ia, self.bits_alt)], axis=-1)

    def sample(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """Uniformly random bits (count, n, B)."""
        return rng.integers(0, 2, (count, self.n, self.n_bits)).astype(float)


def make_lattice(problem: PlanningProblem, n_waypoints: int, cfg: BPSOConfig) -> Lattice:
    """The lattice of the module docstring for ``problem``."""
    env = problem.env
    s, g = problem.start, problem.goal
    horiz = (g - s)[:2]
    norm = float(np.hypot(*horiz))
    normal = np.array([-horiz[1], horiz[0]]) / norm if norm > 0 else np.array([1.0, 0.0])
    frac = np.arange(1, n_waypoints + 1) / (n_waypoints + 1)
    base = s[:2] + frac[:, None] * horiz  # (n, 2)
    half = cfg.corridor_frac * problem.direct_distance
    offsets = np.linspace(-half, half, 2**cfg.bits_cross)
    xy = base[:, None, :] + offsets[None, :, None] * normal  # (n, C, 2)
    xy = np.clip(xy, 0.0, [env.size_x, env.size_y])
    ground = env.ground(xy[..., 0], xy[..., 1])  # (n, C)
    heights = np.linspace(env.z_min, env.z_max, 2**cfg.bits_alt)
    z = ground[..., None] + heights  # (n, C, A)
    xy = np.broadcast_to(xy[:, :, None, :], (*z.shape, 2))
    cells = np.concatenate([xy, z[..., None]], axis=-1)
    return Lattice(s, g, cells, cfg.bits_cross, cfg.bits_alt)


def sigmoid(v: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-v))


def bpso_step(
    x: np.ndarray, v: np.ndarray, pbest: np.ndarray, gbest: np.ndarray, w: float, c1: float, c2: float,
    v_max: float, r1: np.ndarray, r2: np.ndarray, u: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """One binary PSO update. Shapes: x, v, pbest, r1, r2, u (P, n, B); gbest (n, B). Bits are 0/1 floats."""
    v = pso_velocity(x, v, pbest, gbest, w, c1, c2, v_max, r1, r2)
    return (u < sigmoid(v)).astype(float), v


class BPSO:
    """Binary PSO on the waypoint lattice with the shared Table 6 budget."""

    def __init__(self, pso: SPSOConfig, cfg: BPSOConfig | None = None) -> None:
        self.pso = pso
        self.cfg = cfg or BPSOConfig()

    def lattice(self, problem: PlanningProblem) -> Lattice:
        return make_lattice(problem, self.pso.n_waypoints, self.cfg)

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> OptimiserResult:
        """Optimise; ``initial_paths`` (k, n + 2, 3) replace the first k random particles (nearest cells)."""
        pso, cfg = self.pso, self.cfg
        lat = self.lattice(problem)
        x0 = initial_swarm(lat, rng, pso.n_pop, initial_paths)

        def step(it: int, st: SwarmState) -> np.ndarray:
            shape = st.x.shape
            r1 = rng.random(shape)
            r2 = rng.random(shape)
            u = rng.random(shape)
            st.w = pso.w0
            v = st.v
            assert v is not None  # run_swarm gives the swarm its velocities (v0)
            x, st.v = bpso_step(st.x, v, st.pbest_x, st.gbest_x, st.w, pso.c1, pso.c2, cfg.v_max,
                                r1, r2, u)
            return x

        return run_swarm("bpso", problem, pso, lat, x0, step, deadline, progress, v0=np.zeros_like(x0))
