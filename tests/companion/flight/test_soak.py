"""Soak (issue 7): 5 consecutive missions on the simulated autopilot with random seeds and packet-loss rates, in
one process, with no leaked tasks or sockets and bounded memory growth. Each mission is the planned route's first
legs (take-off, climb-out, three waypoints): what leaks or grows is per connection, upload and flight, not per
kilometre flown. Marked slow; it runs in CI while it stays well under a minute (20 missions took 106-114 s by
2026-12, 12 took 80 s on 2026-12-02, 8 took 56-58 s, 6 took 30-37 s, the lossy ones waiting out the protocol's
wall-clock timeouts, so it flies 5 with up to 20 % loss since the suite neared CI's 25 minutes; 30 % loss is
test_faults' full flight, and every other companion test checks its own leaks of tasks, threads and sockets)."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import numpy as np
import pytest
from processes import rss_kib

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import mission_from_plan_json
from companion.mission.events import EventLog
from companion.sim import SimAutopilot
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
FLIGHTS = 5
LEGS = 4  # route points flown per mission: the start and three more (the last one as the goal)


def _sockets() -> int:
    n = 0
    for fd in os.listdir("/proc/self/fd"):
        try:
            n += os.readlink(f"/proc/self/fd/{fd}").startswith("socket:")
        except OSError:
            continue
    return n


@pytest.mark.slow
def test_five_missions_in_a_row_without_leaks(static_plan_doc) -> None:
    doc = static_plan_doc()
    doc["waypoints"] = doc["waypoints"][:LEGS]
    sc = load_scenario(STATIC)
    rng = np.random.default_rng(2026)
    sockets0 = _sockets()
    rss: list[float] = []

    async def one(seed: int, loss: float) -> bool:
        async with SimAutopilot(sc, "udpin:127.0.0.1:0", speedup=20.0, loss=loss, seed=seed) as sim:
            async with Link(f"udpout:127.0.0.1:{sim.port}", open_timeout=5.0) as link:
                await link.wait_heartbeat(10.0)
                items = mission_from_plan_json(doc, sc, "ardupilot")
                sup = FlightSupervisor(link, MissionClient(link), EventLog(), arm=True)
                out = await sup.fly(items, (), ready_timeout=30.0, flight_timeout=120.0)
        me = asyncio.current_task()
        assert not [t for t in asyncio.all_tasks() if t is not me and not t.done()]
        return out.completed

    completed = 0
    for k in range(FLIGHTS):
        seed, loss = int(rng.integers(1 << 30)), float(rng.uniform(0.0, 0.2))
        completed += asyncio.run(one(seed, loss))
        assert _sockets() <= sockets0, f"flight {k}: sockets left open"
        rss.append((rss_kib(os.getpid()) or 0) / 1024)
    assert completed == FLIGHTS
    growth = rss[-1] - rss[2]  # after the first flights have warmed caches and allocator pools
    assert growth < 12.0, f"memory grew {growth:.1f} MB over {FLIGHTS - 3} flights: {np.round(rss, 1)}"
