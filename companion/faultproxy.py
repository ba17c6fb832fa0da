"""A fault-injecting UDP proxy for tests (issue 7): sits between the companion and an autopilot (our simulator,
a MAVSDK server, SITL) and drops, duplicates, reorders, delays and corrupts datagrams, seeded.

    companion --udpout--> [front 127.0.0.1:port]  proxy  [back] --> autopilot's udpin port
    companion <---------- [front]                 proxy  [back] <-- autopilot

Replies go to the last address that sent to the front. Every random choice comes from a seeded generator per
direction, so a given seed and traffic order (per direction) give the same faults. :meth:`outage` drops
everything for a while (link loss).
"""

from __future__ import annotations

import asyncio
import logging
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Faults:
    """Per-datagram probabilities (each direction) and delays in seconds."""

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0  # held back and sent after the next datagram in the same direction
    corrupt: float = 0.0  # one random byte flipped
    delay_s: float = 0.0
    jitter_s: float = 0.0  # uniform extra delay in [0, jitter_s]

    def __post_init__(self) -> None:
        for name in ("drop", "duplicate", "reorder", "corrupt"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {getattr(self, name)}")
        if self.delay_s < 0 or self.jitter_s < 0:
            raise ValueError("delays must be >= 0")


@dataclass
class Counters:
    forwarded: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    corrupted: int = 0
    by_direction: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})


class _Endpoint(asyncio.DatagramProtocol):
    def __init__(self, on_datagram) -> None:  # noqa: ANN001
        self._on = on_datagram
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple) -> None:
        self._on(data, addr)


class FaultProxy:
    """UDP proxy from ``front`` (bound on ``host``, port 0 = any free port) to ``target`` (host, port)."""

    def __init__(self, target: tuple[str, int], faults: Faults = Faults(), seed: int = 0,
                 host: str = "127.0.0.1", port: int = 0) -> None:
        self.target = target
        self.faults = faults
        self.counters = Counters()
        # one generator per direction: each direction's faults depend only on its own traffic order
        self._rng = {d: np.random.default_rng([seed, i]) for i, d in enumerate(("up", "down"))}
        self._bind = (host, port)
        self._front: _Endpoint | None = None
        self._back: _Endpoint | None = None
        self._client: tuple | None = None
        self._held: dict[str, bytes | None] = {"up": None, "down": None}
        self._outage_until = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def port(self) -> int:
        assert self._front is not None and self._front.transport is not None
        return self._front.transport.get_extra_info("sockname")[1]

    async def start(self) -> FaultProxy:
        self._loop = asyncio.get_running_loop()
        _, self._front = await self._loop.create_datagram_endpoint(
            lambda: _Endpoint(self._from_client), local_addr=self._bind)
        _, self._back = await self._loop.create_datagram_endpoint(
            lambda: _Endpoint(self._from_target), remote_addr=self.target)
        return self

    async def stop(self) -> None:
        for ep in (self._front, self._back):
            if ep is not None and ep.transport is not None:
                ep.transport.close()
        self._front = self._back = None

    async def __aenter__(self) -> FaultProxy:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    def outage(self, seconds: float) -> None:
        """Drop every datagram both ways for ``seconds`` from now (a link outage)."""
        assert self._loop is not None
        self._outage_until = self._loop.time() + seconds
        log.info("proxy: outage for %.1f s", seconds)

    # -- forwarding ------------------------------------------------------------------------------------
    def _from_client(self, data: bytes, addr: tuple) -> None:
        self._client = addr
        self._forward("up", data)

    def _from_target(self, data: bytes, addr: tuple) -> None:
        if self._client is not None:
            self._forward("down", data)

    def _send(self, direction: str, data: bytes) -> None:
        if direction == "up":
            if self._back is not None and self._back.transport is not None:
                self._back.transport.sendto(data)
        elif self._front is not None and self._front.transport is not None and self._client is not None:
            self._front.transport.sendto(data, self._client)
        self.counters.forwarded += 1
        self.counters.by_direction[direction] += 1

    def _forward(self, direction: str, data: bytes) -> None:
        assert self._loop is not None
        f, rng, c = self.faults, self._rng[direction], self.counters
        draws = rng.random(5)  # always five draws per datagram: the fault sequence depends on traffic only
        if self._loop.time() < self._outage_until or draws[0] < f.drop:
            c.dropped += 1
            return
        if draws[1] < f.corrupt and data:
            i = int(rng.integers(len(data)))
            data = data[:i] + bytes([data[i] ^ 0xFF]) + data[i + 1:]
            c.corrupted += 1
        copies = 2 if draws[2] < f.duplicate else 1
        c.duplicated += copies - 1
        if draws[3] < f.reorder and self._held[direction] is None:
            self._held[direction] = data  # goes out after the next one
            c.reordered += 1
            return
        batch = [data] * copies
        held, self._held[direction] = self._held[direction], None
        if held is not None:
            batch.append(held)
        delay = f.delay_s + (draws[4] * f.jitter_s if f.jitter_s else 0.0)
        for item in batch:
            if delay > 0:
                self._loop.call_later(delay, self._send, direction, item)
            else:
                self._send(direction, item)
