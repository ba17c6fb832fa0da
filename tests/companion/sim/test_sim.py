"""The built-in simulated autopilot over real UDP/TCP sockets on 127.0.0.1 (no mocks)."""

from __future__ import annotations

import asyncio
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pymap3d
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.items import FRAME_REL_ALT_INT, MissionItem, compare_items
from companion.mavlink.storage import Firmware, stored
from companion.sim import COPTER_MODES, PLANE_MODES, SimAutopilot, serve
from companion.sim.autopilot import PREARM_TEXT
from companion.sim.transport import new_mavlink
from planner.world.scenario import Scenario, load_scenario

SCENARIOS = Path(__file__).resolve().parents[3] / "sitl_scenarios"
ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
MISSION_ACCEPTED = mavlink.MAV_MISSION_ACCEPTED
ERROR_AFTER_FINAL = -1  # Client.upload: final ACK lost, the repeated item got MAV_MISSION_ERROR
BOOTING = (mavlink.MAV_STATE_UNINIT, mavlink.MAV_STATE_BOOT, mavlink.MAV_STATE_CALIBRATING)
PLANE = Firmware.ARDUPLANE  # how the simulated plane stores items (its readback)


def booted(msg: mavlink.MAVLink_message) -> bool:
    """A HEARTBEAT of the autopilot (not of another component, e.g. an ADS-B receiver) done booting."""
    return msg.get_srcComponent() == mavlink.MAV_COMP_ID_AUTOPILOT1 and msg.system_status not in BOOTING


@pytest.fixture(scope="module")
def static() -> Scenario:
    return load_scenario(SCENARIOS / "rescue_static.toml")


@pytest.fixture(scope="module")
def dynamic() -> Scenario:
    return load_scenario(SCENARIOS / "rescue_dynamic.toml")


class Client:
    """A small asyncio MAVLink 2 client (a GCS/companion stand-in) with an inbox it can wait on. Like a companion
    it waits, on entry, for the autopilot to have finished booting (unless ``wait_booted`` is False)."""

    def __init__(self, port: int, sysid: int = 1, compid: int = 191, wait_booted: bool = True) -> None:
        self.port = port
        self.wait_booted = wait_booted
        self.mav = new_mavlink(sysid, compid)
        self.inbox: list[mavlink.MAVLink_message] = []
        self.cursor = 0
        self._arrived = asyncio.Event()
        self._transport: asyncio.DatagramTransport | None = None

    async def __aenter__(self) -> Client:
        client = self

        class Proto(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: object) -> None:
                for msg in client.mav.parse_buffer(data) or []:
                    client.inbox.append(msg)
                client._arrived.set()

        self._transport, _ = await asyncio.get_running_loop().create_datagram_endpoint(
            Proto, remote_addr=("127.0.0.1", self.port))
        self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                                                    mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        await self.expect("HEARTBEAT", timeout=5.0)
        if self.wait_booted:
            await self.expect("HEARTBEAT", timeout=5.0, where=booted, after=0)
        return self

    async def __aexit__(self, *exc: object) -> None:
        assert self._transport is not None
        self._transport.close()

    def send(self, msg: mavlink.MAVLink_message) -> None:
        assert self._transport is not None
        self._transport.sendto(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256

    async def expect(self, kind: str | tuple[str, ...], timeout: float = 2.0,
                     where: Callable[[mavlink.MAVLink_message], bool] = lambda m: True,
                     after: int | None = None) -> mavlink.MAVLink_message:
        """First message of ``kind`` matching ``where`` after ``after`` (default: the last one returned)."""
        kinds = (kind,) if isinstance(kind, str) else kind
        loop = asyncio.get_running_loop()
        deadline = loop.time() + timeout
        i = self.cursor if after is None else after
        while True:
            while i < len(self.inbox):
                msg = self.inbox[i]
                i += 1
                if msg.get_type() in kinds and where(msg):
                    self.cursor = i
                    return msg
            remaining = deadline - loop.time()
            if remaining <= 0:
                raise TimeoutError(f"no {kinds} within {timeout} s")
            self._arrived.clear()
            try:
                await asyncio.wait_for(self._arrived.wait(), remaining)
            except TimeoutError:
                pass

    def mark(self) -> int:
        return len(self.inbox)

    async def command(self, command: int, *params: float, timeout: float = 2.0) -> int:
        mark = self.mark()
        p = list(params) + [0.0] * (7 - len(params))
        self.send(mavlink.MAVLink_command_long_message(1, 1, command, 0, *p))
        ack = await self.expect("COMMAND_ACK", timeout, lambda m: m.command == command, after=mark)
        return ack.result

    async def command_int(self, command: int, p1: float, p2: float, p3: float, p4: float, lat: float, lon: float,
                          alt: float, timeout: float = 2.0) -> int:
        """COMMAND_INT in MAV_FRAME_GLOBAL_RELATIVE_ALT_INT; the result of its COMMAND_ACK."""
        mark = self.mark()
        self.send(mavlink.MAVLink_command_int_message(1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command, 0, 0,
                                                      p1, p2, p3, p4, round(lat * 1e7), round(lon * 1e7), alt))
        ack = await self.expect("COMMAND_ACK", timeout, lambda m: m.command == command, after=mark)
        return ack.result

    async def set_mode(self, custom_mode: int) -> int:
        return await self.command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                  custom_mode)

    async def wait_ready(self, timeout: float = 5.0) -> None:
        """Ask for every stream at 2 Hz (an ArduCopter sends nothing unasked), then wait for a good EKF."""
        mark = self.mark()
        self.send(mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_ALL, 2, 1))
        await self.expect("EKF_STATUS_REPORT", timeout, lambda m: m.flags == 0x33F, after=mark)

    async def upload(self, items: list[MissionItem], mission_type: int = 0, retry_s: float = 0.25,
                     max_retries: int = 40) -> int:
        """Upload like a patient client: resend the last message on silence; INVALID_SEQUENCE is not fatal."""
        last: mavlink.MAVLink_message = mavlink.MAVLink_mission_count_message(1, 1, len(items), mission_type)
        self.send(last)
        retries = final_sends = 0
        mark = self.mark()
        while True:
            try:
                msg = await self.expect(("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"), retry_s,
                                        lambda m: m.mission_type == mission_type, after=mark)
            except TimeoutError:
                retries += 1
                assert retries <= max_retries, "upload: no answer"
                mark = self.mark()
                self.send(last)
                final_sends += last.get_type() == "MISSION_ITEM_INT" and last.seq == len(items) - 1
                continue
            mark = self.cursor
            if msg.get_type() == "MISSION_ACK":
                if msg.type == mavlink.MAV_MISSION_INVALID_SEQUENCE:
                    continue
                if msg.type == mavlink.MAV_MISSION_ERROR and final_sends > 1:
                    # the ACCEPTED for our final item was lost and the repeat found no upload running (what
                    # ArduPilot does too): the outcome is unknown, only a readback can tell
                    return ERROR_AFTER_FINAL
                return msg.type
            retries = 0
            last = items[msg.seq].to_message(1, 1)
            self.send(last)
            final_sends += msg.seq == len(items) - 1

    async def download(self, mission_type: int = 0, legacy: bool = False, retry_s: float = 0.25,
                       max_retries: int = 40) -> list[mavlink.MAVLink_message]:
        request: mavlink.MAVLink_message = mavlink.MAVLink_mission_request_list_message(1, 1, mission_type)
        count_msg = await self._ask(request, "MISSION_COUNT", lambda m: True, retry_s, max_retries)
        out = []
        for seq in range(count_msg.count):
            cls = mavlink.MAVLink_mission_request_message if legacy else mavlink.MAVLink_mission_request_int_message
            kind = "MISSION_ITEM" if legacy else "MISSION_ITEM_INT"
            out.append(await self._ask(cls(1, 1, seq, mission_type), kind, lambda m, s=seq: m.seq == s, retry_s,
                                       max_retries))
        self.send(mavlink.MAVLink_mission_ack_message(1, 1, MISSION_ACCEPTED, mission_type))
        return out

    async def _ask(self, request: mavlink.MAVLink_message, kind: str, where: Callable[..., bool], retry_s: float,
                   max_retries: int) -> mavlink.MAVLink_message:
        for _ in range(max_retries):
            mark = self.mark()
            self.send(request)
            try:
                return await self.expect(kind, retry_s, where, after=mark)
            except TimeoutError:
                continue
        raise TimeoutError(f"no {kind}")


def item(seq: int, command: int, enu: tuple[float, float, float] = (0.0, 0.0, 0.0), *, scenario: Scenario,
         frame: int = FRAME_REL_ALT_INT, **params: float) -> MissionItem:
    h = scenario.home
    if enu[:2] == (0.0, 0.0):
        x = y = 0
    else:
        lat, lon, _ = pymap3d.enu2geodetic(enu[0], enu[1], 0.0, h.lat, h.lon, h.alt)
        x, y = round(float(lat) * 1e7), round(float(lon) * 1e7)
    return MissionItem(seq, frame, command, x=x, y=y, z=enu[2], **params)


def route(scenario: Scenario, points: list[tuple[float, float, float]], speed: float = 18.0) -> list[MissionItem]:
    """home, TAKEOFF 50 m, DO_CHANGE_SPEED, then one NAV_WAYPOINT per point."""
    items = [item(0, mavlink.MAV_CMD_NAV_WAYPOINT, scenario=scenario),
             item(1, mavlink.MAV_CMD_NAV_TAKEOFF, (0.0, 0.0, 50.0), scenario=scenario),
             item(2, mavlink.MAV_CMD_DO_CHANGE_SPEED, scenario=scenario, frame=mavlink.MAV_FRAME_MISSION,
                  param1=0.0, param2=speed, param3=-1.0)]
    items += [item(3 + i, mavlink.MAV_CMD_NAV_WAYPOINT, p, scenario=scenario) for i, p in enumerate(points)]
    return items


THREE_WPS = [(200.0, 200.0, 50.0), (500.0, 450.0, 80.0), (800.0, 800.0, 50.0)]


# --- link and identity --------------------------------------------------------------------------------------


@pytest.mark.asyncio
@pytest.mark.parametrize("vehicle, mav_type, mode", [
    ("plane", mavlink.MAV_TYPE_FIXED_WING, PLANE_MODES["MANUAL"]),
    ("copter", mavlink.MAV_TYPE_QUADROTOR, COPTER_MODES["STABILIZE"]),
])
async def test_heartbeat_identifies_an_ardupilot_vehicle(static: Scenario, vehicle: str, mav_type: int,
                                                         mode: int) -> None:
    async with SimAutopilot(static, "udpin:127.0.0.1:0", vehicle=vehicle) as sim, Client(sim.port) as gcs:
        hb = await gcs.expect("HEARTBEAT", where=booted, after=0)
        assert (hb.type, hb.autopilot, hb.custom_mode) == (mav_type, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mode)
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, mavlink.MAV_COMP_ID_AUTOPILOT1)
        assert hb.get_msgbuf()[0] == 0xFD  # MAVLink 2
        assert sim.port != 0


@pytest.mark.asyncio
async def test_tcp_server_streams_mavlink(static: Scenario) -> None:
    async with SimAutopilot(static, "tcp:127.0.0.1:0", speedup=5.0) as sim:
        reader, writer = await asyncio.open_connection("127.0.0.1", sim.port)
        parser = new_mavlink(255, 190)
        try:
            msgs: list[mavlink.MAVLink_message] = []
            while not any(m.get_type() == "HEARTBEAT" for m in msgs):
                msgs += parser.parse_buffer(await asyncio.wait_for(reader.read(4096), 3.0)) or []
        finally:
            writer.close()
            await writer.wait_closed()


@pytest.mark.asyncio
async def test_stop_leaves_no_tasks_and_frees_the_port(static: Scenario) -> None:
    sim = SimAutopilot(static, "udpin:127.0.0.1:0")
    await sim.start()
    port = sim.port
    await sim.stop()
    assert not [t for t in asyncio.all_tasks() if t.get_name().startswith("sim-")]
    async with SimAutopilot(static, f"udpin:127.0.0.1:{port}") as again:
        assert again.port == port


# --- mission protocol ---------------------------------------------------------------------------------------


@pytest.mark.asyncio
async def test_upload_uses_legacy_requests_and_download_normalises_frames(static: Scenario) -> None:
    items = route(static, THREE_WPS)
    async with SimAutopilot(static, "udpin:127.0.0.1:0") as sim, Client(sim.port) as gcs:
        mark = gcs.mark()
        assert await gcs.upload(items) == MISSION_ACCEPTED
        requests = [m.get_type() for m in gcs.inbox[mark:] if m.get_type().startswith("MISSION_REQUEST")]
        assert requests and set(requests) == {"MISSION_REQUEST"}
        await gcs.wait_ready()  # home is set (item 0 reads back as zeros before)
        got = await gcs.download()
        assert len(got) == len(items)
        home = got[0]
        assert home.frame == mavlink.MAV_FRAME_GLOBAL
        assert (home.x, home.y) == (round(static.home.lat * 1e7), round(static.home.lon * 1e7))
        assert home.z == pytest.approx(static.home.alt)
        for sent, msg in zip(items[1:], got[1:]):  # as ArduPlane stores them: DO_CHANGE_SPEED in frame GLOBAL
            assert msg.frame in (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL)
            assert compare_items(stored(sent, PLANE), MissionItem.from_message(msg)) is None
        legacy = await gcs.download(legacy=True)
        assert [m.get_type() for m in legacy] == ["MISSION_ITEM"] * len(items)
        assert legacy[3].x == pytest.approx(items[3].lat, abs=1e-6)
        assert [i.command for i in sim.mission] == [i.command for i in items]


@pytest.mark.asyncio
async def test_bad_items_are_refused_with_arduPilot_results(static: Scenario) -> None:
    base = route(static, THREE_WPS)
    nan_param1 = base[:3] + [item(3, mavlink.MAV_CMD_NAV_WAYPOINT, THREE_WPS[0], scenario=static, param1=math.nan)]
    nan_param4 = base[:3] + [item(3, mavlink.MAV_CMD_NAV_WAYPOINT, THREE_WPS[0], scenario=static, param4=math.nan)]
    local_ned = base[:3] + [item(3, mavlink.MAV_CMD_NAV_WAYPOINT, THREE_WPS[0], scenario=static,
                                 frame=mavlink.MAV_FRAME_LOCAL_NED)]
    async with SimAutopilot(static, "udpin:127.0.0.1:0") as sim, Client(sim.port) as gcs:
        assert await gcs.upload(nan_param1) == mavlink.MAV_MISSION_INVALID_PARAM1
        assert await gcs.upload(local_ned) == mavlink.MAV_MISSION_UNSUPPORTED_FRAME
        assert await gcs.upload(nan_param4) == MISSION_ACCEPTED  # NaN yaw on a NAV command is fine


@pytest.mark.asyncio
async def test_second_sender_is_denied_during_an_upload(static: Scenario) -> None:
    items = route(static, THREE_WPS)
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=1.0) as sim, Client(sim.port) as a,
                Client(sim.port, sysid=255, compid=190) as b):
        mark = a.mark()
        a.send(mavlink.MAVLink_mission_count_message(1, 1, len(items), 0))
        req = await a.expect("MISSION_REQUEST", after=mark)
        assert req.seq == 0 and (req.target_system, req.target_component) == (1, 191)
        mark_b = b.mark()
        b.send(mavlink.MAVLink_mission_count_message(1, 1, 2, 0))
        ack = await b.expect("MISSION_ACK", where=lambda m: m.target_system == 255, after=mark_b)
        assert ack.type == mavlink.MAV_MISSION_DENIED
        b.send(items[0].to_message(1, 1))
        ack = await b.expect("MISSION_ACK", where=lambda m: m.target_system == 255, after=b.cursor)
        assert ack.type == mavlink.MAV_MISSION_DENIED
        a.send(items[0].to_message(1, 1))  # the first uploader carries on
        for seq in range(1, len(items)):
            req = await a.expect("MISSION_REQUEST", where=lambda m, s=seq: m.seq == s and m.target_system == 1)
            a.send(items[seq].to_message(1, 1))
        ack = await a.expect("MISSION_ACK", where=lambda m: m.target_system == 1)
        assert ack.type == MISSION_ACCEPTED
        assert len(sim.mission) == len(items)


@pytest.mark.asyncio
async def test_failed_upload_leaves_old_and_new_items_mixed(static: Scenario) -> None:
    old = route(static, [(100.0, 100.0, 60.0), (200.0, 200.0, 60.0), (300.0, 300.0, 60.0)])
    new = route(static, [(600.0, 100.0, 90.0), (700.0, 200.0, 90.0), (800.0, 300.0, 90.0)])
    broken = new[:4] + [MissionItem(**{**new[4].__dict__, "param1": math.nan})] + new[5:]
    async with SimAutopilot(static, "udpin:127.0.0.1:0") as sim, Client(sim.port) as gcs:
        assert await gcs.upload(old) == MISSION_ACCEPTED
        assert await gcs.upload(broken) == mavlink.MAV_MISSION_INVALID_PARAM1
        got = [MissionItem.from_message(m) for m in await gcs.download()]
        assert len(got) == len(old)
        assert compare_items(new[3], got[3]) is None  # written before the failure
        assert compare_items(old[4], got[4]) is None  # left from the old mission
        assert compare_items(old[5], got[5]) is None
        assert sim.mission[3].x == new[3].x and sim.mission[4].x == old[4].x


@pytest.mark.asyncio
async def test_upload_times_out_on_simulated_time(static: Scenario) -> None:
    async with SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs:
        mark = gcs.mark()
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        gcs.send(mavlink.MAVLink_mission_count_message(1, 1, 4, 0))
        ack = await gcs.expect("MISSION_ACK", timeout=3.0, after=mark)
        assert ack.type == mavlink.MAV_MISSION_OPERATION_CANCELLED
        assert loop.time() - t0 < 2.0  # 8 s of sim time at 20x
        requests = [m for m in gcs.inbox[mark:] if m.get_type() == "MISSION_REQUEST"]
        assert len(requests) >= 5 and {m.seq for m in requests} == {0}
        await gcs.expect("STATUSTEXT", where=lambda m: "upload timeout" in m.text, after=mark)


@pytest.mark.asyncio
async def test_lossy_link_still_lets_a_patient_client_upload(static: Scenario) -> None:
    items = route(static, THREE_WPS)
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", loss=0.3, latency_s=0.01, seed=7) as sim,
                Client(sim.port) as gcs):
        for _ in range(5):
            if await gcs.upload(items, retry_s=0.1, max_retries=60) in (MISSION_ACCEPTED, ERROR_AFTER_FINAL):
                readback = [MissionItem.from_message(m) for m in await gcs.download(retry_s=0.1, max_retries=60)]
                if len(readback) == len(items) and all(
                        compare_items(stored(a, PLANE), b) is None for a, b in zip(items[1:], readback[1:])):
                    break
        else:
            pytest.fail("no verified upload in 5 attempts")
        assert [compare_items(stored(a, PLANE), b) for a, b in zip(items[1:], sim.mission[1:])] \
            == [None] * (len(items) - 1)


@pytest.mark.asyncio
async def test_partial_write_and_atomic_fence(static: Scenario) -> None:
    items = route(static, THREE_WPS)
    moved = item(4, mavlink.MAV_CMD_NAV_WAYPOINT, (450.0, 500.0, 90.0), scenario=static)
    fence = [MissionItem(i, mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, param1=80.0,
                         x=items[3 + i].x, y=items[3 + i].y, mission_type=mavlink.MAV_MISSION_TYPE_FENCE)
             for i in range(2)]
    async with SimAutopilot(static, "udpin:127.0.0.1:0") as sim, Client(sim.port) as gcs:
        assert await gcs.upload(items) == MISSION_ACCEPTED
        mark = gcs.mark()
        gcs.send(mavlink.MAVLink_mission_write_partial_list_message(1, 1, 4, 4, 0))
        req = await gcs.expect("MISSION_REQUEST", after=mark)
        assert req.seq == 4
        gcs.send(moved.to_message(1, 1))
        assert (await gcs.expect("MISSION_ACK", after=mark)).type == MISSION_ACCEPTED
        assert compare_items(moved, sim.mission[4]) is None and len(sim.mission) == len(items)
        assert await gcs.upload(fence, mission_type=mavlink.MAV_MISSION_TYPE_FENCE) == MISSION_ACCEPTED
        bad = [fence[0], MissionItem(**{**fence[1].__dict__, "frame": mavlink.MAV_FRAME_LOCAL_NED})]
        result = await gcs.upload(bad, mission_type=mavlink.MAV_MISSION_TYPE_FENCE)
        assert result == mavlink.MAV_MISSION_UNSUPPORTED_FRAME
        assert sim.fence == [stored(f, PLANE) for f in fence]  # replaced only by a complete upload
        assert len(await gcs.download(mavlink.MAV_MISSION_TYPE_FENCE)) == 2


@pytest.mark.asyncio
async def test_serve_runs_for_the_given_simulated_time(static: Scenario) -> None:
    loop = asyncio.get_running_loop()
    t0 = loop.time()
    await asyncio.wait_for(serve(static, "udpin:127.0.0.1:0", speedup=20.0, until=4.0), 3.0)
    assert loop.time() - t0 < 1.5
    assert not [t for t in asyncio.all_tasks() if t.get_name().startswith("sim-")]


# --- arming and modes ---------------------------------------------------------------------------------------


@pytest.mark.asyncio
async def test_arming_is_refused_until_the_vehicle_is_ready(static: Scenario) -> None:
    # ready 1.5 s (wall) after start, not the default 0.5 s: on a loaded CI host the first command has come later
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=4.0, ready_after_s=6.0) as sim,
                Client(sim.port) as gcs):
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_FAILED
        await gcs.expect("STATUSTEXT", where=lambda m: m.text == PREARM_TEXT["plane"], after=mark)
        gps = await gcs.expect("GPS_RAW_INT", after=0)
        assert gps.fix_type == 0
        await gcs.wait_ready()
        await gcs.expect("GPS_RAW_INT", where=lambda m: m.fix_type >= 3, after=gcs.mark())
        await gcs.expect("SYS_STATUS", where=lambda m: m.onboard_control_sensors_health & 0x10000000,
                         after=gcs.mark())
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        assert sim.armed
        hb = await gcs.expect("HEARTBEAT", after=gcs.mark())
        assert hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        assert await gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION) == ACCEPTED
        home = await gcs.expect("HOME_POSITION", after=0)
        assert home.altitude == round(static.home.alt * 1000)
        assert await gcs.command(31999) == mavlink.MAV_RESULT_UNSUPPORTED


@pytest.mark.asyncio
async def test_copter_refuses_to_arm_in_auto_and_plane_does_not(static: Scenario) -> None:
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0, vehicle="copter") as sim,
                Client(sim.port) as gcs):
        await gcs.wait_ready()
        assert await gcs.set_mode(COPTER_MODES["AUTO"]) == ACCEPTED
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_FAILED
        await gcs.expect("STATUSTEXT", where=lambda m: "AUTO mode not armable" in m.text, after=mark)
        assert await gcs.set_mode(COPTER_MODES["GUIDED"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        assert sim.mode == "GUIDED" and sim.armed
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs):
        assert await gcs.upload(route(static, THREE_WPS)) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        assert sim.armed and sim.mode == "AUTO" and sim.current_seq == 1  # taking off at once


# --- flight -------------------------------------------------------------------------------------------------


@pytest.mark.asyncio
async def test_plane_flies_three_waypoints_and_returns(static: Scenario) -> None:
    items = route(static, THREE_WPS)
    async with SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs:
        assert await gcs.upload(items) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        for seq in range(2, len(items)):  # not 1: the DO_CHANGE_SPEED after TAKEOFF is reported in its place
            await gcs.expect("MISSION_ITEM_REACHED", timeout=8.0, where=lambda m, s=seq: m.seq == s, after=mark)
        await gcs.expect("STATUSTEXT", timeout=2.0, after=mark,
                         where=lambda m: m.text == "Mission complete, changing mode to RTL")
        hb = await gcs.expect("HEARTBEAT", after=gcs.mark())
        assert hb.custom_mode == PLANE_MODES["RTL"]
        pos = await gcs.expect("GLOBAL_POSITION_INT", after=gcs.mark())
        assert pos.relative_alt > 40_000 and pos.alt - pos.relative_alt == round(static.home.alt * 1000)
        truth = sim.truth
        assert max(b[0] - a[0] for a, b in zip(truth, truth[1:])) <= 0.2 + 1e-6
        # each waypoint was passed within its acceptance radius or beyond it along the track
        for wp in THREE_WPS:
            assert min(math.hypot(t[4] - wp[0], t[5] - wp[1]) for t in truth) < 60.0
        # as in ArduPilot, the DO command after TAKEOFF runs (and is reached) when the take-off is complete
        assert sim.reached[: len(items) - 1] == [1, 2, 3, 4, 5]
        assert not [m for m in gcs.inbox[mark:] if m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 1]


@pytest.mark.asyncio
async def test_reupload_in_flight_keeps_the_active_item_until_set_current(static: Scenario) -> None:
    first = route(static, [(0.0, 900.0, 60.0), (900.0, 900.0, 60.0)])
    second = route(static, [(900.0, 0.0, 60.0), (900.0, 900.0, 60.0)])
    async with SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs:
        assert await gcs.upload(first) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        await gcs.expect("MISSION_CURRENT", timeout=5.0, where=lambda m: m.seq == 3, after=0)
        assert await gcs.upload(second) == MISSION_ACCEPTED
        assert sim.mission[3].x == second[3].x
        assert sim.current_seq == 3 and sim.active_item is not None and sim.active_item.y == first[3].y
        assert await gcs.command(mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, 3) == ACCEPTED
        assert sim.active_item is not None and sim.active_item.y == second[3].y
        await gcs.expect("MISSION_CURRENT", where=lambda m: m.seq == 3, after=gcs.mark())


@pytest.mark.asyncio
async def test_copter_takes_off_in_guided_then_runs_the_mission(static: Scenario) -> None:
    items = route(static, [(30.0, 40.0, 30.0)], speed=10.0)
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0, vehicle="copter") as sim,
                Client(sim.port) as gcs):
        assert await gcs.upload(items) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(COPTER_MODES["GUIDED"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_MISSION_START) == ACCEPTED
        for seq in range(2, len(items)):  # the take-off (1) is reported as the DO command after it (2)
            await gcs.expect("MISSION_ITEM_REACHED", timeout=5.0, where=lambda m, s=seq: m.seq == s, after=mark)
        x, y, z = sim.position
        assert math.dist((x, y, z), (30.0, 40.0, 30.0)) < static.vehicle.acceptance_radius
        assert sim.mode == "AUTO"  # a copter holds after the last item


@pytest.mark.asyncio
async def test_intruders_are_reported_as_adsb_vehicles(dynamic: Scenario) -> None:
    items = route(dynamic, THREE_WPS)
    intruder = dynamic.intruders[0]
    async with SimAutopilot(dynamic, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs:
        assert await gcs.upload(items) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        adsb = await gcs.expect("ADSB_VEHICLE", timeout=5.0, after=0)
        assert adsb.ICAO_address == intruder.icao
        assert adsb.callsign == intruder.id[:9]
        if intruder.meet is None:
            assert adsb.hor_velocity == round(intruder.speed * 100)
        else:  # timed by the vehicle's progress: faster or slower to keep the appointment
            assert 0.5 * intruder.speed <= adsb.hor_velocity / 100 <= 2.0 * intruder.speed
        assert adsb.flags & mavlink.ADSB_FLAGS_VALID_COORDS and adsb.flags & mavlink.ADSB_FLAGS_VALID_ALTITUDE
        assert adsb.altitude == round((dynamic.home.alt + intruder.waypoints[0][2]) * 1000)
        assert 0 <= adsb.heading < 36000
        await sim.run_until(sim.sim_time + 1.0)
        track = sim.intruder_truth[intruder.id]
        mission_t0 = sim.sim_time - sim.mission_time
        assert track and track[0][0] - mission_t0 >= intruder.start_time
        assert math.dist(track[0][1:], intruder.waypoints[0]) < intruder.speed * 0.5


def _radius_flown(sim: SimAutopilot, centre: tuple[float, float], since: float) -> tuple[float, float]:
    """(median, max) distance of the truth track from ``centre`` after sim time ``since``."""
    d = [math.hypot(t[4] - centre[0], t[5] - centre[1]) for t in sim.truth if t[0] >= since]
    return float(np.median(d)), max(d)


@pytest.mark.asyncio
async def test_plane_loiter_circles_its_entry_point_at_wp_loiter_rad_as_set(static: Scenario) -> None:
    """ArduPlane's LOITER circles the point where the mode changed at |WP_LOITER_RAD| (SITL: 80 m); a PARAM_SET
    of WP_LOITER_RAD changes the circle, and PARAM_REQUEST_READ answers the flight parameters."""
    items = route(static, [(0.0, 900.0, 60.0), (900.0, 900.0, 60.0)])
    async with SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs:
        gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"ROLL_LIMIT_DEG", -1))
        roll = await gcs.expect("PARAM_VALUE", where=lambda m: m.param_id == "ROLL_LIMIT_DEG", after=0)
        assert roll.param_value == static.vehicle.max_bank_deg  # what the simulated plane banks to
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"WP_LOITER_RAD", 120.0, mavlink.MAV_PARAM_TYPE_INT16))
        await gcs.expect("PARAM_VALUE", where=lambda m: m.param_id == "WP_LOITER_RAD" and m.param_value == 120.0)
        assert await gcs.upload(items) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        await gcs.expect("MISSION_CURRENT", timeout=8.0, where=lambda m: m.seq == 3, after=0)
        x, y, _ = sim.position
        t0 = sim.sim_time
        assert await gcs.set_mode(PLANE_MODES["LOITER"]) == ACCEPTED
        await sim.run_until(t0 + 60.0)
        median, _ = _radius_flown(sim, (x, y), t0 + 25.0)
        assert abs(median - 136.0) < 8.0, median  # ArduPlane flies its circles ~16 m wider (test_hold_turn.py)


@pytest.mark.asyncio
async def test_plane_do_reposition_circles_the_given_centre_at_the_given_radius(static: Scenario) -> None:
    """MAV_CMD_DO_REPOSITION as ArduPlane takes it: refused outside GUIDED without the change-mode flag; with it,
    GUIDED and a circle of param3 around lat/lon (counter-clockwise with param4 set)."""
    items = route(static, [(0.0, 900.0, 60.0), (900.0, 900.0, 60.0)])
    centre = (300.0, 500.0)
    lat, lon, _ = pymap3d.enu2geodetic(*centre, 0.0, static.home.lat, static.home.lon, static.home.alt)
    async with SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs:
        assert await gcs.upload(items) == MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        await gcs.expect("MISSION_CURRENT", timeout=8.0, where=lambda m: m.seq == 3, after=0)
        assert await gcs.command(mavlink.MAV_CMD_DO_REPOSITION, -1, 1, 50.0, 1, lat, lon, 70.0) == \
            mavlink.MAV_RESULT_UNSUPPORTED  # as COMMAND_LONG (ArduPlane SITL)
        assert await gcs.command_int(mavlink.MAV_CMD_DO_REPOSITION, -1, 0, 50.0, 0, lat, lon, 70.0) == \
            mavlink.MAV_RESULT_FAILED  # in AUTO, without MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
        t0 = sim.sim_time
        assert await gcs.command_int(mavlink.MAV_CMD_DO_REPOSITION, -1, 1, 50.0, 1, lat, lon, 70.0) == ACCEPTED
        assert sim.mode == "GUIDED"
        await sim.run_until(t0 + 70.0)
        median, worst = _radius_flown(sim, centre, t0 + 45.0)
        assert abs(median - 66.0) < 6.0 and worst < 80.0, (median, worst)  # 16 m wider than asked, as ArduPlane
        assert abs(sim.position[2] - 70.0) < 5.0
        # counter-clockwise: the bearing from the centre increases anticlockwise (ENU angle grows)
        late = [t for t in sim.truth if t[0] >= t0 + 45.0][:20]
        ang = np.unwrap([math.atan2(t[5] - centre[1], t[4] - centre[0]) for t in late])
        assert ang[-1] > ang[0]
