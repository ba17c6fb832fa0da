"""Companion test fixtures: a leak check on every test (tasks, threads, sockets — as pymodbus' test/conftest.py
does), a raw MAVLink peer on a plain UDP socket, for talking to a :class:`Link` without going through it, a MAVSDK
ground station on our simulated autopilot, and quick plans of rescue_static to fly (made once per session)."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import socket
from collections.abc import AsyncIterator, Callable
from contextlib import AbstractAsyncContextManager
from pathlib import Path
from typing import Any

import pytest
import pytest_asyncio
from leaks import Snapshot, fail_on_leaks
from pymavlink.dialects.v20 import ardupilotmega as mavlink


@pytest_asyncio.fixture(autouse=True)
async def no_leaks():
    """Fail a test that leaves asyncio tasks, threads or open sockets behind (after a short grace period
    for things already closing)."""
    before = Snapshot.take()
    yield
    await fail_on_leaks(before)


class RawPeer:
    """A MAVLink endpoint on a bare UDP socket bound to 127.0.0.1 (ephemeral port): it packs and parses with
    pymavlink's MAVLink 2 codec only, so it shares no code path with :class:`companion.mavlink.link.Link`."""

    def __init__(self, system: int = 1, component: int = 1) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.peer_addr: tuple[str, int] | None = None
        self._codecs: dict[tuple[int, int], mavlink.MAVLink] = {}
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.system, self.component = system, component

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> RawPeer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def pack(self, msg, system: int | None = None, component: int | None = None) -> bytes:
        key = (self.system if system is None else system, self.component if component is None else component)
        codec = self._codecs.setdefault(key, mavlink.MAVLink(None, srcSystem=key[0], srcComponent=key[1]))
        return msg.pack(codec)

    def send(self, msg, system: int | None = None, component: int | None = None) -> None:
        self.send_raw(self.pack(msg, system, component))

    def send_raw(self, data: bytes) -> None:
        assert self.peer_addr is not None, "nothing received yet: peer address unknown"
        self.sock.sendto(data, self.peer_addr)

    async def recv(self, timeout: float = 2.0) -> list:
        """The messages of the next datagram (good ones only)."""
        loop = asyncio.get_running_loop()
        data, addr = await asyncio.wait_for(loop.sock_recvfrom(self.sock, 65535), timeout)
        self.peer_addr = addr
        return [m for m in self.parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]

    async def recv_type(self, mtype: str, timeout: float = 2.0):
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        while True:
            for m in await self.recv(max(0.0, deadline - loop.time())):
                if m.get_type() == mtype:
                    return m


@pytest.fixture
def raw_peer():
    with RawPeer() as peer:
        yield peer



@contextlib.asynccontextmanager
async def _mavsdk_ground_station(scenario: Any) -> AsyncIterator[Any]:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync

    from companion.sim import SimAutopilot

    async with SimAutopilot(scenario, listen="udpin:127.0.0.1:0", speedup=5.0) as sim:
        cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        sdk = Mavsdk(cfg)
        cfg.destroy()
        try:
            await sdk.add_any_connection(f"udpout://127.0.0.1:{sim.port}")
            system = await sdk.first_autopilot(10.0)
            assert system is not None
            yield MissionRawAsync(system)
        finally:
            sdk.destroy()
            await asyncio.get_running_loop().shutdown_default_executor()


@pytest.fixture
def mavsdk_ground_station() -> Callable[[Any], AbstractAsyncContextManager[Any]]:
    """``async with mavsdk_ground_station(scenario) as raw``: a MAVSDK 4 ground station connected over UDP to our
    simulated autopilot flying ``scenario`` (5x), ``raw`` its MissionRawAsync (the ground station's importers);
    afterwards MAVSDK is destroyed and the loop's default executor shut down, then the autopilot stops."""
    return _mavsdk_ground_station


STATIC = Path(__file__).resolve().parents[2] / "sitl_scenarios" / "rescue_static.toml"
QUICK_PLAN = ("planner.pso.n_pop=200", "planner.pso.max_iter=80")  # a feasible rescue_static plan in ~0.5 s


@pytest.fixture(scope="session")
def static_plan_doc() -> Callable[..., dict]:
    """``static_plan_doc(*overrides)``: the PLAN.json document of rescue_static planned with the quick settings
    (and ``overrides``), made once per session; each call returns a fresh copy."""
    from companion.cli import _plan_doc_for

    made: dict[tuple[str, ...], dict] = {}

    def get(*overrides: str) -> dict:
        if overrides not in made:
            made[overrides], _ = _plan_doc_for(STATIC, None, [*QUICK_PLAN, *overrides], None)
        return copy.deepcopy(made[overrides])

    return get
