"""The replanner's planner process (docs/design.md, "Live replanning"): a planner in its own process, started
and warmed before it is needed, so that a replan neither waits for imports and compilation nor slows the
companion's event loop (and an in-process simulator) while it searches."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

import numpy as np

from planner import kernel
from planner.deadline import Deadline
from planner.legs import plan_through
from planner.world.scenario import Scenario

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class WorkerPlan:
    """What a replan sends back from the worker process (small: no swarm, no trajectory)."""

    status: str
    waypoints: np.ndarray
    violations: dict[str, int]
    optimiser_s: float


def _plan_job(problem: Any, settings: Any, seed: list[int], initial: np.ndarray | None, budget_s: float,
              vias: np.ndarray | None = None) -> WorkerPlan:
    """One replan in the worker process, through ``vias`` (k, 3) when given (``initial``: the first leg's seeds)."""
    # the deadline starts here, in the worker process, when the job does
    result = plan_through(problem, np.zeros((0, 3)) if vias is None else vias, settings, np.random.default_rng(seed),
                          Deadline.after(budget_s), initial_paths=initial)
    violations = {k: int(v[0]) for k, v in result.evaluation.violations.items() if int(v[0])}
    return WorkerPlan(result.status.value, np.asarray(result.waypoints), violations, result.optimiser.time_s)


def _warm_up(problem: Any, settings: Any) -> None:
    """Import, allocate and run every code path once in the worker, before the first real replan."""
    from planner.search.alloc import tune_allocator

    tune_allocator()
    if problem is not None:
        kernel.warm_up(problem)  # every compiled function, even those a short plan would not reach
        _plan_job(problem, settings, [0], None, 0.03)


def expects_traffic(scenario: Scenario, rate: float | None) -> bool:
    """True when a flight may meet moving threats, so its planner process is started and warmed before take-off:
    the scenario has threats or intruders, or the autopilot is real (``rate`` None), which may relay ADS-B
    traffic whatever the scenario says."""
    return bool(len(scenario.environment.threats) or scenario.intruders or rate is None)


class PlanWorker:
    """A planner in its own process: the companion's event loop (and an in-process simulator) keep running at
    full speed while it plans, and the planner gets a whole core for its budget. ``problem`` and
    ``settings`` (optional) are planned once, briefly, to warm the worker up."""

    def __init__(self, problem: Any = None, settings: Any = None) -> None:
        self._pool: ProcessPoolExecutor | None = ProcessPoolExecutor(
            max_workers=1, mp_context=multiprocessing.get_context("spawn"))
        self._warm: asyncio.Future[None]
        self.warm(problem, settings)
        self._overhead_s = 0.035  # running estimate: wall time of a job beyond its optimiser's search

    def warm(self, problem: Any, settings: Any) -> None:
        """Queue a warm-up on ``problem`` (None: the process start and imports alone) behind what was queued
        before: a worker started before the route was known is warmed on it later."""
        if self._pool is None:
            return
        try:
            self._warm = asyncio.get_running_loop().run_in_executor(self._pool, _warm_up, problem, settings)
        except BrokenProcessPool:
            return  # the first warm-up's future already says so; plan() falls back to a thread
        self._warm.add_done_callback(lambda f: f.cancelled() or f.exception())  # no "never retrieved" noise

    async def ready(self) -> float:
        """Wait for the warm-up (process start, imports, a first short plan); returns the seconds waited. A
        process that failed to start is left to :meth:`plan`, which then plans in a thread."""
        t0 = time.monotonic()
        if self._pool is not None:
            with contextlib.suppress(Exception):
                await asyncio.shield(self._warm)
        return time.monotonic() - t0

    async def plan(self, problem: Any, settings: Any, seed: list[int], initial: np.ndarray,
                   budget_s: float, vias: np.ndarray | None = None) -> WorkerPlan:
        """Plan within ``budget_s`` of wall time in all, through ``vias`` when given (planner.legs): the search gets
        what the smoothing, the checks and the hand-over to and from the process (measured on earlier jobs) leave of
        it. If the process cannot be started or has died, plans in a thread instead (slower: it shares the
        interpreter)."""
        loop = asyncio.get_running_loop()
        t0 = time.monotonic()
        search = max(budget_s - self._overhead_s, 0.2 * budget_s)
        args = (problem, settings, seed, initial, search, vias)
        if self._pool is not None:
            try:
                await self._warm
                out = await loop.run_in_executor(self._pool, _plan_job, *args)
            except BrokenProcessPool as e:
                log.warning("planner process failed (%s); planning in a thread from now on", e)
                self._pool.shutdown(wait=False, cancel_futures=True)
                self._pool = None
        if self._pool is None:
            out = await asyncio.to_thread(_plan_job, *args)
        self._overhead_s = 0.5 * self._overhead_s + 0.5 * max(time.monotonic() - t0 - out.optimiser_s, 0.0)
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
