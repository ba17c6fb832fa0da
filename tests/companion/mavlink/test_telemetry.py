"""companion.mavlink.telemetry over real sockets on 127.0.0.1: the companion asks for its message rates once the
autopilot is identified, again after every TCP reconnect and after a heartbeat loss, and carries on whatever the
autopilot answers (or does not). A raw UDP peer and a small TCP server play the autopilot and record what they receive.
The last test does the same against a real ArduPlane SITL on SERIAL1 and measures the rates."""

from __future__ import annotations

import asyncio
import logging

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import LinkError
from companion.mavlink.link import Link
from companion.mavlink.profiles import PX4_UNUSED_STREAMS
from companion.mavlink.telemetry import OFF, RATES, Rate, TelemetryRates, message_id, request_rates, stream_requests

pytestmark = pytest.mark.asyncio

# What the companion asks for, written out independently of the table: message id → interval (µs)
EXPECTED_INTERVALS = {
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 100_000,  # 10 Hz
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 500_000,  # 2 Hz
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1_000_000,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 1_000_000,
    mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT: 1_000_000,
    mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE: 200_000,  # 5 Hz
}
# ArduPilot's legacy stream groups holding them, at the highest rate of their members (whole Hz)
EXPECTED_STREAMS = {mavlink.MAV_DATA_STREAM_POSITION: 10, mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: 2,
                    mavlink.MAV_DATA_STREAM_EXTRA3: 1}
SET_INTERVAL = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL


def heartbeat(autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, vehicle=mavlink.MAV_TYPE_FIXED_WING):
    return mavlink.MAVLink_heartbeat_message(vehicle, autopilot, 0, 0, mavlink.MAV_STATE_STANDBY, 3)


def requests(received: list) -> tuple[list[tuple[int, int]], list[tuple[int, int]], list[str]]:
    """(stream requests as (stream, Hz), SET_MESSAGE_INTERVALs as (msg id, µs), the order of both kinds)."""
    streams = [(m.req_stream_id, m.req_message_rate) for m in received if m.get_type() == "REQUEST_DATA_STREAM"]
    intervals = [(int(m.param1), int(m.param2)) for m in received
                 if m.get_type() == "COMMAND_LONG" and m.command == SET_INTERVAL]
    order = [m.get_type() for m in received if m.get_type() in ("REQUEST_DATA_STREAM", "COMMAND_LONG")]
    return streams, intervals, order


class UdpAutopilot:
    """Plays the autopilot on the raw peer: records what the link sends and answers SET_MESSAGE_INTERVAL with
    ``answers.get(msg_id, ACCEPTED)`` (None: no answer at all)."""

    def __init__(self, peer, answers: dict[int, int | None] | None = None) -> None:
        self.peer = peer
        self.answers = answers or {}
        self.received: list = []
        self._task: asyncio.Task | None = None
        self._stopping = False

    async def __aenter__(self) -> UdpAutopilot:
        self._task = asyncio.create_task(self._serve())
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._task is not None
        self._stopping = True  # RawPeer.recv uses wait_for, which on 3.11 can swallow the cancellation
        self._task.cancel()
        await asyncio.gather(self._task, return_exceptions=True)

    async def _serve(self) -> None:
        while not self._stopping:
            try:
                msgs = await self.peer.recv(0.2)
            except TimeoutError:
                continue
            for m in msgs:
                self.received.append(m)
                if m.get_type() == "COMMAND_LONG" and m.command == SET_INTERVAL:
                    result = self.answers.get(int(m.param1), mavlink.MAV_RESULT_ACCEPTED)
                    if result is not None:
                        self.peer.send(mavlink.MAVLink_command_ack_message(SET_INTERVAL, result, 0, 0,
                                                                           m.get_srcSystem(), m.get_srcComponent()))


async def until(condition, timeout: float = 3.0) -> None:
    async with asyncio.timeout(timeout):
        while not condition():
            await asyncio.sleep(0.02)


async def test_rates_requested_once_the_autopilot_is_identified(raw_peer, caplog):
    caplog.set_level(logging.DEBUG, logger="companion.mavlink.telemetry")
    answers = {mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT: mavlink.MAV_RESULT_UNSUPPORTED,
               mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: mavlink.MAV_RESULT_DENIED,
               mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE: None}  # never answered
    logged: list[dict[str, str]] = []
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link, UdpAutopilot(raw_peer, answers) as ap:
        rates = TelemetryRates(link, ack_timeout=0.2, on_results=logged.append).start()
        await until(lambda: any(m.get_type() == "HEARTBEAT" for m in ap.received))
        await asyncio.sleep(0.3)
        assert requests(ap.received) == ([], [], [])  # nothing to ask before an autopilot is known
        raw_peer.send(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_INVALID, vehicle=mavlink.MAV_TYPE_GCS), 255, 190)
        await asyncio.sleep(0.2)
        assert rates.rounds == 0  # a ground station is not an autopilot
        raw_peer.send(heartbeat(), 1, 1)
        raw_peer.send(heartbeat(), 1, 1)  # the second HEARTBEAT of the same connection starts nothing
        await link.wait_heartbeat(2.0)
        await until(lambda: rates.rounds == 1)
        results = await rates.wait()
        streams, intervals, order = requests(ap.received)
        assert dict(streams) == EXPECTED_STREAMS and len(streams) == len(EXPECTED_STREAMS)
        assert dict(intervals) == EXPECTED_INTERVALS and len(intervals) == len(EXPECTED_INTERVALS)
        # the stream requests first: ArduPilot applies one to every message of its group, so a later one would
        # undo the per-message intervals
        assert order == ["REQUEST_DATA_STREAM"] * len(streams) + ["COMMAND_LONG"] * len(intervals)
        for m in ap.received:
            if m.get_type() in ("REQUEST_DATA_STREAM", "COMMAND_LONG"):
                assert (m.target_system, m.target_component) == (1, 1)
                assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 191)
        assert results == {"GLOBAL_POSITION_INT": "ACCEPTED", "MISSION_CURRENT": "ACCEPTED",
                           "SYS_STATUS": "ACCEPTED", "GPS_RAW_INT": "DENIED", "EKF_STATUS_REPORT": "UNSUPPORTED",
                           "ADSB_VEHICLE": "no answer"}
        assert logged == [results]
        assert rates.rounds == 1
        # refusals and silence are logged, and the link goes on as before
        assert any("GPS_RAW_INT" in r.getMessage() and r.levelno == logging.INFO for r in caplog.records)
        raw_peer.send(mavlink.MAVLink_mission_current_message(4), 1, 1)
        assert (await link.wait_for("MISSION_CURRENT", timeout=2.0)).seq == 4


async def test_px4_gets_no_ardupilot_stream_requests(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link, UdpAutopilot(raw_peer) as ap:
        await until(lambda: any(m.get_type() == "HEARTBEAT" for m in ap.received))
        raw_peer.send(heartbeat(autopilot=mavlink.MAV_AUTOPILOT_PX4, vehicle=mavlink.MAV_TYPE_QUADROTOR), 1, 1)
        await link.wait_heartbeat(2.0)
        rates = TelemetryRates(link, ack_timeout=0.2).start()  # started late: asks at once
        assert rates.rounds == 1
        assert set((await rates.wait()).values()) == {"ACCEPTED"}
        streams, intervals, _ = requests(ap.received)
        # the messages the companion does not read are turned off first (PX4 floods its onboard link)
        off = {message_id(name): OFF for name in PX4_UNUSED_STREAMS}
        assert streams == [] and intervals == [*off.items(), *EXPECTED_INTERVALS.items()]


async def test_rates_requested_again_when_the_heartbeat_comes_back(raw_peer):
    """An autopilot that rebooted behind a UDP link has forgotten the rates: ask again when it is back."""
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}", heartbeat_interval=0.1,
                    heartbeat_timeout=0.3) as link, UdpAutopilot(raw_peer) as ap:
        rates = TelemetryRates(link, ack_timeout=0.2).start()
        await until(lambda: any(m.get_type() == "HEARTBEAT" for m in ap.received))
        raw_peer.send(heartbeat(), 1, 1)
        await until(lambda: rates.rounds == 1)
        await rates.wait()
        await until(lambda: link.heartbeat_lost)  # silent for longer than heartbeat_timeout
        first = len(ap.received)
        raw_peer.send(heartbeat(), 1, 1)
        await until(lambda: rates.rounds == 2)
        await rates.wait()
        streams, intervals, _ = requests(ap.received[first:])
        assert dict(streams) == EXPECTED_STREAMS and dict(intervals) == EXPECTED_INTERVALS


async def test_a_round_in_progress_ends_with_the_link_and_stop_unregisters(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link, \
            UdpAutopilot(raw_peer, {msg_id: None for msg_id in EXPECTED_INTERVALS}) as ap:
        rates = TelemetryRates(link, ack_timeout=5.0).start()  # nothing is answered: a slow round
        await until(lambda: any(m.get_type() == "HEARTBEAT" for m in ap.received))
        raw_peer.send(heartbeat(), 1, 1)
        await until(lambda: len(requests(ap.received)[1]) == 1)
        task = rates._task
    # closing the link closed the round's subscription: the round is over (the leak check would see it)
    await asyncio.wait_for(asyncio.gather(task, return_exceptions=True), 1.0)
    assert task.done() and rates.results == {}
    rates.stop()
    assert not link._on_target


class TcpAutopilot:
    """A SITL-like TCP autopilot: greets each connection with plain text, heartbeats at 10 Hz, answers
    SET_MESSAGE_INTERVAL with ACCEPTED and records what arrives on each connection separately."""

    def __init__(self) -> None:
        self.codec = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.connections: list[list] = []
        self.server: asyncio.Server | None = None
        self._writers: set[asyncio.StreamWriter] = set()
        self._handlers: set[asyncio.Task] = set()

    async def start(self) -> int:
        self.server = await asyncio.start_server(self._handle, "127.0.0.1", 0)
        return self.server.sockets[0].getsockname()[1]

    def drop_connections(self) -> None:
        for w in list(self._writers):
            w.close()

    async def close(self) -> None:
        if self.server is not None:
            self.server.close()
            await self.server.wait_closed()
        self.drop_connections()
        for t in list(self._handlers):
            t.cancel()
        await asyncio.gather(*self._handlers, return_exceptions=True)

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        received: list = []
        self.connections.append(received)
        self._writers.add(writer)
        self._handlers.add(asyncio.current_task())
        parser = mavlink.MAVLink(None)
        parser.robust_parsing = True
        sender = asyncio.create_task(self._heartbeats(writer))
        try:
            writer.write(b"Init ArduPlane V4.7.0-dev\r\n")
            while data := await reader.read(4096):
                for m in parser.parse_buffer(data) or []:
                    if m.get_type() == "BAD_DATA":
                        continue
                    received.append(m)
                    if m.get_type() == "COMMAND_LONG" and m.command == SET_INTERVAL:
                        writer.write(mavlink.MAVLink_command_ack_message(
                            SET_INTERVAL, mavlink.MAV_RESULT_ACCEPTED, 0, 0, m.get_srcSystem(),
                            m.get_srcComponent()).pack(self.codec))
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
            await asyncio.sleep(0.1)


async def test_rates_requested_again_after_a_tcp_reconnect():
    ap = TcpAutopilot()
    port = await ap.start()
    try:
        async with Link(f"tcp:127.0.0.1:{port}", reconnect_min=0.2) as link:
            rates = TelemetryRates(link, ack_timeout=0.5).start()
            await link.wait_heartbeat(2.0)
            await until(lambda: rates.rounds == 1)
            assert set((await rates.wait()).values()) == {"ACCEPTED"}
            ap.drop_connections()
            # nothing to do for the caller: the link reconnects, hears the autopilot, and the rates follow
            await until(lambda: link.reconnects == 1 and rates.rounds == 2)
            assert set((await rates.wait()).values()) == {"ACCEPTED"}
            assert len(ap.connections) == 2
            for received in ap.connections:
                streams, intervals, _ = requests(received)
                assert dict(streams) == EXPECTED_STREAMS and len(streams) == len(EXPECTED_STREAMS)
                assert dict(intervals) == EXPECTED_INTERVALS and len(intervals) == len(EXPECTED_INTERVALS)
    finally:
        await ap.close()


async def test_table_helpers():
    assert {r.msg_id: r.interval_us for r in RATES} == EXPECTED_INTERVALS
    assert dict(stream_requests()) == EXPECTED_STREAMS
    # rounded up to whole Hz, the fastest member decides
    assert stream_requests([Rate("GPS_RAW_INT", 0.5, 2, ""), Rate("SYS_STATUS", 2.5, 2, "")]) == [(2, 3)]


async def test_request_rates_needs_a_target(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        with pytest.raises(LinkError, match="no target"):
            await request_rates(link)


# --- real ArduPlane SITL ---------------------------------------------------------------------------------------

SITL_HOME = (-35.363261, 149.165230, 584.0)  # CMAC, as the sitl_scenarios


async def _rates(link: Link, wall_s: float) -> dict[str, float]:
    """Messages per second of *autopilot* time (GLOBAL_POSITION_INT.time_boot_ms) over ``wall_s`` of wall time."""
    counts: dict[str, int] = {}
    boot: list[int] = []
    with link.subscribe("GLOBAL_POSITION_INT", "MISSION_CURRENT", "HEARTBEAT", "SYS_STATUS") as sub:
        loop = asyncio.get_running_loop()
        end = loop.time() + wall_s
        while (left := end - loop.time()) > 0:
            try:
                msg = await sub.get(left)
            except TimeoutError:
                break
            counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
            if msg.get_type() == "GLOBAL_POSITION_INT":
                boot.append(msg.time_boot_ms)
    span = (boot[-1] - boot[0]) / 1000.0
    assert span > 0, boot
    # messages between the first and the last position: count - 1 intervals for the position itself
    return {k: (v - (k == "GLOBAL_POSITION_INT")) / span for k, v in counts.items()}


async def test_arduplane_sitl_serial1_rates_before_and_after(sitl_factory_fn):
    """ArduPlane SITL at 10x, a ground station on SERIAL0, the companion's link on SERIAL1: ArduPilot streams
    everything there at 1 Hz of its own time until asked; after the requests (all ACCEPTED) the position comes at
    10 Hz, MISSION_CURRENT at 2 Hz, and the HEARTBEAT stays at 1 Hz. Measured by hand at 10x: GLOBAL_POSITION_INT
    10 Hz wall before, 100 Hz wall after."""
    sitl = sitl_factory_fn("plane", SITL_HOME, speedup=10.0)
    with sitl.hold_serial0():
        async with Link(sitl.serial1_url, open_timeout=10.0) as link:
            await link.wait_heartbeat(30.0)
            before = await _rates(link, 2.0)
            rates = TelemetryRates(link).start()
            results = await rates.wait()
            after = await _rates(link, 2.0)
    assert results == {r.message: "ACCEPTED" for r in RATES}
    assert before["GLOBAL_POSITION_INT"] == pytest.approx(1.0, abs=0.3), before
    assert after["GLOBAL_POSITION_INT"] == pytest.approx(10.0, abs=1.0), after
    assert before["MISSION_CURRENT"] == pytest.approx(1.0, abs=0.3), before
    assert after["MISSION_CURRENT"] == pytest.approx(2.0, abs=0.3), after
    assert after["SYS_STATUS"] == pytest.approx(1.0, abs=0.3), after
    assert before["HEARTBEAT"] == pytest.approx(1.0, abs=0.3) and after["HEARTBEAT"] == pytest.approx(1.0, abs=0.3)
