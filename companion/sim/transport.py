"""Server end of the simulated autopilot's MAVLink connection: ``udpin:`` or ``tcp:`` listen, with fault injection.

Pure asyncio: a :class:`asyncio.DatagramProtocol` (UDP) or an :func:`asyncio.start_server` (TCP) feeds bytes to
pymavlink's parser (``MAVLink(file=None).parse_buffer``); no threads, no polling. Outgoing messages are packed with
the autopilot's system/component id (or another component of the same system, e.g. an ADS-B receiver, with its
own sequence numbers) and go to the last UDP sender, or to every connected TCP client (as ArduPilot SITL's
serial-over-TCP port does). A message one TCP client sends that is not addressed to the autopilot alone (a
broadcast: HEARTBEAT, STATUSTEXT; or one for another system) is passed on to the other TCP clients as it came, as
ArduPilot's MAVLink routing passes a companion's messages on to the ground station's link.

Fault injection: each incoming datagram (TCP: each parsed message) and each outgoing packet is dropped with
probability ``loss`` (one seeded ``numpy.random.Generator``); outgoing packets are delayed by ``latency_s`` with
``loop.call_later``.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import LinkError
from companion.mavlink.signing import SigningKey, enable_signing

logger = logging.getLogger(__name__)

MessageHandler = Callable[[mavlink.MAVLink_message], None]


@dataclass(frozen=True)
class ListenAddress:
    scheme: str  # "udpin" | "tcp"
    host: str
    port: int


def parse_listen(listen: str) -> ListenAddress:
    """``"udpin:127.0.0.1:14550"`` / ``"tcp:127.0.0.1:5760"`` → :class:`ListenAddress` (port 0 = any free port)."""
    scheme, sep, rest = listen.partition(":")
    host, sep2, port_text = rest.rpartition(":")
    if not sep or not sep2 or scheme not in ("udpin", "udp", "tcp", "tcpin") or not host:
        raise LinkError(f"simulator listen address {listen!r}: expected udpin:HOST:PORT or tcp:HOST:PORT")
    try:
        port = int(port_text)
    except ValueError:
        raise LinkError(f"simulator listen address {listen!r}: port {port_text!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise LinkError(f"simulator listen address {listen!r}: port out of range")
    return ListenAddress("tcp" if scheme.startswith("tcp") else "udpin", host, port)


def new_mavlink(system_id: int, component_id: int) -> mavlink.MAVLink:
    """A MAVLink 2 packer/parser with no file behind it."""
    mav = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
    mav.robust_parsing = True
    return mav


class SimTransport:
    """Listening MAVLink endpoint of the simulator; ``on_message`` gets every parsed, not-dropped message."""

    def __init__(self, listen: str, on_message: MessageHandler, *, system_id: int, component_id: int,
                 loss: float = 0.0, latency_s: float = 0.0, rng: np.random.Generator | None = None,
                 signing_key: SigningKey | None = None) -> None:
        if not 0.0 <= loss < 1.0:
            raise ValueError(f"loss must be in [0, 1), got {loss}")
        if latency_s < 0.0:
            raise ValueError(f"latency_s must be >= 0, got {latency_s}")
        self.address = parse_listen(listen)
        self._on_message = on_message
        self._loss = loss
        self._latency = latency_s
        self._rng = rng if rng is not None else np.random.default_rng(0)
        self._signing_key = signing_key
        self._packer = self._mavlink(system_id, component_id)
        self._packers = {component_id: self._packer}  # one per sending component (own sequence numbers)
        self._udp: asyncio.DatagramTransport | None = None
        self._udp_parser = self._mavlink(system_id, component_id)
        self._peer: tuple[str, int] | None = None
        self._server: asyncio.Server | None = None
        self._tcp_clients: dict[asyncio.StreamWriter, asyncio.Task[None]] = {}
        self._pending: set[asyncio.TimerHandle] = set()
        self._silent_until = 0.0  # loop time: an outage (nothing in or out) lasts until then
        self._relisten: asyncio.Task[None] | None = None
        self.port = self.address.port
        self.sent = 0
        self.received = 0

    def _mavlink(self, system_id: int, component_id: int) -> mavlink.MAVLink:
        mav = new_mavlink(system_id, component_id)
        if self._signing_key is not None:  # as ArduPilot with a key set: signed out, unsigned in rejected
            # one signing clock for the vehicle (ArduPilot's is persistent): a new connection's parser starts
            # at the vehicle's timestamp and rejects a stream more than 60 s behind it
            packer = getattr(self, "_packer", None)
            enable_signing(mav, self._signing_key, timestamp=packer.signing.timestamp if packer else 0)
        return mav

    @property
    def connected(self) -> bool:
        """True once a peer exists to send to."""
        return self._peer is not None or bool(self._tcp_clients)

    async def open(self) -> None:
        loop = asyncio.get_running_loop()
        host, port = self.address.host, self.address.port
        try:
            if self.address.scheme == "udpin":
                self._udp, _ = await loop.create_datagram_endpoint(
                    lambda: _UdpProtocol(self), local_addr=(host, port))
                self.port = self._udp.get_extra_info("sockname")[1]
            else:
                self._server = await asyncio.start_server(self._serve_tcp_client, host, port)
                self.port = self._server.sockets[0].getsockname()[1]
        except OSError as exc:
            raise LinkError(f"simulator cannot listen on {self.address.scheme}:{host}:{port}: {exc}") from exc
        logger.info("simulated autopilot listening on %s:%s:%d", self.address.scheme, host, self.port)

    async def close(self) -> None:
        for handle in self._pending:
            handle.cancel()
        self._pending.clear()
        if self._relisten is not None:
            self._relisten.cancel()
            await asyncio.gather(self._relisten, return_exceptions=True)
            self._relisten = None
        if self._udp is not None:
            protocol = self._udp.get_protocol()
            self._udp.close()
            self._udp = None
            assert isinstance(protocol, _UdpProtocol)
            await protocol.closed  # the socket is really closed only after connection_lost
        if self._server is not None:
            self._server.close()
        for writer, task in list(self._tcp_clients.items()):
            task.cancel()
            writer.close()
        await asyncio.gather(*self._tcp_clients.values(), return_exceptions=True)
        self._tcp_clients.clear()
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    def outage(self, seconds: float) -> None:
        """Fault injection: the network goes away for ``seconds`` (wall). Nothing gets through either way; on TCP
        the port also stops listening (connects are refused) while open connections stay half-open, as after a
        cable pull, and listens again on the same port afterwards."""
        loop = asyncio.get_running_loop()
        self._silent_until = loop.time() + seconds
        if self._server is None:
            return
        self._server.close()  # existing connections are left alone
        handle: asyncio.TimerHandle

        def relisten() -> None:
            self._pending.discard(handle)
            self._relisten = asyncio.ensure_future(self._listen_again())

        handle = loop.call_later(seconds, relisten)
        self._pending.add(handle)

    def _silent(self) -> bool:
        return asyncio.get_running_loop().time() < self._silent_until

    async def _listen_again(self) -> None:
        try:
            self._server = await asyncio.start_server(self._serve_tcp_client, self.address.host, self.port)
        except OSError as exc:
            logger.error("simulator: cannot listen again on tcp port %d after the outage: %s", self.port, exc)
            return
        logger.info("simulator: listening again on tcp port %d", self.port)

    # --- outgoing -------------------------------------------------------------------------------------------

    def send(self, msg: mavlink.MAVLink_message, component_id: int | None = None) -> None:
        """Pack and send one message (subject to loss and latency); silently nothing if no peer yet.
        ``component_id``: send as that component of our system instead of the autopilot."""
        packer = self._packer
        if component_id is not None:
            packer = self._packers.get(component_id) or self._packers.setdefault(
                component_id, self._mavlink(self._packer.srcSystem, component_id))
        buf = msg.pack(packer)
        packer.seq = (packer.seq + 1) % 256
        if not self.connected or self._silent():
            return
        if self._loss and self._rng.random() < self._loss:
            return
        if self._latency > 0.0:
            loop = asyncio.get_running_loop()
            handle: asyncio.TimerHandle

            def deliver() -> None:
                self._pending.discard(handle)
                self._write(buf)

            handle = loop.call_later(self._latency, deliver)
            self._pending.add(handle)
        else:
            self._write(buf)

    def _write(self, buf: bytes) -> None:
        self.sent += 1
        if self._udp is not None and self._peer is not None:
            self._udp.sendto(buf, self._peer)
        for writer in self._tcp_clients:
            if not writer.is_closing():
                writer.write(buf)

    # --- incoming -------------------------------------------------------------------------------------------

    def _feed(self, parser: mavlink.MAVLink, data: bytes, per_message_loss: bool,
              source: asyncio.StreamWriter | None = None) -> None:
        if self._silent():
            return
        try:
            messages = parser.parse_buffer(data) or []
        except mavlink.MAVError as exc:  # robust_parsing makes this rare; a bad packet must not kill the link
            logger.debug("simulator: unparsable input dropped: %s", exc)
            return
        for msg in messages:
            if msg.get_type() == "BAD_DATA":
                continue
            if per_message_loss and self._loss and self._rng.random() < self._loss:
                continue
            self.received += 1
            if source is not None and len(self._tcp_clients) > 1:
                self._route(msg, source)
            self._on_message(msg)

    def _route(self, msg: mavlink.MAVLink_message, source: asyncio.StreamWriter) -> None:
        """Pass a message from one TCP client on to the others unless it is addressed to this system only."""
        if getattr(msg, "target_system", 0) == self._packer.srcSystem:
            return
        buf = bytes(msg.get_msgbuf())
        for writer in self._tcp_clients:
            if writer is not source and not writer.is_closing():
                writer.write(buf)

    def _datagram(self, data: bytes, addr: tuple[str, int]) -> None:
        if self._loss and self._rng.random() < self._loss:
            return
        self._peer = addr  # reply to the last sender, as ArduPilot's udpin does
        self._feed(self._udp_parser, data, per_message_loss=False)

    async def _serve_tcp_client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        assert task is not None
        self._tcp_clients[writer] = task
        parser = self._mavlink(self._packer.srcSystem, self._packer.srcComponent)
        logger.info("simulator: TCP client %s connected", writer.get_extra_info("peername"))
        try:
            while data := await reader.read(4096):
                self._feed(parser, data, per_message_loss=True, source=writer)
        except (ConnectionError, asyncio.IncompleteReadError):
            pass
        finally:
            self._tcp_clients.pop(writer, None)
            writer.close()


class _UdpProtocol(asyncio.DatagramProtocol):
    def __init__(self, owner: SimTransport) -> None:
        self._owner = owner
        self.closed: asyncio.Future[None] = asyncio.get_running_loop().create_future()

    def connection_lost(self, exc: Exception | None) -> None:
        if not self.closed.done():
            self.closed.set_result(None)

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self._owner._datagram(data, addr)

    def error_received(self, exc: Exception) -> None:  # e.g. ICMP port unreachable after the client left
        logger.debug("simulator: UDP error %s", exc)
