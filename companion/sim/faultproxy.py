"""A fault-injecting UDP proxy for tests (issue 7): sits between the companion and an autopilot (our simulator,
a MAVSDK server, SITL) and drops, duplicates, reorders, delays and corrupts datagrams, seeded.

    companion --udpout--> [front 127.0.0.1:port]  proxy  [back] --> autopilot's udpin port
    companion <---------- [front]                 proxy  [back] <-- autopilot

Replies go to the last address that sent to the front. Every random choice comes from a seeded generator per
direction, so a given seed and traffic order (per direction) give the same faults. :meth:`outage` drops
everything for a while (link loss).

:class:`TcpOutageProxy` is the same idea for a TCP link (ArduPilot SITL's serial ports): a plain forwarder, one
onward connection per accepted client, whose :meth:`~TcpOutageProxy.outage` drops the bytes both ways while the
connections stay open, as a radio link that goes silent.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
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
    def __init__(self, on_datagram: Callable[[bytes, tuple], None]) -> None:
        self._on = on_datagram
        self.transport: asyncio.DatagramTransport | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]  # a datagram endpoint's (typed as the base)

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


@dataclass
class TcpSession:
    """One accepted client and its onward connection; times are the proxy loop's clock."""

    number: int  # 1, 2, ... in order of acceptance
    accepted_at: float
    onward: bool = False  # the onward connection to the target was made
    closed_at: float | None = None
    closed_by: str | None = None  # "client", "target", "onward connect failed: ...", "proxy stopped"


@dataclass
class TcpCounters:
    """Bytes per direction ("up": client -> target, "down": target -> client)."""

    forwarded: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})
    dropped: dict[str, int] = field(default_factory=lambda: {"up": 0, "down": 0})


class TcpOutageProxy:
    """TCP forwarder from ``host:listen_port`` (0 = any free port) to ``target`` (host, port), for tests.

    Every client it accepts gets its own connection onward to the target; bytes are copied both ways until one
    side closes, and then the other side is closed too (so the target sees its client go, and a later client is
    a new connection to it). :meth:`outage` makes the link silent for a while: whatever arrives from either side
    is read and dropped, and both connections stay open; a close still passes (an outage silences the bytes, not
    the ends of the connections), and a client that connects meanwhile is accepted and connected onward as
    usual, and hears nothing until the outage ends. ``sessions`` and ``counters`` record what happened.
    """

    def __init__(self, target: tuple[str, int], listen_port: int = 0, host: str = "127.0.0.1") -> None:
        self.target = target
        self.sessions: list[TcpSession] = []
        self.counters = TcpCounters()
        self.outages: list[tuple[float, float]] = []  # (start, end) of each outage, loop time
        self._bind = (host, listen_port)
        self._server: asyncio.Server | None = None
        self._handlers: set[asyncio.Task] = set()
        self._outage_until = 0.0
        self._loop: asyncio.AbstractEventLoop | None = None

    @property
    def port(self) -> int:
        assert self._server is not None
        return self._server.sockets[0].getsockname()[1]

    @property
    def url(self) -> str:
        """The pymavlink connection string of the listening side."""
        return f"tcp:{self._bind[0]}:{self.port}"

    async def start(self) -> TcpOutageProxy:
        self._loop = asyncio.get_running_loop()
        self._server = await asyncio.start_server(self._serve, *self._bind)
        return self

    async def stop(self) -> None:
        """Stop listening and close every connection (both sides) still open."""
        if self._server is not None:
            self._server.close()
            await self._server.wait_closed()
            self._server = None
        handlers = list(self._handlers)
        for task in handlers:
            task.cancel()
        await asyncio.gather(*handlers, return_exceptions=True)

    async def __aenter__(self) -> TcpOutageProxy:
        return await self.start()

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    def outage(self, seconds: float) -> None:
        """Drop every byte both ways for ``seconds`` from now; the connections stay open."""
        assert self._loop is not None
        now = self._loop.time()
        self._outage_until = now + seconds
        self.outages.append((now, now + seconds))
        log.info("tcp proxy: outage for %.1f s", seconds)

    @property
    def in_outage(self) -> bool:
        return self._loop is not None and self._loop.time() < self._outage_until

    # -- forwarding ------------------------------------------------------------------------------------
    async def _serve(self, client_r: asyncio.StreamReader, client_w: asyncio.StreamWriter) -> None:
        assert self._loop is not None
        task = asyncio.current_task()
        assert task is not None
        self._handlers.add(task)
        session = TcpSession(len(self.sessions) + 1, self._loop.time())
        self.sessions.append(session)
        writers = [client_w]
        pumps: list[asyncio.Task] = []
        try:
            try:
                target_r, target_w = await asyncio.open_connection(*self.target)
            except OSError as e:
                session.closed_by = f"onward connect failed: {e}"
                return
            writers.append(target_w)
            session.onward = True
            pumps = [asyncio.create_task(self._pump(client_r, target_w, "up"), name=f"tcp-proxy up {session.number}"),
                     asyncio.create_task(self._pump(target_r, client_w, "down"),
                                         name=f"tcp-proxy down {session.number}")]
            done, _ = await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
            session.closed_by = "client" if pumps[0] in done else "target"
        except asyncio.CancelledError:
            # stop(): end quietly (asyncio's server logs a handler task that ends cancelled as an error)
            session.closed_by = session.closed_by or "proxy stopped"
        finally:
            for pump in pumps:
                pump.cancel()
            for w in writers:
                w.close()  # before any await: the sockets close even if stop() cancels the waits below
            try:
                await asyncio.gather(*pumps, return_exceptions=True)
                for w in writers:
                    await w.wait_closed()
            except (OSError, asyncio.CancelledError):
                pass
            session.closed_at = self._loop.time()
            self._handlers.discard(task)
            log.info("tcp proxy: session %d closed by %s", session.number, session.closed_by)

    async def _pump(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, direction: str) -> None:
        """Copy ``reader`` to ``writer`` (dropping during an outage) until EOF or a socket error."""
        assert self._loop is not None
        try:
            while data := await reader.read(65536):
                if self._loop.time() < self._outage_until:
                    self.counters.dropped[direction] += len(data)
                    continue
                writer.write(data)
                await writer.drain()
                self.counters.forwarded[direction] += len(data)
        except OSError as e:
            log.info("tcp proxy: %s side: %s", direction, e)
