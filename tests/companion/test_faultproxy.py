"""The fault-injecting UDP proxy (issue 7 groundwork): real datagrams on 127.0.0.1."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest

from companion.builder import build_mission, MissionSpec
from companion.faultproxy import FaultProxy, Faults
from companion.events import EventLog
from companion.link import Link
from companion.protocol import MissionClient
from companion.sim import SimAutopilot
from companion.supervisor import FlightSupervisor
from planner.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


class _Echo(asyncio.DatagramProtocol):
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.transport.sendto(b"echo:" + data, addr)


class _Collect(asyncio.DatagramProtocol):
    def __init__(self) -> None:
        self.got: list[bytes] = []

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self.got.append(data)


async def _exchange(faults: Faults, seed: int, n: int = 400, outage: float = 0.0) -> tuple[list[bytes], object]:
    loop = asyncio.get_running_loop()
    echo_t, _ = await loop.create_datagram_endpoint(_Echo, local_addr=("127.0.0.1", 0))
    target = echo_t.get_extra_info("sockname")[:2]
    async with FaultProxy(target, faults, seed=seed) as proxy:
        client_t, client = await loop.create_datagram_endpoint(_Collect, remote_addr=("127.0.0.1", proxy.port))
        if outage:
            proxy.outage(outage)
        for i in range(n):
            client_t.sendto(f"{i:04d}".encode())
            await asyncio.sleep(0.0005)
        await asyncio.sleep(0.1)
        client_t.close()
    echo_t.close()
    return client.got, proxy.counters


def test_clean_proxy_forwards_everything_both_ways_in_order() -> None:
    got, c = asyncio.run(_exchange(Faults(), seed=0, n=100))
    assert got == [f"echo:{i:04d}".encode() for i in range(100)]
    assert c.forwarded == 200 and c.dropped == 0


def test_faults_happen_at_their_rates_and_repeat_with_the_seed() -> None:
    faults = Faults(drop=0.3, duplicate=0.1, reorder=0.1)
    got, c = asyncio.run(_exchange(faults, seed=7))
    # each echo crosses the proxy twice: both legs must survive, ≈ 0.7² of 400 (binomial sd ≈ 10)
    unique = {g for g in got}
    assert 140 < len(unique) < 250
    assert len(got) > len(unique)  # duplicates arrived
    order = [int(g[5:]) for g in got]
    assert order != sorted(order)  # and out of order
    assert c.dropped > 0 and c.duplicated > 0 and c.reordered > 0
    again, c2 = asyncio.run(_exchange(faults, seed=7))
    assert (c2.dropped, c2.duplicated, c2.reordered) == (c.dropped, c.duplicated, c.reordered)


def test_outage_drops_everything_for_its_duration() -> None:
    got, c = asyncio.run(_exchange(Faults(), seed=0, n=50, outage=60.0))
    assert got == [] and c.dropped == 50


def test_corruption_is_caught_by_mavlink_crc() -> None:
    """Corrupted datagrams reach the other side but fail MAVLink's checksum (they are dropped, never taken for
    data): the verified pre-flight upload still ends with the right mission stored."""
    sc = load_scenario(ROOT / "sitl_scenarios" / "rescue_static.toml")
    items = build_mission([[200.0, 200, 50], [500, 600, 80], [800, 800, 50]], MissionSpec("ardupilot", sc.vehicle,
                                                                                          sc.home))

    async def go() -> object:
        async with SimAutopilot(sc, "udpin:127.0.0.1:0", speedup=5.0) as sim:
            async with FaultProxy(("127.0.0.1", sim.port), Faults(corrupt=0.2, duplicate=0.1, reorder=0.1),
                                  seed=2) as proxy:
                async with Link(f"udpout:127.0.0.1:{proxy.port}", open_timeout=5.0) as link:
                    await link.wait_heartbeat(10.0)
                    # the supervisor's pre-flight upload: redone when the link breaks a transfer
                    await FlightSupervisor(link, MissionClient(link), EventLog(), arm=False).upload(items)
                    return proxy.counters, sim.mission

    counters, stored = asyncio.run(go())
    assert counters.corrupted > 0
    assert len(stored) == len(items)


@pytest.mark.parametrize("bad", [{"drop": 1.0}, {"corrupt": -0.1}, {"delay_s": -1.0}])
def test_bad_fault_settings_are_refused(bad: dict) -> None:
    with pytest.raises(ValueError):
        Faults(**bad)
