"""The leak check of the test fixtures (pymodbus' test/conftest.py does the same): what a test left behind of
asyncio tasks, threads and sockets of this process, given what there was before it."""

from __future__ import annotations

import asyncio
import os
import threading
import time
from dataclasses import dataclass

import pytest

GRACE_STEPS, GRACE_STEP_S = 40, 0.05  # 2 s for things that are already closing


def socket_fds() -> set[str]:
    """This process's open sockets, as ``fd->socket:[inode]``."""
    found = set()
    for fd in os.listdir("/proc/self/fd"):
        try:
            target = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:"):
            found.add(f"{fd}->{target}")
    return found


def _tasks() -> set[asyncio.Task]:
    me = asyncio.current_task()
    return {t for t in asyncio.all_tasks() if t is not me and not t.done()}


@dataclass(frozen=True)
class Snapshot:
    """What exists now; ``with_tasks`` only inside a running event loop."""

    tasks: frozenset
    threads: frozenset
    sockets: frozenset
    with_tasks: bool

    @classmethod
    def take(cls, with_tasks: bool = True) -> Snapshot:
        return cls(frozenset(_tasks() if with_tasks else ()), frozenset(threading.enumerate()),
                   frozenset(socket_fds()), with_tasks)

    def leftovers(self) -> str | None:
        """What exists now and did not then, in words, or None."""
        tasks = (_tasks() - self.tasks) if self.with_tasks else set()
        threads = {t for t in threading.enumerate() if t.is_alive()} - self.threads
        sockets = socket_fds() - self.sockets
        problems = [f"tasks: {sorted(t.get_name() for t in tasks)}"] if tasks else []
        problems += [f"threads: {sorted(t.name for t in threads)}"] if threads else []
        problems += [f"sockets: {sorted(sockets)}"] if sockets else []
        return "; ".join(problems) or None


async def fail_on_leaks(before: Snapshot) -> None:
    """In a running loop: fail the test if anything new is still there after the grace period."""
    for _ in range(GRACE_STEPS):
        if (left := before.leftovers()) is None:
            return
        await asyncio.sleep(GRACE_STEP_S)
    pytest.fail(f"test leaked {left}")


def fail_on_leaks_sync(before: Snapshot) -> None:
    """Without a loop (threads and sockets only): as :func:`fail_on_leaks`."""
    for _ in range(GRACE_STEPS):
        if (left := before.leftovers()) is None:
            return
        time.sleep(GRACE_STEP_S)
    pytest.fail(f"test leaked {left}")
