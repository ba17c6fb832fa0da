"""A time budget as one object (issue 34): by when a plan, or one phase of it, must be done.

A :class:`Deadline` is a number of seconds counted on one clock from when it was made. Without a budget it is
:meth:`Deadline.never`, whose seconds are infinite, so the same code runs with and without one: ``remaining()``
is then infinite, ``affords(step_s)`` always True and every ``share`` of it unbounded too. A plan hands a phase
either its deadline itself (the phase may use all that is left) or a :meth:`share` of what is left (a child that
ends no later than it); :meth:`minus` keeps a reserve for what runs after a phase (the plan's smoothing and
checks). Whether the *next iteration* of a search fits is :class:`planner.search.termination.WallClock`'s
prediction, made against a Deadline.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

Clock = Callable[[], float]  # seconds on a monotonic clock (time.perf_counter, or a test's fake)


@dataclass(frozen=True)
class Deadline:
    """``seconds`` of budget counted from ``start`` on ``clock`` (infinite: no budget)."""

    seconds: float
    start: float
    clock: Clock = time.perf_counter

    @classmethod
    def after(cls, seconds: float | None, clock: Clock = time.perf_counter) -> Deadline:
        """A budget of ``seconds`` starting now; None (or infinity) is no budget: :meth:`never`."""
        return cls(math.inf if seconds is None else float(seconds), clock(), clock)

    @classmethod
    def never(cls, clock: Clock = time.perf_counter) -> Deadline:
        """No budget: nothing is ever out of time (``clock`` still times the work, e.g. a result's ``time_s``)."""
        return cls(math.inf, clock(), clock)

    @property
    def bounded(self) -> bool:
        """True for a finite budget."""
        return math.isfinite(self.seconds)

    def elapsed(self) -> float:
        """Seconds since the start."""
        return self.clock() - self.start

    def remaining(self) -> float:
        """Seconds left (negative once overrun; infinite without a budget)."""
        return self.seconds - self.elapsed()

    def affords(self, step_s: float) -> bool:
        """True when ``step_s`` more seconds of work still end within the budget."""
        return self.elapsed() + step_s <= self.seconds

    def share(self, fraction: float) -> Deadline:
        """A deadline from now with ``fraction`` (at most 1) of what is left (nothing once overrun), so never later
        than this one; without a budget, this one (still unbounded)."""
        if not self.bounded:
            return self
        now = self.clock()
        return Deadline(min(fraction, 1.0) * max(self.seconds - (now - self.start), 0.0), now, self.clock)

    def minus(self, reserve_s: float) -> Deadline:
        """The same start with ``reserve_s`` fewer seconds (none left when the reserve is larger than the budget),
        for work that must still fit after the phase given it; without a budget, unbounded still."""
        return Deadline(max(self.seconds - reserve_s, 0.0), self.start, self.clock)


NEVER = Deadline.never()  # the default where no budget is given (its start is when this module was imported)
