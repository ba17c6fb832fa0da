"""companion.mavlink.link over real sockets on 127.0.0.1: heartbeat, target learning and filtering, subscription
ordering, garbage tolerance, TCP reconnect with back-off."""

from __future__ import annotations

import asyncio
import logging
import os

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import LinkError
from companion.mavlink.link import HeartbeatTimeout, Link

pytestmark = pytest.mark.asyncio


def heartbeat(autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, vehicle=mavlink.MAV_TYPE_FIXED_WING):
    return mavlink.MAVLink_heartbeat_message(vehicle, autopilot, 0, 0, mavlink.MAV_STATE_STANDBY, 3)


def mission_current(seq):
    return mavlink.MAVLink_mission_current_message(seq)


async def test_heartbeat_1hz_from_onboard_controller(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        loop = asyncio.get_running_loop()
        stamps = []
        while len(stamps) < 3:
            for m in await raw_peer.recv(2.0):
                if m.get_type() == "HEARTBEAT":
                    assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)
                    assert m.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
                    assert m.autopilot == mavlink.MAV_AUTOPILOT_INVALID
                    assert m.get_header().mlen > 0 and m.get_msgbuf()[0] == 0xFD  # MAVLink 2
                    stamps.append(loop.time())
        gaps = [b - a for a, b in zip(stamps, stamps[1:])]
        assert all(0.85 < g < 1.2 for g in gaps), gaps
        assert link.target_system is None  # nobody has spoken yet


async def test_source_system_is_configurable(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}", source_system=42):
        m = await raw_peer.recv_type("HEARTBEAT")
        assert (m.get_srcSystem(), m.get_srcComponent()) == (42, 191)


async def test_learns_target_from_first_autopilot_heartbeat_and_filters(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")  # learn the link's address
        mine = link.subscribe("MISSION_CURRENT")
        everything = link.subscribe("MISSION_CURRENT", any_source=True)
        # a GCS (autopilot INVALID) is not a vehicle
        raw_peer.send(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_INVALID, vehicle=mavlink.MAV_TYPE_GCS), 255, 190)
        raw_peer.send(heartbeat(), 2, 1)
        raw_peer.send(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_PX4, vehicle=mavlink.MAV_TYPE_QUADROTOR), 3, 1)
        hb = await link.wait_heartbeat(2.0)
        assert hb.get_srcSystem() == 2
        assert (link.target_system, link.target_component) == (2, 1)
        assert link.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert link.vehicle_type == mavlink.MAV_TYPE_FIXED_WING
        assert link.heartbeat_age < 1.0
        raw_peer.send(mission_current(9), 3, 1)  # another vehicle
        raw_peer.send(mission_current(8), 2, 100)  # a camera on our vehicle
        raw_peer.send(mission_current(5), 2, 1)  # the autopilot
        assert (await mine.get(2.0)).seq == 5
        assert [(await everything.get(2.0)).seq for _ in range(3)] == [9, 8, 5]
        with pytest.raises(TimeoutError):
            await mine.get(0.2)
        mine.close()
        everything.close()
        assert link.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA  # PX4 heartbeat of system 3 ignored


async def test_given_target_system_wins(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}", target_system=3) as link:
        await raw_peer.recv_type("HEARTBEAT")
        raw_peer.send(heartbeat(), 2, 1)
        raw_peer.send(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_PX4, vehicle=mavlink.MAV_TYPE_QUADROTOR), 3, 1)
        await link.wait_heartbeat(2.0)
        assert (link.target_system, link.target_component, link.autopilot) == (3, 1, mavlink.MAV_AUTOPILOT_PX4)


async def test_subscribe_and_expect_are_live_before_the_request(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")
        raw_peer.send(heartbeat())
        await link.wait_heartbeat(2.0)
        # registered synchronously: an answer that arrives before we await is not lost
        ack = link.expect("COMMAND_ACK", predicate=lambda m: m.command == 400)
        sub = link.subscribe("MISSION_CURRENT")
        raw_peer.send(mavlink.MAVLink_command_ack_message(176, 0))  # other command: not it
        for seq in range(5):
            raw_peer.send(mission_current(seq))
        raw_peer.send(mavlink.MAVLink_command_ack_message(400, 0))
        got = await asyncio.wait_for(ack, 2.0)
        assert got.command == 400
        assert [(await sub.get(2.0)).seq for _ in range(5)] == [0, 1, 2, 3, 4]
        sub.close()
        assert not link._expectations and not link._subscriptions
        # a timed-out wait_for unregisters itself
        with pytest.raises(TimeoutError):
            await link.wait_for("COMMAND_ACK", timeout=0.1)
        assert not link._expectations
        # the async generator unsubscribes in its finally
        raw_peer.send(mission_current(7))
        raw_peer.send(mission_current(8))
        await asyncio.sleep(0.05)  # read and dropped: nobody subscribed
        seen = []
        gen = link.messages("MISSION_CURRENT")
        first = asyncio.ensure_future(gen.__anext__())
        await asyncio.sleep(0.05)  # the generator has subscribed
        raw_peer.send(mission_current(11))
        seen.append((await first).seq)
        await gen.aclose()
        assert seen == [11] and not link._subscriptions


async def test_wait_heartbeat_times_out_as_a_link_error(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")
        raw_peer.send(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_INVALID, vehicle=mavlink.MAV_TYPE_GCS), 255, 190)
        with pytest.raises(HeartbeatTimeout) as err:
            await link.wait_heartbeat(0.3)
        assert isinstance(err.value, LinkError) and isinstance(err.value, TimeoutError)
        assert link.target_system is None


async def test_close_fails_pending_waits():
    with_peer = Link("udpin:127.0.0.1:0")
    await with_peer.open()
    fut = with_peer.expect("HEARTBEAT")
    sub = with_peer.subscribe("HEARTBEAT")
    await with_peer.close()
    with pytest.raises(LinkError):
        await fut
    with pytest.raises(LinkError):
        await sub.get(1.0)
    await with_peer.close()  # idempotent


async def test_garbage_and_bad_crc_do_not_break_the_receive_path(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")
        good = raw_peer.pack(heartbeat())
        bad_crc = bytearray(raw_peer.pack(heartbeat()))
        bad_crc[-1] ^= 0xFF
        raw_peer.send_raw(b"Init ArduPlane V4.7.0-dev\r\nplain text, not MAVLink\n")
        raw_peer.send_raw(os.urandom(300))
        raw_peer.send_raw(bytes(bad_crc))
        raw_peer.send_raw(b"\xfd\xff\x00")  # truncated header
        raw_peer.send_raw(b"junk" + good)  # a good frame behind garbage in the same datagram
        # a stray 0xFD in the garbage can announce a long frame, so the stream parser may swallow the next
        # few hundred bytes before its CRC check fails and it resynchronises: keep talking, as a vehicle does
        hb = link.expect("HEARTBEAT")
        for _ in range(20):
            if hb.done():
                break
            raw_peer.send_raw(good)
            await asyncio.sleep(0.05)
        hb = await asyncio.wait_for(hb, 1.0)
        assert hb.get_srcSystem() == 1 and link.target_system == 1
        assert link.bad_packets > 0
        raw_peer.send(mission_current(3))
        assert (await link.wait_for("MISSION_CURRENT", timeout=2.0)).seq == 3


class TcpAutopilot:
    """A tiny SITL-like TCP MAVLink peer: greets every connection with plain text, then heartbeats at
    ``rate`` Hz; records what it receives; can drop connections and stop/start listening."""

    def __init__(self, rate: float = 10.0) -> None:
        self.rate = rate
        self.codec = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.parser = mavlink.MAVLink(None)
        self.parser.robust_parsing = True
        self.connections = 0
        self.received: list = []
        self.server: asyncio.Server | None = None
        self.port = 0
        self._writers: set[asyncio.StreamWriter] = set()
        self._handlers: set[asyncio.Task] = set()

    async def start(self) -> None:
        self.server = await asyncio.start_server(self._handle, "127.0.0.1", self.port)
        self.port = self.server.sockets[0].getsockname()[1]

    async def stop_listening(self) -> None:
        assert self.server is not None
        self.server.close()
        await self.server.wait_closed()
        self.server = None

    def drop_connections(self) -> None:
        for w in list(self._writers):
            w.close()

    async def close(self) -> None:
        if self.server is not None:
            await self.stop_listening()
        self.drop_connections()
        for t in list(self._handlers):
            t.cancel()
        await asyncio.gather(*self._handlers, return_exceptions=True)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self.connections += 1
        self._writers.add(writer)
        self._handlers.add(asyncio.current_task())
        sender = asyncio.create_task(self._heartbeats(writer))
        try:
            writer.write(b"Init ArduPlane V4.7.0-dev (plain text before MAVLink)\r\nFrame: PLANE\r\n")
            while data := await reader.read(4096):
                self.received += [m for m in self.parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            sender.cancel()
            await asyncio.gather(sender, return_exceptions=True)
            writer.close()
            self._writers.discard(writer)
            self._handlers.discard(asyncio.current_task())

    async def _heartbeats(self, writer: asyncio.StreamWriter) -> None:
        while not writer.is_closing():
            writer.write(heartbeat().pack(self.codec))
            await asyncio.sleep(1 / self.rate)


async def test_tcp_reconnects_after_peer_closes():
    ap = TcpAutopilot()
    await ap.start()
    try:
        async with Link(f"tcp:127.0.0.1:{ap.port}", reconnect_min=0.2) as link:
            await link.wait_heartbeat(2.0)  # through SITL's plain-text greeting
            assert link.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
            assert link.bad_packets > 0
            ap.drop_connections()
            await asyncio.sleep(0.05)
            assert not link.connected
            with pytest.raises(LinkError):
                link.send(heartbeat())
            sub = link.subscribe("HEARTBEAT")  # survives the reconnect
            await sub.get(3.0)
            assert link.connected and link.reconnects == 1 and ap.connections == 2
            await asyncio.sleep(1.2)
            ours = [m for m in ap.received if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 191]
            assert len(ours) >= 3  # greeting + 1 Hz, on both connections
            sub.close()
    finally:
        await ap.close()


async def test_tlog_records_both_ways_in_one_file_across_a_reconnect(tmp_path):
    """With ``tlog``, every message sent and parsed goes to one .tlog across a TCP reconnect, which pymavlink reads
    back: our HEARTBEATs (greetings on both connections, link 3) and the autopilot's (link 0), times never going
    backwards; the autopilot's plain-text greeting (garbage) is not recorded; the file is closed with the link."""
    from pymavlink import mavutil

    path = tmp_path / "flight.tlog"
    ap = TcpAutopilot()
    await ap.start()
    try:
        async with Link(f"tcp:127.0.0.1:{ap.port}", reconnect_min=0.2, tlog=path) as link:
            await link.wait_heartbeat(2.0)
            assert link.bad_packets > 0  # the greeting text
            ap.drop_connections()
            await asyncio.sleep(0.05)
            with link.subscribe("HEARTBEAT") as sub:
                await sub.get(3.0)
            link.send(mission_current(7))
            assert link.reconnects == 1 and ap.connections == 2
        assert link.tlog is not None and link.tlog._file is None  # closed with the link
    finally:
        await ap.close()
    log = mavutil.mavlink_connection(str(path))
    msgs = []
    while (m := log.recv_match()) is not None:
        msgs.append(m)
    log.close()
    assert msgs and "BAD_DATA" not in {m.get_type() for m in msgs}
    times = [m._timestamp for m in msgs]
    assert times == sorted(times)
    ours = [m for m in msgs if m.get_srcComponent() == 191]
    assert {m._link for m in ours} == {3} and {m._link for m in msgs if m.get_srcComponent() == 1} == {0}
    assert sum(m.get_type() == "HEARTBEAT" for m in ours) >= 2  # a greeting on each connection
    assert [m.seq for m in ours if m.get_type() == "MISSION_CURRENT"] == [7]
    assert sum(m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1 for m in msgs) >= 2
    assert link.tlog.records == len(msgs)


async def test_tcp_reconnect_backs_off_exponentially_with_a_cap(caplog):
    caplog.set_level(logging.INFO, logger="companion.mavlink.link")
    ap = TcpAutopilot()
    await ap.start()
    try:
        async with Link(f"tcp:127.0.0.1:{ap.port}", reconnect_min=0.1, reconnect_max=0.4) as link:
            await link.wait_heartbeat(2.0)
            await ap.stop_listening()
            ap.drop_connections()
            await asyncio.sleep(1.6)  # tries at ~0.1, 0.3, 0.7, 1.1, 1.5: all refused
            delays = [float(r.getMessage().split("next try in ")[1].split()[0])
                      for r in caplog.records if "next try in" in r.getMessage()]
            assert delays[:4] == [0.2, 0.4, 0.4, 0.4], delays
            await ap.start()  # same port again
            await link.wait_for("HEARTBEAT", timeout=3.0)
            assert link.reconnects == 1
    finally:
        await ap.close()


async def test_open_fails_cleanly_when_nothing_listens():
    ap = TcpAutopilot()
    await ap.start()
    port = ap.port
    await ap.close()
    with pytest.raises(LinkError):
        async with Link(f"tcp:127.0.0.1:{port}"):
            pass
