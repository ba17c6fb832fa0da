"""Stop / switch criteria for swarm optimisers (docs/method.md §7, paper Algorithm 1), as small composable objects."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Protocol


@dataclass
class Progress:
    """What a criterion may look at after each iteration."""

    iteration: int  # iterations completed
    best_cost: float
    stagnant_iters: int  # iterations since gbest last improved
    diversity: float  # normalised swarm diversity σ²(t)
    elapsed_s: float


class Criterion(Protocol):
    name: str

    def done(self, p: Progress) -> bool: ...


@dataclass(frozen=True)
class MaxIterations:
    max_iter: int
    name: str = "max_iterations"

    def done(self, p: Progress) -> bool:
        return p.iteration >= self.max_iter


@dataclass(frozen=True)
class Stagnation:
    """No gbest improvement for Δ_stag iterations."""

    iters: int
    name: str = "stagnation"

    def done(self, p: Progress) -> bool:
        return p.stagnant_iters >= self.iters


@dataclass(frozen=True)
class Diversity:
    """Swarm diversity σ²(t) = mean ‖x_i − x̄‖² (normalised coordinates) below a floor; 0 disables."""

    minimum: float
    name: str = "diversity"

    def done(self, p: Progress) -> bool:
        return self.minimum > 0 and p.diversity < self.minimum


@dataclass(frozen=True)
class WallClock:
    """Planning budget in seconds (replanning); firing it means status timeout/approximate."""

    budget_s: float
    name: str = "timeout"

    def done(self, p: Progress) -> bool:
        return p.elapsed_s >= self.budget_s


@dataclass
class AnyOf:
    """Stops when any criterion fires; remembers which."""

    criteria: list[Criterion] = field(default_factory=list)
    fired: str | None = None
    _t0: float = field(default_factory=time.perf_counter)

    def elapsed(self) -> float:
        return time.perf_counter() - self._t0

    def done(self, p: Progress) -> bool:
        for c in self.criteria:
            if c.done(p):
                self.fired = c.name
                return True
        return False
