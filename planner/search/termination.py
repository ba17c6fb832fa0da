"""Stop / switch criteria for swarm optimisers (docs/method.md §7, paper Algorithm 1), as small composable objects."""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from typing import Protocol

from planner.deadline import Deadline


@dataclass
class Progress:
    """What a criterion may look at after each iteration."""

    iteration: int  # iterations completed
    best_cost: float
    stagnant_iters: int  # iterations since gbest last improved
    diversity: float  # normalised swarm diversity σ²(t)
    elapsed_s: float
    feasible_iters: int = 0  # iterations since gbest became feasible (0: it is not)


class Criterion(Protocol):
    @property
    def name(self) -> str: ...  # read-only: the criteria are frozen dataclasses

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
class Settled:
    """gbest feasible for ``iters`` iterations (0 disables): a search that needs a safe route, not the best one."""

    iters: int
    name: str = "feasible"

    def done(self, p: Progress) -> bool:
        return self.iters > 0 and p.feasible_iters >= self.iters


@dataclass(frozen=True)
class Diversity:
    """Swarm diversity σ²(t) = mean ‖x_i − x̄‖² (normalised coordinates) below a floor; 0 disables."""

    minimum: float
    name: str = "diversity"

    def done(self, p: Progress) -> bool:
        return self.minimum > 0 and p.diversity < self.minimum


@dataclass
class WallClock:
    """Stops a search *before* an iteration that would overrun its :class:`~planner.deadline.Deadline` (issue
    16); firing it means status timeout/approximate.

    The loop calls :meth:`lap` at the end of every iteration (and once after its set-up, e.g. the initial
    evaluation, which is a fair first guess at an iteration's cost). :meth:`done` fires when the deadline does not
    afford the predicted duration of the next iteration (what must still run after the search, the plan's
    decoding, smoothing and final checks, is kept out of the deadline with :meth:`Deadline.minus`). The prediction
    is the *maximum of the last* ``window`` *laps*: on a shared machine an iteration is slowed now and then by
    preemption, a cache flush or the garbage collector, and such bursts come in runs, so the recent maximum covers
    them where a mean or a median would not; an upper quantile needs more samples than a 0.15 s search has. A
    single slow lap costs at most ``window`` iterations of conservatism and then ages out, so one spike does not
    end the search for good. With no lap yet the prediction is ``first_s``: a prior the caller measured (the time
    of one evaluation, say), 0 if it has none. Without a budget (:meth:`Deadline.never`) it never fires.

    Laps are timed on the deadline's clock from when the criterion is made.
    """

    deadline: Deadline
    window: int = 8
    first_s: float = 0.0
    name: str = "timeout"
    _last: float = field(init=False)
    _laps: deque[float] = field(init=False)

    def __post_init__(self) -> None:
        self._last = self.deadline.clock()
        self._laps = deque(maxlen=self.window)

    def lap(self) -> None:
        """Record the time since the previous lap (or since the start) as one iteration's duration."""
        now = self.deadline.clock()
        self._laps.append(now - self._last)
        self._last = now

    def restart_lap(self) -> None:
        """Start timing the next iteration from now (work since the last lap was not an iteration)."""
        self._last = self.deadline.clock()

    def predicted_s(self) -> float:
        """Predicted duration of the next iteration: the longest of the last ``window`` laps."""
        return max(self._laps, default=self.first_s)

    def affords(self, seconds: float) -> bool:
        """True when ``seconds`` more of work still ends within the deadline."""
        return self.deadline.affords(seconds)

    def done(self, p: Progress | None = None) -> bool:
        return not self.affords(self.predicted_s())


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

