"""The fault-injecting UDP proxy (issue 7 groundwork): real datagrams on 127.0.0.1; and the TCP outage forwarder,
real TCP connections on 127.0.0.1."""

from __future__ import annotations

import asyncio
import socket
from pathlib import Path

import pytest

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import MissionSpec, build_mission
from companion.mission.events import EventLog
from companion.sim import SimAutopilot
from companion.sim.faultproxy import FaultProxy, Faults, TcpOutageProxy
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]


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


class _TcpEcho:
    """A TCP echo server on 127.0.0.1 that records its connections and whether each saw EOF."""

    def __init__(self) -> None:
        self.connections: list[dict] = []
        self.server: asyncio.Server | None = None

    async def __aenter__(self) -> _TcpEcho:
        self.server = await asyncio.start_server(self._serve, "127.0.0.1", 0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self.server is not None
        self.server.close()
        await self.server.wait_closed()
        for c in self.connections:
            c["writer"].close()
        await asyncio.sleep(0)

    @property
    def target(self) -> tuple[str, int]:
        assert self.server is not None
        return "127.0.0.1", self.server.sockets[0].getsockname()[1]

    async def _serve(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        conn = {"writer": writer, "eof": False, "got": b""}
        self.connections.append(conn)
        try:
            while data := await reader.read(4096):
                conn["got"] += data
                writer.write(b"echo:" + data)
                await writer.drain()
            conn["eof"] = True
        except OSError:
            pass
        finally:
            writer.close()


async def _read_some(reader: asyncio.StreamReader, timeout: float) -> bytes | None:
    """What arrives within ``timeout`` s (b"" on EOF), or None if nothing does."""
    try:
        return await asyncio.wait_for(reader.read(4096), timeout)
    except TimeoutError:
        return None


def test_tcp_proxy_forwards_both_ways_and_passes_closes_on() -> None:
    async def go() -> None:
        async with _TcpEcho() as echo, TcpOutageProxy(echo.target) as proxy:
            assert proxy.url == f"tcp:127.0.0.1:{proxy.port}"
            reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
            writer.write(b"one")
            assert await _read_some(reader, 2.0) == b"echo:one"
            writer.close()  # the client goes: the proxy closes its onward connection, the target sees EOF
            await writer.wait_closed()
            for _ in range(100):
                if echo.connections[0]["eof"]:
                    break
                await asyncio.sleep(0.01)
            assert echo.connections[0]["eof"]
            # a second client is a second connection onward
            reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
            writer.write(b"two")
            assert await _read_some(reader, 2.0) == b"echo:two"
            assert len(echo.connections) == 2 and echo.connections[1]["got"] == b"two"
            echo.connections[1]["writer"].close()  # now the target goes: the client sees EOF
            assert await _read_some(reader, 2.0) == b""
            writer.close()
            await writer.wait_closed()
            await asyncio.sleep(0.05)
            assert [(s.number, s.onward, s.closed_by) for s in proxy.sessions] == [(1, True, "client"),
                                                                                  (2, True, "target")]
            assert proxy.counters.forwarded == {"up": 6, "down": 16}
            assert proxy.counters.dropped == {"up": 0, "down": 0}

    asyncio.run(go())


def test_tcp_outage_drops_bytes_both_ways_and_keeps_the_connections() -> None:
    async def go() -> None:
        async with _TcpEcho() as echo, TcpOutageProxy(echo.target) as proxy:
            reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
            writer.write(b"a")
            assert await _read_some(reader, 2.0) == b"echo:a"
            proxy.outage(1.5)
            assert proxy.in_outage
            writer.write(b"lost")  # dropped on the way up: the target never sees it
            assert await _read_some(reader, 0.3) is None  # silence, not EOF
            echo.connections[0]["writer"].write(b"unasked")  # dropped on the way down
            assert await _read_some(reader, 0.2) is None
            # a client that connects during the outage is accepted and connected onward, and hears nothing
            reader2, writer2 = await asyncio.open_connection("127.0.0.1", proxy.port)
            writer2.write(b"early")
            assert await _read_some(reader2, 0.1) is None
            while proxy.in_outage:
                await asyncio.sleep(0.02)
            writer.write(b"b")  # same connections, working again
            assert await _read_some(reader, 2.0) == b"echo:b"
            writer2.write(b"c")
            assert await _read_some(reader2, 2.0) == b"echo:c"
            assert echo.connections[0]["got"] == b"ab" and echo.connections[1]["got"] == b"c"
            assert not echo.connections[0]["eof"]
            assert proxy.counters.dropped == {"up": 9, "down": 7}
            assert len(proxy.outages) == 1 and abs(proxy.outages[0][1] - proxy.outages[0][0] - 1.5) < 1e-9
            for w in (writer, writer2):
                w.close()
                await w.wait_closed()

    asyncio.run(go())


def test_tcp_proxy_closes_a_client_it_cannot_connect_onward_and_stops_cleanly() -> None:
    async def go() -> None:
        with socket.socket() as s:  # a port nobody listens on
            s.bind(("127.0.0.1", 0))
            closed_port = s.getsockname()[1]
        async with TcpOutageProxy(("127.0.0.1", closed_port)) as proxy:
            reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
            assert await _read_some(reader, 2.0) == b""
            writer.close()
            await writer.wait_closed()
            assert not proxy.sessions[0].onward
            assert proxy.sessions[0].closed_by.startswith("onward connect failed")
        async with _TcpEcho() as echo:
            proxy = await TcpOutageProxy(echo.target).start()
            reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
            writer.write(b"x")
            assert await _read_some(reader, 2.0) == b"echo:x"
            await proxy.stop()  # closes both sides of the open session
            assert await _read_some(reader, 2.0) == b""
            assert proxy.sessions[0].closed_by == "proxy stopped"
            writer.close()
            await writer.wait_closed()
            # stopped while a session is closing (its client just went, the proxy is closing the rest): its
            # sockets still close (no_leaks); each pass stops it one loop step later
            for steps in range(12):
                proxy = await TcpOutageProxy(echo.target).start()
                reader, writer = await asyncio.open_connection("127.0.0.1", proxy.port)
                writer.write(b"y")
                assert await _read_some(reader, 2.0) == b"echo:y"
                writer.close()
                for _ in range(steps):
                    await asyncio.sleep(0)
                await proxy.stop()
                await writer.wait_closed()
                assert proxy.sessions[0].closed_at is not None

    asyncio.run(go())
