"""MAVLink link layer: one pymavlink connection driven by the asyncio loop (docs/design.md, "Companion").

:class:`Link` owns the socket (or serial port), sends our 1 Hz HEARTBEAT as an onboard controller, learns which
system is the vehicle from its first autopilot HEARTBEAT, and hands incoming messages to subscribers. Nothing in
here knows about missions: the mission protocol (``companion.mavlink.protocol``) sits on top.

Receiving uses ``loop.add_reader`` on the connection's file descriptor and drains pymavlink's non-blocking
``recv_msg()`` until it has nothing more: no thread and no polling. pymavlink's parser runs in robust mode, so
garbage (ArduPilot SITL starts its TCP stream with plain text) and bad CRCs become ``BAD_DATA`` and are counted,
never raised. A socket error or a closed TCP peer makes the link re-create the pymavlink connection with a capped
exponential back-off (0.5 s doubling to 8 s by default); subscriptions survive the reconnect.

Only messages from the target autopilot (system *and* component) reach subscribers unless they ask for
``any_source=True``: other vehicles, cameras, ground stations and our own echo are ignored for protocol purposes.
A subscription can name further components *of the target system* per message type (``extra_components``), e.g.
ADSB_VEHICLE from an ADS-B receiver (component 156) on the vehicle; other systems stay excluded.

:meth:`Link.on_target_acquired` registers callbacks run whenever the target autopilot is (re)acquired: its first
HEARTBEAT, the first on each new connection (after a reconnect) and the first after a heartbeat loss. Layers
above use it to redo per-connection setup (``companion.mavlink.telemetry`` asks for message rates there).

With ``tlog`` (a path) every message sent and every message parsed (from any system, our own echo included; not
garbage) goes to a telemetry log (:mod:`companion.mavlink.tlog`), one file across reconnects, closed with the link.
"""

from __future__ import annotations

import asyncio
import logging
import math
import struct
import time
from collections.abc import AsyncIterator, Callable, Iterable, Mapping
from pathlib import Path
from types import ModuleType
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega

from companion.mavlink.errors import LinkError
from companion.mavlink.profiles import AutopilotProfile, profile_for
from companion.mavlink.signing import SigningKey, enable_signing
from companion.mavlink.tlog import SENT_LINK, Tlog

log = logging.getLogger(__name__)

Message = Any  # a pymavlink MAVLink_message; pymavlink has no usable type for it
RECEIVED = "_fuseplan_received"  # the attribute a link stamps on each message it delivers (time.monotonic())


def received_at(msg: Message) -> float:
    """The monotonic time the link received ``msg`` (a message read from a queue much later, a backlog, is still
    timed by its arrival); now for one that came from no link."""
    return getattr(msg, RECEIVED, None) or time.monotonic()
Predicate = Callable[[Message], bool]

MAV_COMP_ID_ONBOARD_COMPUTER = ardupilotmega.MAV_COMP_ID_ONBOARD_COMPUTER  # 191
MAV_COMP_ID_AUTOPILOT1 = ardupilotmega.MAV_COMP_ID_AUTOPILOT1
MAV_COMP_ID_ADSB = ardupilotmega.MAV_COMP_ID_ADSB  # 156: an ADS-B receiver on the vehicle
MAV_AUTOPILOT_INVALID = ardupilotmega.MAV_AUTOPILOT_INVALID
_READ_BURST = 256  # messages handled per readable event before yielding to the loop (add_reader fires again)


NETWORK_SCHEMES = ("tcp", "tcpin", "udp", "udpin", "udpout", "udpbcast")


def check_url(url: str, option: str = "--connect") -> str:
    """``url`` if it is a connection string the companion can open (``SCHEME:HOST:PORT`` with a scheme of
    :data:`NETWORK_SCHEMES` and a port 1–65535, a serial device ``/dev/…`` or ``COMn`` with an optional
    ``,BAUD``, or a MAVSDK ``scheme://`` URL); else a one-line :class:`~planner.errors.FuseplanError` (exit 2)
    before anything is planned or opened."""
    from planner.errors import FuseplanError

    def bad(why: str) -> FuseplanError:
        return FuseplanError(f"{option} {url!r}: {why} (e.g. tcp:127.0.0.1:5760, udpin:0.0.0.0:14550, "
                             "/dev/ttyACM0)")

    if not url or any(c.isspace() or not c.isprintable() for c in url):
        raise bad("empty, or holds spaces or control characters")
    if url.startswith("/dev/") or url.upper().startswith("COM"):
        device, _, baud = url.partition(",")
        if baud and not (baud.isdigit() and 0 < int(baud) <= 10_000_000):
            raise bad(f"baud {baud!r} is not a positive number")
        if url.upper().startswith("COM") and not device[3:].isdigit():
            raise bad("a Windows serial port is COM followed by its number")
        return url
    if "://" in url:
        scheme, _, rest = url.partition("://")
        host, _, port = rest.rpartition(":")
    else:
        scheme, _, rest = url.partition(":")
        if scheme not in NETWORK_SCHEMES:
            raise bad(f"unknown connection type {scheme!r}; use one of {', '.join(NETWORK_SCHEMES)} or a serial "
                      "device")
        host, _, port = rest.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise bad("HOST:PORT with a port 1-65535 expected after the connection type")
    return url


class HeartbeatTimeout(LinkError, TimeoutError):
    """No HEARTBEAT from the target autopilot in time (a :class:`LinkError` and a ``TimeoutError``)."""


class _PeerClosed(ConnectionError):
    """pymavlink saw EOF / reset on a stream socket (raised from its handle_eof/handle_disconnect hooks)."""


class Subscription:
    """Incoming messages of some types, in arrival order; registered when created, so nothing sent after it
    exists can be missed. Use as a (sync or async) context manager, iterate it, or call :meth:`get`.

    The queue holds at most ``maxsize`` messages; beyond that the oldest are dropped (and logged), so a
    forgotten subscription cannot grow without bound.
    """

    def __init__(self, link: Link, types: frozenset[str] | None, predicate: Predicate | None,
                 any_source: bool, maxsize: int,
                 extra_components: Mapping[str, frozenset[int]] | None = None) -> None:
        self._link = link
        self.types = types
        self._predicate = predicate
        self.any_source = any_source
        self.extra_components: Mapping[str, frozenset[int]] = extra_components or {}
        self._maxsize = maxsize
        self._queue: asyncio.Queue[Message] = asyncio.Queue()
        self.dropped = 0
        self.closed = False

    def _matches(self, msg: Message, from_target: bool, sibling: int | None) -> bool:
        """``from_target``: sent by the target autopilot; ``sibling``: the sender's component when it is another
        component of the target system (else None)."""
        mtype = msg.get_type()
        if self.types is not None and mtype not in self.types:
            return False
        if not (from_target or self.any_source
                or (sibling is not None and sibling in self.extra_components.get(mtype, ()))):
            return False
        if self._predicate is None:
            return True
        try:
            return bool(self._predicate(msg))
        except Exception:  # a subscriber's bug must not break the receive path of everyone else
            log.exception("subscription predicate failed on %s", msg.get_type())
            return False

    def _offer(self, msg: Message) -> None:
        if self._queue.qsize() >= self._maxsize:
            self._queue.get_nowait()
            self.dropped += 1
            if self.dropped == 1 or self.dropped % 100 == 0:
                log.warning("subscription %s overflowing: %d messages dropped", self.types, self.dropped)
        self._queue.put_nowait(msg)

    async def get(self, timeout: float | None = None) -> Message:
        """The next message; raises ``TimeoutError`` after ``timeout`` s, :class:`LinkError` once closed."""
        if self.closed and self._queue.empty():
            raise LinkError("subscription closed")
        # asyncio.timeout, not wait_for: on Python 3.11 wait_for can swallow a cancellation that arrives as the
        # message does, leaving a cancelled task running for ever (seen with the replanner's watch loop)
        async with asyncio.timeout(timeout):
            msg = await self._queue.get()
        if msg is None:  # close() sentinel
            raise LinkError("subscription closed")
        return msg

    def drain(self) -> list[Message]:
        """Every message queued now, without waiting (none after :meth:`close`)."""
        out = []
        while not self._queue.empty():
            msg = self._queue.get_nowait()
            if msg is None:  # close() sentinel: keep it for a pending get()
                self._queue.put_nowait(None)
                break
            out.append(msg)
        return out

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self._link._subscriptions.discard(self)
            self._queue.put_nowait(None)  # wake a pending get()

    def __aiter__(self) -> Subscription:
        return self

    async def __anext__(self) -> Message:
        try:
            return await self.get()
        except LinkError:
            raise StopAsyncIteration from None

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    async def __aenter__(self) -> Subscription:
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()


DEFAULT_BAUD = 57600  # a serial link's rate unless told: SiK telemetry radios and most autopilots' TELEM ports


class Link:
    """An asyncio MAVLink connection to one autopilot.

    ``url`` is a pymavlink connection string: ``udpin:HOST:PORT``, ``udpout:HOST:PORT``, ``udp:HOST:PORT``
    (= udpin), ``tcp:HOST:PORT`` or a serial device (``/dev/ttyACM0``, with ``baud``). The TCP connect itself
    is pymavlink's single blocking ``connect()`` (immediate on localhost; make sure a remote host is
    reachable). ``target_system`` / ``target_component`` pin the vehicle; otherwise the first HEARTBEAT with
    ``autopilot != MAV_AUTOPILOT_INVALID`` decides. Times are seconds. ``open_timeout`` > 0 keeps retrying
    the first connection with back-off for that long before :meth:`open` raises :class:`LinkError`.
    """

    def __init__(self, url: str, *, source_system: int = 1,
                 source_component: int = MAV_COMP_ID_ONBOARD_COMPUTER,
                 target_system: int | None = None, target_component: int | None = None,
                 baud: int = DEFAULT_BAUD, heartbeat_interval: float = 1.0, heartbeat_timeout: float = 5.0,
                 reconnect_min: float = 0.5, reconnect_max: float = 8.0, open_timeout: float = 0.0,
                 dialect: ModuleType = ardupilotmega, signing_key: SigningKey | None = None,
                 tlog: Path | None = None) -> None:
        self.url = url
        self.tlog = Tlog(tlog) if tlog is not None else None  # every message sent and received, as a .tlog
        self._signing_key = signing_key  # MAVLink 2 signing: sign all we send, drop unsigned input
        self._signing_timestamp = 0  # the last signing timestamp of a closed connection (10 µs units)
        self.source_system = source_system
        self.source_component = source_component
        self.baud = baud
        self.heartbeat_interval = heartbeat_interval
        self.heartbeat_timeout = heartbeat_timeout
        self.reconnect_min = reconnect_min
        self.reconnect_max = reconnect_max
        self.open_timeout = open_timeout
        self.dialect = dialect

        self.target_system: int | None = target_system
        self.pinned = target_system is not None  # chosen by the user, not by whichever autopilot spoke first
        self.target_component: int | None = target_component
        self.autopilot: int | None = None  # MAV_AUTOPILOT_* of the target
        self.vehicle_type: int | None = None  # MAV_TYPE_* of the target
        self.last_heartbeat: float | None = None  # loop.time() of the target's last HEARTBEAT
        self.last_heartbeat_msg: Message | None = None
        self.heartbeat_lost = False
        self.bad_packets = 0  # BAD_DATA / unparsable input seen
        self.dropped_unsigned = 0  # with signing on: unsigned messages dropped
        self.dropped_signed = 0  # with signing on: messages signed with another key (or replayed) dropped
        self.other_autopilots: set[int] = set()  # systems of autopilots heard that are not the target
        self.reconnects = 0  # successful re-creations of the connection
        # gaps in the target's HEARTBEATs longer than heartbeat_timeout, or a new connection, counted when its
        # HEARTBEAT is heard again: whoever looks compares this count, so no outage goes unnoticed (issue 33)
        self.outages = 0
        self.last_outage_s = 0.0  # how long the last one was, s
        self._target_heard = False  # the target's HEARTBEAT has been heard on the current connection
        self._on_target: list[Callable[[Message], None]] = []

        self._conn: Any = None  # pymavlink mavfile
        self._fd: int | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._subscriptions: set[Subscription] = set()
        self._expectations: list[tuple[frozenset[str] | None, Predicate | None, bool, asyncio.Future]] = []
        self._heartbeat_task: asyncio.Task | None = None
        self._reconnect_task: asyncio.Task | None = None
        self._closing = False
        self._heartbeat_msg = dialect.MAVLink_heartbeat_message(
            dialect.MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID, 0, 0, dialect.MAV_STATE_ACTIVE, 3)

    # ------------------------------------------------------------------ lifecycle
    async def __aenter__(self) -> Link:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.close()

    @property
    def connected(self) -> bool:
        return self._conn is not None

    @property
    def profile(self) -> AutopilotProfile:
        """What the target autopilot does where the companion must know it (:mod:`companion.mavlink.profiles`), from its
        last HEARTBEAT's autopilot and type; the generic profile until one is heard."""
        return profile_for(self.autopilot, self.vehicle_type)

    async def open(self) -> None:
        """Create the connection, start receiving and heartbeating."""
        if self._loop is not None:
            raise LinkError("link already opened")
        self._loop = asyncio.get_running_loop()
        self._closing = False
        deadline = self._loop.time() + self.open_timeout
        delay = self.reconnect_min
        while True:
            try:
                self._connect()
                break
            except OSError as exc:
                if self._loop.time() + delay > deadline:
                    self._loop = None
                    if self.tlog is not None:
                        self.tlog.close()
                    raise LinkError(f"cannot open {self.url}: {exc}") from exc
                log.info("cannot open %s (%s); retrying in %.1f s", self.url, exc, delay)
                await asyncio.sleep(delay)
                delay = min(delay * 2, self.reconnect_max)
        self._heartbeat_task = asyncio.create_task(self._heartbeat_loop(), name=f"link-heartbeat {self.url}")

    async def close(self) -> None:
        """Stop everything this link started and close the socket; idempotent."""
        self._closing = True
        tasks = [t for t in (self._heartbeat_task, self._reconnect_task) if t is not None]
        self._heartbeat_task = self._reconnect_task = None
        for task in tasks:
            task.cancel()
        for task in tasks:
            try:
                await task
            except asyncio.CancelledError:
                pass
        self._disconnect()
        for sub in list(self._subscriptions):
            sub.close()
        for *_, fut in list(self._expectations):
            if not fut.done():
                fut.set_exception(LinkError("link closed"))
        self._expectations.clear()
        self._loop = None
        if self.tlog is not None:
            self.tlog.close()

    def _connect(self) -> None:
        """(Re-)create the pymavlink connection and register its fd with the loop."""
        try:
            conn = mavutil.mavlink_connection(self.url, baud=self.baud, source_system=self.source_system,
                                              source_component=self.source_component, retries=0)
        except OSError:
            raise  # transient: retried with back-off
        except (ValueError, ImportError, TypeError) as exc:  # a malformed URL, or serial without pyserial
            raise LinkError(f"cannot use connection {self.url!r}: {exc}") from exc
        # Our own MAVLink 2 encoder/parser: pymavlink's default is chosen from process-wide state (and its
        # auto-switch to MAVLink 2 rewrites os.environ and the global dialect), which we do not want to touch.
        conn.mav = self.dialect.MAVLink(conn, srcSystem=self.source_system, srcComponent=self.source_component)
        conn.mav.robust_parsing = True
        if self._signing_key is not None:
            # a new connection goes on from the last timestamp used or learned from the peer (pymavlink
            # takes a signed peer's when it is ahead): SITL's clock runs ahead of ours under speed-up, and
            # it ignores a stream more than 60 s behind its own
            enable_signing(conn.mav, self._signing_key, timestamp=self._signing_timestamp)
        conn.robust_parsing = True
        conn.first_byte = False
        conn.WIRE_PROTOCOL_VERSION = "2.0"
        # pymavlink prints and (without autoreconnect) silently carries on when a TCP peer goes away; make
        # those hooks raise so the receive path can reconnect.
        conn.handle_eof = conn.handle_disconnect = _raise_peer_closed
        try:
            conn.mav.send(self._heartbeat_msg)  # so a udpin peer (MAVSDK, SITL on UDP) learns our address now
        except (OSError, _PeerClosed) as exc:
            conn.close()
            raise OSError(f"greeting HEARTBEAT failed: {exc}") from exc
        if self.tlog is not None:
            self.tlog.write(self._heartbeat_msg.get_msgbuf(), SENT_LINK)
        fd = conn.fd if conn.fd is not None else conn.port.fileno()
        assert self._loop is not None
        self._loop.add_reader(fd, self._on_readable)
        self._conn, self._fd = conn, fd
        self._target_heard = False
        log.info("link %s open (fd %d)", self.url, fd)

    def _disconnect(self) -> None:
        conn, fd = self._conn, self._fd
        self._conn = self._fd = None
        if conn is None:
            return
        if self._signing_key is not None:
            self._signing_timestamp = max(self._signing_timestamp, conn.mav.signing.timestamp)
        if fd is not None and self._loop is not None:
            self._loop.remove_reader(fd)
        try:
            conn.close()
        except OSError as exc:
            log.debug("closing %s: %s", self.url, exc)

    def _connection_lost(self, exc: BaseException) -> None:
        if self._conn is None or self._closing:
            return
        log.warning("link %s lost: %s", self.url, exc or "peer closed")
        self._disconnect()
        if self._reconnect_task is None or self._reconnect_task.done():
            self._reconnect_task = asyncio.create_task(self._reconnect_loop(), name=f"link-reconnect {self.url}")

    async def _reconnect_loop(self) -> None:
        delay = self.reconnect_min
        while not self._closing:
            await asyncio.sleep(delay)
            try:
                self._connect()
            except OSError as exc:
                delay = min(delay * 2, self.reconnect_max)
                log.info("reconnect to %s failed (%s); next try in %.1f s", self.url, exc, delay)
                continue
            self.reconnects += 1
            log.info("link %s reconnected", self.url)
            return

    # ------------------------------------------------------------------ sending
    def send(self, msg: Message) -> None:
        """Send one pymavlink message object (built with ``link.dialect`` or any v2 dialect's classes),
        signed with our system/component id. Raises :class:`LinkError` while disconnected."""
        conn = self._conn
        if conn is None:
            raise LinkError(f"link {self.url} is not connected")
        try:
            conn.mav.send(msg)
        except (OSError, _PeerClosed) as exc:
            self._connection_lost(exc)
            raise LinkError(f"send on {self.url} failed: {exc}") from exc
        if self.tlog is not None:
            self.tlog.write(msg.get_msgbuf(), SENT_LINK)  # as packed: sequence number, signature and all

    async def _heartbeat_loop(self) -> None:
        """1 Hz HEARTBEAT, and the heartbeat-loss watch on the target."""
        assert self._loop is not None
        while True:
            await asyncio.sleep(self.heartbeat_interval)  # the first one went out with the connection
            if self._conn is not None:
                try:
                    self.send(self._heartbeat_msg)
                except LinkError as exc:
                    log.debug("heartbeat not sent: %s", exc)
            now = self._loop.time()
            if (self.last_heartbeat is not None and not self.heartbeat_lost
                    and now - self.last_heartbeat > self.heartbeat_timeout):
                self.heartbeat_lost = True
                log.warning("no HEARTBEAT from system %s for %.1f s", self.target_system,
                            now - self.last_heartbeat)
                if self._conn is not None and self.url.startswith("tcp"):
                    self._connection_lost(ConnectionError("heartbeat timeout"))  # half-open TCP: start over

    # ------------------------------------------------------------------ receiving
    def _on_readable(self) -> None:
        conn = self._conn
        for _ in range(_READ_BURST):
            if conn is None or conn is not self._conn:
                return
            try:
                msg = conn.recv_msg()
            except (OSError, _PeerClosed) as exc:
                self._connection_lost(exc)
                return
            except (ardupilotmega.MAVError, struct.error, ValueError, IndexError) as exc:
                # robust parsing normally returns BAD_DATA instead; be as tolerant if it does not
                self.bad_packets += 1
                log.debug("unparsable input on %s: %s", self.url, exc)
                continue
            if msg is None:
                return
            if self.tlog is not None and msg.get_type() != "BAD_DATA":
                self.tlog.write(msg.get_msgbuf())  # the bytes as received
            self._dispatch(msg)

    def _dispatch(self, msg: Message) -> None:
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            self.bad_packets += 1
            if self._signing_key is not None and "signature" in str(getattr(msg, "reason", "")):
                data = bytes(getattr(msg, "data", b"") or b"")
                signed = len(data) > 2 and data[0] == 0xFD and data[2] & 0x01  # MAVLINK_IFLAG_SIGNED
                if signed:
                    self.dropped_signed += 1
                else:
                    self.dropped_unsigned += 1
            return
        setattr(msg, RECEIVED, time.monotonic())
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self.source_system, self.source_component):
            return  # our own echo (broadcast / forwarding peers)
        if mtype == "HEARTBEAT":
            self._on_heartbeat(msg, src)
        from_target = self.target_system is not None and src == (self.target_system, self.target_component)
        sibling = src[1] if not from_target and src[0] == self.target_system else None
        for sub in list(self._subscriptions):
            if sub._matches(msg, from_target, sibling):
                sub._offer(msg)
        if self._expectations:
            for entry in list(self._expectations):
                types, predicate, any_source, fut = entry
                if fut.done() or (types is not None and mtype not in types) or not (from_target or any_source):
                    continue
                try:
                    ok = predicate is None or predicate(msg)
                except Exception as exc:
                    fut.set_exception(exc)
                    continue
                if ok:
                    fut.set_result(msg)

    def _on_heartbeat(self, msg: Message, src: tuple[int, int]) -> None:
        if msg.autopilot == MAV_AUTOPILOT_INVALID:
            return  # GCS, companion, camera…: not a vehicle
        if self.target_system is None:
            self.target_system = src[0]
            log.info("target vehicle: system %d component %d (autopilot %d, type %d)",
                     src[0], src[1], msg.autopilot, msg.type)
        if src[0] != self.target_system:
            if src[0] not in self.other_autopilots:
                self.other_autopilots.add(src[0])
                log.warning("HEARTBEAT from another autopilot, system %d, on %s: ignored (the target is system %d)",
                            src[0], self.url, self.target_system)
            return
        if self.target_component is None:
            self.target_component = src[1]
        if src[1] != self.target_component:
            return
        assert self._loop is not None
        now = self._loop.time()
        if self.last_heartbeat is not None and (not self._target_heard or self.heartbeat_lost
                                                or now - self.last_heartbeat > self.heartbeat_timeout):
            self.outages += 1
            self.last_outage_s = now - self.last_heartbeat
            log.info("system %d heard again after %.1f s (outage %d)", src[0], self.last_outage_s, self.outages)
        self.autopilot, self.vehicle_type = msg.autopilot, msg.type
        self.last_heartbeat, self.last_heartbeat_msg = now, msg
        acquired = not self._target_heard or self.heartbeat_lost
        self._target_heard = True
        if self.heartbeat_lost:
            self.heartbeat_lost = False
            log.info("HEARTBEAT from system %d back", src[0])
        if acquired:
            for callback in list(self._on_target):
                try:
                    callback(msg)
                except Exception:  # a callback's bug must not break the receive path
                    log.exception("target-acquired callback %r failed", callback)

    def on_target_acquired(self, callback: Callable[[Message], None]) -> Callable[[], None]:
        """Run ``callback(heartbeat)`` each time the target autopilot is (re)acquired: its first HEARTBEAT, the
        first one on every new connection (each reconnect), and the first one after the heartbeat was lost (an
        autopilot that rebooted behind a UDP or serial link). It runs synchronously in the receive path, before
        subscribers see that HEARTBEAT: it must not block (start a task for anything that waits). Returns a
        function that unregisters it."""
        self._on_target.append(callback)

        def remove() -> None:
            if callback in self._on_target:
                self._on_target.remove(callback)
        return remove

    # ------------------------------------------------------------------ subscribing
    def subscribe(self, *types: str, predicate: Predicate | None = None, any_source: bool = False,
                  maxsize: int = 1000, extra_components: Mapping[str, Iterable[int]] | None = None) -> Subscription:
        """A :class:`Subscription` to messages of ``types`` (all types if none), live from this call on.
        Only the target autopilot's messages unless ``any_source``; ``extra_components`` maps a message type to
        further components of the *target system* whose messages of that type are delivered too (e.g.
        ``{"ADSB_VEHICLE": [MAV_COMP_ID_ADSB]}``: an ADS-B receiver's reports, but not its HEARTBEAT; never
        another system's)."""
        extra = {t: frozenset(c) for t, c in (extra_components or {}).items()}
        sub = Subscription(self, frozenset(types) if types else None, predicate, any_source, maxsize, extra)
        self._subscriptions.add(sub)
        return sub

    async def messages(self, *types: str, predicate: Predicate | None = None, any_source: bool = False,
                       extra_components: Mapping[str, Iterable[int]] | None = None) -> AsyncIterator[Message]:
        """Async generator over incoming messages; unsubscribes when the consumer stops or the link closes.
        It subscribes on the first ``__anext__``: use :meth:`subscribe` when nothing may be missed before."""
        sub = self.subscribe(*types, predicate=predicate, any_source=any_source, extra_components=extra_components)
        try:
            async for msg in sub:
                yield msg
        finally:
            sub.close()

    def expect(self, *types: str, predicate: Predicate | None = None,
               any_source: bool = False) -> asyncio.Future:
        """A future for the next matching message, registered now: create it *before* sending the request it
        answers. Cancelling the future unregisters it."""
        if self._loop is None:
            raise LinkError("link is not open")
        fut = self._loop.create_future()
        entry = (frozenset(types) if types else None, predicate, any_source, fut)
        self._expectations.append(entry)
        fut.add_done_callback(lambda _f: self._expectations.remove(entry) if entry in self._expectations else None)
        return fut

    async def wait_for(self, *types: str, predicate: Predicate | None = None, timeout: float = 1.5,
                       any_source: bool = False) -> Message:
        """The next matching message; ``TimeoutError`` after ``timeout`` s."""
        fut = self.expect(*types, predicate=predicate, any_source=any_source)
        try:
            async with asyncio.timeout(timeout):  # not wait_for: see Subscription.get
                return await fut
        finally:
            fut.cancel()

    async def wait_heartbeat(self, timeout: float = 5.0) -> Message:
        """The target's HEARTBEAT: the last one if it is fresher than ``heartbeat_timeout``, else the next
        (which also picks the target when none is known yet). :class:`HeartbeatTimeout` after ``timeout`` s."""
        if (self.last_heartbeat is not None and self._loop is not None
                and self._loop.time() - self.last_heartbeat <= self.heartbeat_timeout):
            return self.last_heartbeat_msg
        try:
            return await self.wait_for("HEARTBEAT", predicate=lambda m: m.autopilot != MAV_AUTOPILOT_INVALID,
                                       timeout=timeout)
        except TimeoutError:
            who = "an autopilot" if self.target_system is None else f"system {self.target_system}"
            raise HeartbeatTimeout(f"no HEARTBEAT from {who} on {self.url} within {timeout:g} s"
                                   + self.signing_hint()) from None

    def signing_hint(self) -> str:
        """With signing on, why nothing may have been heard: input dropped as unsigned or signed with another
        key (empty when nothing was dropped)."""
        if self._signing_key is None or not (self.dropped_unsigned or self.dropped_signed):
            return ""
        if self.dropped_unsigned and not self.dropped_signed:
            return (f"; signing is on and {self.dropped_unsigned} unsigned messages were dropped: the autopilot "
                    "does not sign (provision the key on it, or fly without signing)")
        return (f"; signing is on and {self.dropped_signed} messages signed with another key (and "
                f"{self.dropped_unsigned} unsigned) were dropped: check that both ends hold the same key")

    async def wait_back(self, timeout: float) -> bool:
        """Wait until the link is up again: connected, and the target's HEARTBEAT heard on this connection within
        ``heartbeat_timeout`` (after a TCP drop, the reconnect and the autopilot's first HEARTBEAT on it). False
        after ``timeout`` s."""
        assert self._loop is not None
        deadline = self._loop.time() + timeout
        while not (self.connected and self._target_heard and not self.heartbeat_lost
                   and self.heartbeat_age <= self.heartbeat_timeout):
            if self._loop.time() >= deadline:
                return False
            await asyncio.sleep(0.05)
        return True

    @property
    def heartbeat_age(self) -> float:
        """Seconds since the target's last HEARTBEAT (inf if never heard)."""
        if self.last_heartbeat is None or self._loop is None:
            return math.inf
        return self._loop.time() - self.last_heartbeat


def _raise_peer_closed() -> None:
    raise _PeerClosed("connection closed by peer")
