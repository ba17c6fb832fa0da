"""The cost J of docs/method.md §4–§5 as compiled loops over segment × obstacle × particle (numba).

The numpy implementation in :mod:`planner.problem` is the reference; this kernel computes the same terms,
penalties and violation counts without the numpy temporaries that dominate small swarms (a replan's swarm of
100 × 9 segments spends most of its time in array set-up, not arithmetic). ``FUSEPLAN_KERNEL=numpy`` picks the
reference; without numba installed the reference is used. tests/planner/test_kernel.py holds the two to 1e-9.

By what each module computes, bottom up: :mod:`~planner.kernel.jit` (how functions are compiled),
:mod:`~planner.kernel.fastmath` (branch-free arctangent, sine and cosine, Bézier ranges, the peak factor),
:mod:`~planner.kernel.swarm` (decoding particles, the PSO update), :mod:`~planner.kernel.inputs` (the environment
variables, a problem's typed :class:`KernelInputs`, warm_up), :mod:`~planner.kernel.segments` (segment distances,
the broad phase's grid lookup, segment_blocked) and :mod:`~planner.kernel.cost` (the cost and its terms).
"""

from planner.kernel.cost import evaluate
from planner.kernel.inputs import (
    BROAD_ENV_VAR,
    ENV_VAR,
    GRID_CELLS,
    GRID_MIN_OBSTACLES,
    KERNELS,
    KernelInputs,
    ObstacleGrid,
    broad_phase,
    chosen,
    warm_up,
)
from planner.kernel.jit import njit
from planner.kernel.segments import segment_blocked
from planner.kernel.swarm import decode_spherical, pso_step

__all__ = [
    "BROAD_ENV_VAR", "ENV_VAR", "GRID_CELLS", "GRID_MIN_OBSTACLES", "KERNELS", "KernelInputs", "ObstacleGrid",
    "broad_phase", "chosen", "decode_spherical", "evaluate", "njit", "pso_step", "segment_blocked", "warm_up",
]
