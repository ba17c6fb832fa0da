"""A CPU hog for benches that measure deadlines under load (issue 16): busy processes beside the one measured.

On a 2-core companion computer the planner shares the machine with the MAVLink link, the replan worker and
whatever else the vehicle runs; a deadline that only holds on an idle machine is not a deadline. ``cpu_hog(n)``
starts ``n`` processes that spin until the block ends (pinned to ``cores`` when given and the OS allows it).
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from multiprocessing.synchronize import Event as EventType


def _spin(stop: EventType, core: int | None) -> None:
    if core is not None and hasattr(os, "sched_setaffinity"):
        try:
            os.sched_setaffinity(0, {core})
        except OSError:  # a core this process may not use: spin wherever the OS puts it
            pass
    x = 0
    while not stop.is_set():
        for _ in range(100_000):  # pure arithmetic: no syscalls between checks of the flag
            x = (x * 1103515245 + 12345) & 0x7FFFFFFF


@contextmanager
def cpu_hog(processes: int = 1, cores: Sequence[int] | None = None) -> Iterator[int]:
    """Keep ``processes`` busy-looping processes running for the block; yields how many run. ``cores[i]`` pins
    process i (e.g. the core the measured process is not on)."""
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    procs = [ctx.Process(target=_spin, args=(stop, None if not cores else cores[i % len(cores)]), daemon=True)
             for i in range(processes)]
    for p in procs:
        p.start()
    try:
        yield len(procs)
    finally:
        stop.set()
        for p in procs:
            p.join(timeout=2.0)
            if p.is_alive():
                p.kill()
