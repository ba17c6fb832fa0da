"""The CPU hog really loads the machine and stops when its block ends."""

import os
import time

from planner.bench.load import cpu_hog


def _cpu_seconds_of_children() -> float:
    t = os.times()
    return t.children_user + t.children_system


def test_cpu_hog_spins_for_its_block_and_stops():
    before = _cpu_seconds_of_children()
    with cpu_hog(1) as n:
        assert n == 1
        wall0 = time.monotonic()
        time.sleep(0.6)
        wall = time.monotonic() - wall0
    # the child's CPU time is reported once it has been joined: it must have spun most of the block
    assert _cpu_seconds_of_children() - before >= 0.5 * wall
