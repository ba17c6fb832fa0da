"""The simulated autopilot against what real ArduPilot does: every expected value here was measured on ArduPilot
4.7.0-dev SITL (the team's build, in the folder FUSEPLAN_SITL_DIR names; plane.parm / copter.parm, start.sh at
-35.363261,149.165230,584 heading 0, speed-up 10, a pymavlink client on SERIAL0), as the comments say. The real
autopilot is the judge: when SITL and these tests disagree, the simulator (and then this file, with the new
measurement) changes, never SITL.

Real UDP sockets on 127.0.0.1 through the test client of test_sim.py.
"""

from __future__ import annotations

import asyncio
import collections
import dataclasses
import math
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from test_sim import PLANE_MODES, Client, booted, dynamic, item, route, static  # noqa: F401  (the pytest fixtures of test_sim.py)

from companion.mavlink.items import FENCE, RALLY, MissionItem, compare_items
from companion.mavlink.storage import Firmware, stored
from companion.mission.builder import mission_from_plan_json
from companion.sim import SimAutopilot
from companion.sim.autopilot import BOOT_S, FIRST_HEARTBEAT_FRACTION, PREARM_TEXT
from planner.world.scenario import Scenario

ACCEPTED = mavlink.MAV_RESULT_ACCEPTED
DENIED = mavlink.MAV_RESULT_DENIED
FIRMWARE = {"plane": Firmware.ARDUPLANE, "copter": Firmware.ARDUCOPTER}
GPI = mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT


async def _count_to(gcs: Client, count: int, mission_type: int = 0) -> mavlink.MAVLink_message:
    """Send MISSION_COUNT; the autopilot's first answer (a request or an ACK)."""
    mark = gcs.mark()
    gcs.send(mavlink.MAVLink_mission_count_message(1, 1, count, mission_type))
    return await gcs.expect(("MISSION_REQUEST", "MISSION_ACK"), after=mark,
                            where=lambda m: m.mission_type == mission_type)


async def _download_count(gcs: Client) -> int:
    mark = gcs.mark()
    gcs.send(mavlink.MAVLink_mission_request_list_message(1, 1, 0))
    return (await gcs.expect("MISSION_COUNT", after=mark)).count


# --- boot ---------------------------------------------------------------------------------------------------
# SITL, client connected at power-up: plane first HEARTBEAT 0.93 s (sim) system_status 2 CALIBRATING, custom mode
# 16 INITIALISING, base_mode 17; STANDBY in MANUAL (base_mode 81) with "ArduPilot Ready" at 1.7 s. Copter first
# HEARTBEAT 0.9 s system_status 1 BOOT, mode 0, base_mode 89; STANDBY (81) at 2.5 s. Until then a mission upload
# gets MAV_MISSION_NO_SPACE + "Only 0 items are supported" (sent before the first HEARTBEAT: no answer at all), a
# fence upload no answer until "ArduPilot Ready" (then its first MISSION_REQUEST), arming COMMAND_ACK FAILED +
# "Arm: System not initialised". After boot, until
# home is set, a download says count 0 and arming fails with a pre-arm text ("Arm: AHRS: waiting for home" on the
# plane, mostly "Arm: Gyros inconsistent" on the copter).
BOOTING = {"plane": (mavlink.MAV_STATE_CALIBRATING, 16, 17), "copter": (mavlink.MAV_STATE_BOOT, 0, 89)}
STANDBY = (mavlink.MAV_STATE_STANDBY, 0, 81)


@pytest.mark.asyncio
@pytest.mark.parametrize("vehicle", ["plane", "copter"])
async def test_boot_phase_as_sitl(static: Scenario, vehicle: str) -> None:  # noqa: F811 - the fixture imported from test_sim
    speedup = 2.0
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=speedup, vehicle=vehicle, boot_s=None,
                             streams_unasked=None) as sim, Client(sim.port, wait_booted=False) as gcs):
        assert sim.boot_s == BOOT_S[vehicle] == {"plane": 1.7, "copter": 2.5}[vehicle]
        hb = await gcs.expect("HEARTBEAT", after=0)
        assert (hb.system_status, hb.custom_mode, hb.base_mode) == BOOTING[vehicle]
        ack = await _count_to(gcs, 5)
        assert ack.get_type() == "MISSION_ACK" and ack.type == mavlink.MAV_MISSION_NO_SPACE
        await gcs.expect("STATUSTEXT", where=lambda m: m.text == "Only 0 items are supported", after=0)
        fence_mark = gcs.mark()  # a fence upload during the boot: no answer until the boot is over
        gcs.send(mavlink.MAVLink_mission_count_message(1, 1, 2, FENCE))
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_FAILED
        await gcs.expect("STATUSTEXT", where=lambda m: m.text == "Arm: System not initialised", after=mark)
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 1e6) == ACCEPTED  # commands work
        assert not [m for m in gcs.inbox if m.get_type() in ("SYS_STATUS", "GLOBAL_POSITION_INT")]
        hb = await gcs.expect("HEARTBEAT", where=booted, timeout=3.0 * BOOT_S[vehicle] / speedup)
        assert (hb.system_status, hb.custom_mode, hb.base_mode) == STANDBY
        assert sim.sim_time == pytest.approx(BOOT_S[vehicle], abs=1.2)  # 1 Hz heartbeats
        ready = await gcs.expect("STATUSTEXT", where=lambda m: m.text == "ArduPilot Ready", after=0)
        request = await gcs.expect("MISSION_REQUEST", where=lambda m: m.mission_type == FENCE, after=fence_mark)
        assert request.seq == 0 and gcs.inbox.index(request) > gcs.inbox.index(ready)
        gcs.send(mavlink.MAVLink_mission_ack_message(1, 1, mavlink.MAV_MISSION_OPERATION_CANCELLED, FENCE))
        # booted, home not set yet
        assert await _download_count(gcs) == 0
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mavlink.MAV_RESULT_FAILED
        await gcs.expect("STATUSTEXT", where=lambda m: m.text == PREARM_TEXT[vehicle], after=mark)
        await gcs.wait_ready()
        assert await _download_count(gcs) == 1  # home
        assert await gcs.upload(route(static, [(200.0, 200.0, 50.0)])) == mavlink.MAV_MISSION_ACCEPTED


@pytest.mark.asyncio
async def test_what_comes_before_the_first_heartbeat_is_lost(static: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    """SITL (client on SERIAL0 at power-up): a MISSION_COUNT sent before the first HEARTBEAT is never answered,
    the next one after it gets MAV_MISSION_NO_SPACE. (No socket: the simulator's answers as handed to its
    transport.)"""
    sim = SimAutopilot(static, "udpin:127.0.0.1:0", boot_s=None)
    replies: list[mavlink.MAVLink_message] = []
    sim._transport.send = lambda msg, component_id=None: replies.append(msg)  # type: ignore[method-assign]  # the test catches the replies
    sim._on_message(mavlink.MAVLink_mission_count_message(1, 1, 3, 0))
    sim.advance(0.2)
    assert not [m for m in replies if m.get_type() == "MISSION_ACK"]
    sim.advance(FIRST_HEARTBEAT_FRACTION * sim.boot_s)
    sim._on_message(mavlink.MAVLink_mission_count_message(1, 1, 3, 0))
    acks = [m.type for m in replies if m.get_type() == "MISSION_ACK"]
    assert acks == [mavlink.MAV_MISSION_NO_SPACE]


# --- readback -----------------------------------------------------------------------------------------------


@pytest.mark.asyncio
@pytest.mark.parametrize("vehicle", ["plane", "copter"])
async def test_readback_is_what_ardupilot_stores(static: Scenario, vehicle: str) -> None:  # noqa: F811 - the fixture imported from test_sim
    """SITL readbacks: plane NAV_WAYPOINT param1/param4 0, param2/param3 whole metres ≤ 255; copter keeps only
    the hold time (whole s); DO_CHANGE_SPEED in frame GLOBAL; a fence circle in frame GLOBAL, autocontinue 0,
    z 0, only param1 (sent 50, 7, 8, 9, z 33 → 50, 0, 0, 0, z 0)."""
    wp = item(3, mavlink.MAV_CMD_NAV_WAYPOINT, (300.0, 300.0, 60.0), scenario=static, param1=5.7, param2=30.6,
              param3=300.0, param4=45.0)
    items = route(static, [(200.0, 200.0, 50.0)])[:3] + [wp]
    base = items[3]
    fence = [MissionItem(0, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
                         param1=50.0, param2=7.0, param3=8.0, param4=9.0, x=base.x, y=base.y, z=33.0,
                         mission_type=FENCE)]
    rally = [MissionItem(i, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mavlink.MAV_CMD_NAV_RALLY_POINT,
                         param1=1.0, param2=2.0, param3=3.0, param4=4.0, x=base.x + 1000 * i, y=base.y, z=60.0 + i,
                         mission_type=RALLY) for i in range(3)]
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=5.0, vehicle=vehicle, boot_s=None) as sim,
                Client(sim.port) as gcs):
        await gcs.wait_ready()
        assert await gcs.upload(items) == mavlink.MAV_MISSION_ACCEPTED
        assert await gcs.upload(fence, mission_type=FENCE) == mavlink.MAV_MISSION_ACCEPTED
        assert await gcs.upload(rally, mission_type=RALLY) == mavlink.MAV_MISSION_ACCEPTED
        got = [MissionItem.from_message(m) for m in await gcs.download()]
        got_fence = [MissionItem.from_message(m) for m in await gcs.download(FENCE)]
        got_rally = [MissionItem.from_message(m) for m in await gcs.download(RALLY)]
    firmware = FIRMWARE[vehicle]
    for sent, back in zip(items[1:], got[1:]):
        assert compare_items(stored(sent, firmware), back) is None
    w = got[3]
    if vehicle == "plane":
        assert (w.param1, w.param2, w.param3, w.param4) == (0.0, 30.0, 255.0, 0.0)
    else:
        assert (w.param1, w.param2, w.param3, w.param4) == (5.0, 0.0, 0.0, 0.0)
    assert got[2].frame == mavlink.MAV_FRAME_GLOBAL  # DO_CHANGE_SPEED sent in MAV_FRAME_MISSION
    f = got_fence[0]
    assert (f.frame, f.autocontinue, f.param1, f.param2, f.param3, f.param4, f.z) == (
        mavlink.MAV_FRAME_GLOBAL, 0, 50.0, 0.0, 0.0, 0.0, 0.0)
    assert len(got_rally) == 3
    for sent, back in zip(rally, got_rally):
        assert compare_items(stored(sent, firmware), back) is None
        assert back.autocontinue == 0


@pytest.mark.asyncio
@pytest.mark.parametrize("vehicle", ["plane", "copter"])
async def test_parameters_as_ardupilot(static: Scenario, vehicle: str) -> None:  # noqa: F811 - the fixture imported from test_sim
    """SITL: FENCE_TYPE reads 4 (plane) / 7 (copter) as MAV_PARAM_TYPE_INT8 with index 65535 when asked by name;
    PARAM_SET FENCE_ENABLE 1 is echoed with PARAM_VALUE; PARAM_SET of a name it does not have gets no answer;
    with a fence stored and FENCE_ENABLE set, SYS_STATUS reports the geofence enabled."""
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=5.0, vehicle=vehicle) as sim,
                Client(sim.port) as gcs):
        mark = gcs.mark()
        gcs.send(mavlink.MAVLink_param_request_read_message(1, 1, b"FENCE_TYPE", -1))
        value = await gcs.expect("PARAM_VALUE", after=mark)
        assert (value.param_id, value.param_value, value.param_type, value.param_index) == (
            "FENCE_TYPE", {"plane": 4.0, "copter": 7.0}[vehicle], mavlink.MAV_PARAM_TYPE_INT8, 65535)
        mark = gcs.mark()
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 3.0, mavlink.MAV_PARAM_TYPE_REAL32))
        gcs.send(mavlink.MAVLink_param_set_message(1, 1, b"FENCE_ENABLE", 1.0, mavlink.MAV_PARAM_TYPE_INT8))
        value = await gcs.expect("PARAM_VALUE", after=mark)
        assert (value.param_id, value.param_value) == ("FENCE_ENABLE", 1.0)
        assert [m.param_id for m in gcs.inbox[mark:] if m.get_type() == "PARAM_VALUE"] == ["FENCE_ENABLE"]
        base = route(static, [(300.0, 300.0, 60.0)])[3]
        fence = [MissionItem(0, mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
                             param1=50.0, x=base.x, y=base.y, mission_type=FENCE)]
        assert await gcs.upload(fence, mission_type=FENCE) == mavlink.MAV_MISSION_ACCEPTED
        status = await gcs.expect("SYS_STATUS", after=gcs.mark())
        assert status.onboard_control_sensors_enabled & mavlink.MAV_SYS_STATUS_GEOFENCE


@pytest.mark.asyncio
async def test_time_waits_for_the_first_client_as_sitl(static: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    """SITL's clock starts with its first client on SERIAL0, so that client sees the whole boot."""
    async with SimAutopilot(static, "udpin:127.0.0.1:0", speedup=10.0, boot_s=None, wait_for_client=True) as sim:
        await asyncio.sleep(0.5)  # 5 s of simulated time, were the clock running
        assert sim.sim_time == 0.0
        async with Client(sim.port, wait_booted=False) as gcs:
            first = await gcs.expect("HEARTBEAT", after=0)
            assert first.system_status == mavlink.MAV_STATE_CALIBRATING


# --- telemetry streams --------------------------------------------------------------------------------------
# SITL, SERIAL0, nobody asked: ArduPlane streams every group at 1 Hz; ArduCopter sends only HEARTBEAT (and
# TIMESYNC every 10 s). SET_MESSAGE_INTERVAL → ACCEPTED and exactly that rate; 0 → the group's rate (off on the
# copter); -1 → off; id 12345 → DENIED + "No ap_message for mavlink id (12345)"; 1 µs → DENIED + "Requested rate
# for message ID 33 too fast. Increase SCHED_LOOP_RATE" (two STATUSTEXT chunks). REQUEST_DATA_STREAM groups (what
# started flowing, of what the simulator sends): POSITION → GLOBAL_POSITION_INT, LOCAL_POSITION_NED; EXTRA1 →
# ATTITUDE; EXTRA2 → VFR_HUD; EXTRA3 → EKF_STATUS_REPORT, SYSTEM_TIME; EXTENDED_STATUS → SYS_STATUS,
# MISSION_CURRENT, GPS_RAW_INT; ALL → all of them. A stream request overrides an earlier per-message interval
# (GLOBAL_POSITION_INT 10 Hz → 3 Hz after POSITION at 3 Hz), a later interval overrides it again, and stopping the
# group stops it.
SIM_SENDS = {"SYS_STATUS", "GPS_RAW_INT", "MISSION_CURRENT", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED",
             "ATTITUDE", "VFR_HUD", "SYSTEM_TIME", "EKF_STATUS_REPORT"}
GROUPS = {
    mavlink.MAV_DATA_STREAM_POSITION: {"GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"},
    mavlink.MAV_DATA_STREAM_EXTRA1: {"ATTITUDE"},
    mavlink.MAV_DATA_STREAM_EXTRA2: {"VFR_HUD"},
    mavlink.MAV_DATA_STREAM_EXTRA3: {"EKF_STATUS_REPORT", "SYSTEM_TIME"},
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: {"SYS_STATUS", "MISSION_CURRENT", "GPS_RAW_INT"},
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: set(),
    mavlink.MAV_DATA_STREAM_ALL: SIM_SENDS,
}


async def _rates(gcs: Client, sim: SimAutopilot, sim_seconds: float) -> dict[str, float]:
    """Messages per simulated second over the next ``sim_seconds``, counted against HEARTBEAT (1 Hz), as the
    SITL measurement did."""
    mark = gcs.mark()
    await sim.run_until(sim.sim_time + sim_seconds)
    counts = collections.Counter(m.get_type() for m in gcs.inbox[mark:] if m.get_srcComponent() == 1)
    beats = max(counts.pop("HEARTBEAT", 0), 1)
    events = ("STATUSTEXT", "HOME_POSITION")  # sent when something happens (home set), not streamed
    return {k: v / beats for k, v in counts.items() if k not in events}


def _near(rate: float | None, hz: float) -> bool:
    return rate is not None and abs(rate - hz) <= 0.25 * hz + 0.2


@pytest.mark.asyncio
@pytest.mark.parametrize("vehicle", ["plane", "copter"])
async def test_streams_unasked_as_the_real_vehicle(static: Scenario, vehicle: str) -> None:  # noqa: F811 - the fixture imported from test_sim
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=3.0, vehicle=vehicle, boot_s=None,
                             streams_unasked=None) as sim, Client(sim.port) as gcs):
        rates = await _rates(gcs, sim, 8.0)
    if vehicle == "copter":
        assert rates == {}  # HEARTBEAT only
    else:
        assert set(rates) == SIM_SENDS and all(_near(r, 1.0) for r in rates.values()), rates


@pytest.mark.asyncio
async def test_set_message_interval_as_ardupilot(static: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=2.0, vehicle="copter", streams_unasked=None) as sim,
                Client(sim.port) as gcs):
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 100_000) == ACCEPTED
        assert _near((await _rates(gcs, sim, 4.0)).get("GLOBAL_POSITION_INT"), 10.0)
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 0) == ACCEPTED
        assert "GLOBAL_POSITION_INT" not in await _rates(gcs, sim, 3.0)  # a copter's default: not sent
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HEARTBEAT,
                                 500_000) == ACCEPTED
        mark = gcs.mark()
        await sim.run_until(sim.sim_time + 4.0)
        beats = [m for m in gcs.inbox[mark:] if m.get_type() == "HEARTBEAT"]
        assert 6 <= len(beats) <= 10  # 2 Hz
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_HEARTBEAT, 0) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE,
                                 200_000) == ACCEPTED
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 12345, 100_000) == DENIED
        await gcs.expect("STATUSTEXT", where=lambda m: m.text == "No ap_message for mavlink id (12345)", after=mark)
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 1) == DENIED
        chunks = [await gcs.expect("STATUSTEXT", after=mark), await gcs.expect("STATUSTEXT")]
        assert chunks[0].id == chunks[1].id != 0 and [c.chunk_seq for c in chunks] == [0, 1]
        assert "".join(c.text for c in chunks) == \
            "Requested rate for message ID 33 too fast. Increase SCHED_LOOP_RATE"
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=2.0, streams_unasked=None) as sim,
                Client(sim.port) as gcs):
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, -1) == ACCEPTED
        assert "GLOBAL_POSITION_INT" not in await _rates(gcs, sim, 3.0)
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 0) == ACCEPTED
        assert _near((await _rates(gcs, sim, 4.0)).get("GLOBAL_POSITION_INT"), 1.0)  # ArduPlane's default


@pytest.mark.asyncio
async def test_request_data_stream_groups_as_ardupilot(static: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=2.0, vehicle="copter", streams_unasked=None) as sim,
                Client(sim.port) as gcs):
        for group, expected in GROUPS.items():
            gcs.send(mavlink.MAVLink_request_data_stream_message(1, 1, group, 2, 1))
            rates = await _rates(gcs, sim, 3.0)
            assert set(rates) == expected, (group, rates)
            assert all(_near(r, 2.0) for r in rates.values()), (group, rates)
            gcs.send(mavlink.MAVLink_request_data_stream_message(1, 1, group, 0, 0))
            await sim.run_until(sim.sim_time + 1.0)
        assert await _rates(gcs, sim, 2.0) == {}
        # a stream request overrides an earlier interval; a later interval overrides it; a stop stops both
        # (SITL: GLOBAL_POSITION_INT 10 Hz, POSITION at 3 Hz → 3 Hz, 10 Hz again; here 2 Hz: the simulator sends
        # LOCAL_POSITION_NED at most 5 times per wall second)
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 100_000) == ACCEPTED
        gcs.send(mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_POSITION, 2, 1))
        await sim.run_until(sim.sim_time + 0.5)
        assert _near((await _rates(gcs, sim, 4.0)).get("GLOBAL_POSITION_INT"), 2.0)
        assert await gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, GPI, 100_000) == ACCEPTED
        rates = await _rates(gcs, sim, 4.0)
        assert _near(rates.get("GLOBAL_POSITION_INT"), 10.0) and _near(rates.get("LOCAL_POSITION_NED"), 2.0)
        gcs.send(mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_POSITION, 0, 0))
        await sim.run_until(sim.sim_time + 1.0)
        assert await _rates(gcs, sim, 3.0) == {}


@pytest.mark.asyncio
async def test_request_message_and_set_current_answers(static: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    """SITL (copter, no streams): REQUEST_MESSAGE of a known message → ACCEPTED and the message (HOME_POSITION
    before home is set, ADSB_VEHICLE with no traffic: ACCEPTED, nothing); an unknown one → FAILED;
    MISSION_SET_CURRENT → MISSION_CURRENT (its only acknowledgement), out of range → nothing;
    DO_SET_MISSION_CURRENT out of range → DENIED."""
    # home comes 6 sim s after power-up (3 s of wall time): the first commands, asked before it, must not race it
    # on a loaded machine (with home at 1 s, CI once saw GET_HOME_POSITION accepted)
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=2.0, vehicle="copter", streams_unasked=None,
                             ready_after_s=6.0) as sim,
                Client(sim.port) as gcs):
        assert await gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_GET_HOME_POSITION) == mavlink.MAV_RESULT_FAILED
        assert await gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_ADSB_VEHICLE) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, 12345) == mavlink.MAV_RESULT_FAILED
        assert not [m for m in gcs.inbox if m.get_type() in ("HOME_POSITION", "ADSB_VEHICLE")]
        await gcs.wait_ready()
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION) == ACCEPTED
        await gcs.expect("HOME_POSITION", after=mark)
        gcs.send(mavlink.MAVLink_request_data_stream_message(1, 1, mavlink.MAV_DATA_STREAM_ALL, 0, 0))
        assert await gcs.upload(route(static, [(30.0, 40.0, 20.0), (60.0, 40.0, 20.0)])) == 0
        await sim.run_until(sim.sim_time + 1.0)
        mark = gcs.mark()
        gcs.send(mavlink.MAVLink_mission_set_current_message(1, 1, 4))
        assert (await gcs.expect("MISSION_CURRENT", after=mark)).seq == 4
        mark = gcs.mark()
        gcs.send(mavlink.MAVLink_mission_set_current_message(1, 1, 9))
        await sim.run_until(sim.sim_time + 1.0)
        assert not [m for m in gcs.inbox[mark:] if m.get_type() == "MISSION_CURRENT"]
        assert await gcs.command(mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, 9) == DENIED
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_DO_SET_MISSION_CURRENT, 3) == ACCEPTED
        assert (await gcs.expect("MISSION_CURRENT", after=mark)).seq == 3


# --- ADS-B --------------------------------------------------------------------------------------------------


@pytest.mark.asyncio
@pytest.mark.parametrize("receiver", [False, True])
async def test_intruders_from_the_autopilot_or_an_adsb_receiver(dynamic: Scenario,  # noqa: F811 - the fixture imported from test_sim
                                                                 receiver: bool) -> None:
    """A receiver on the companion's link is component 156 (MAV_COMP_ID_ADSB) of the vehicle's system, with its
    own HEARTBEAT (MAV_TYPE_ADSB, MAV_AUTOPILOT_INVALID); the autopilot then relays nothing itself."""
    items = route(dynamic, [(200.0, 200.0, 50.0), (500.0, 450.0, 80.0), (800.0, 800.0, 50.0)])
    async with (SimAutopilot(dynamic, "udpin:127.0.0.1:0", speedup=20.0, adsb_receiver=receiver, boot_s=None,
                             streams_unasked=None) as sim, Client(sim.port) as gcs):
        assert await gcs.upload(items) == mavlink.MAV_MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        report = await gcs.expect("ADSB_VEHICLE", timeout=8.0, after=0)
        await sim.run_until(sim.sim_time + 3.0)
    sources = {(m.get_srcSystem(), m.get_srcComponent()) for m in gcs.inbox if m.get_type() == "ADSB_VEHICLE"}
    assert report.ICAO_address == dynamic.intruders[0].icao
    if receiver:
        assert sources == {(1, mavlink.MAV_COMP_ID_ADSB)}
        beats = [m for m in gcs.inbox if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 156]
        assert beats and (beats[0].type, beats[0].autopilot) == (mavlink.MAV_TYPE_ADSB,
                                                                 mavlink.MAV_AUTOPILOT_INVALID)
    else:
        assert sources == {(1, mavlink.MAV_COMP_ID_AUTOPILOT1)}


@pytest.mark.asyncio
async def test_a_meet_intruder_meets_the_simulated_vehicle(dynamic: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    """An intruder timed by a ``meet`` point (as TrafficFeed flies it against SITL) is scheduled from the
    vehicle's progress along the mission it started with, so it crosses the route as the vehicle passes."""
    wps = [(200.0, 200.0, 50.0), (500.0, 450.0, 80.0), (800.0, 800.0, 50.0)]
    meet = (607.7, 592.3, 120.0)  # on the intruder's path (x + y = 1200), where the route crosses it
    intruder = dataclasses.replace(dynamic.intruders[0], meet=meet)
    scenario = dataclasses.replace(dynamic, intruders=(intruder,))
    async with (SimAutopilot(scenario, "udpin:127.0.0.1:0", speedup=20.0) as sim, Client(sim.port) as gcs):
        assert await gcs.upload(route(scenario, wps)) == mavlink.MAV_MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        await gcs.expect("MISSION_ITEM_REACHED", timeout=10.0, where=lambda m: m.seq == 5, after=0)
        await gcs.expect("ADSB_VEHICLE", after=0)
    track = {round(t, 1): (x, y) for t, x, y, _z in sim.intruder_truth[intruder.id]}
    miss = min(math.hypot(x - track[round(t, 1)][0], y - track[round(t, 1)][1])
               for t, _lat, _lon, _alt, x, y, _z in sim.truth if round(t, 1) in track)
    assert miss < 30.0


# --- plane take-off and climb-out ---------------------------------------------------------------------------
# ArduPlane SITL (plane.parm, heading 0), the rescue_static mission fuseplan builds (TAKEOFF param1 10° to 50 m,
# DO_CHANGE_SPEED 18 m/s, first route waypoint (200, 200, 50) with a 20 m radius), armed in AUTO: sim s after
# arming / ENU m from home. Two runs (pymavlink, and `fuseplan fly --connect`) agreed within 0.05 s.
SITL_LIFTOFF_S = 3.9  # first ≥ 1 m above home, after a ground roll north
SITL_LIFTOFF_NORTH = 40.0
SITL_CLIMB_RATE = 10.06  # m/s between 10 and 40 m
SITL_TAKEOFF_COMPLETE_S = 8.88  # "Takeoff complete at 50.43m"; the DO_CHANGE_SPEED runs (and is REACHED) then
SITL_TAKEOFF_COMPLETE_NORTH = 166.0  # m north of home, 0 east: straight ahead on the runway heading
SITL_PEAK_ALT = 63.6  # m: the climb overshoots the take-off altitude while turning
SITL_MAX_NORTH = 270.0  # m: how far north it gets before turning back towards the route start
SITL_WP3_REACHED_S = 20.77  # "Reached waypoint #3 dist 18m", at about (189, 215)
SITL_PATH_TO_WP3 = 437.0  # m flown (horizontally) from arming to reaching the route start
TOLERANCE = 0.15


def _within(got: float, want: float) -> bool:
    return abs(got - want) <= TOLERANCE * abs(want)


@pytest.mark.asyncio
async def test_plane_climb_out_matches_arduplane_sitl(static_plan_doc: Callable[..., dict],
                                                      static: Scenario) -> None:  # noqa: F811 - the fixture imported from test_sim
    items = mission_from_plan_json(static_plan_doc(), static, "ardupilot")
    assert [it.command for it in items[1:4]] == [mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_DO_CHANGE_SPEED,
                                                 mavlink.MAV_CMD_NAV_WAYPOINT]
    async with (SimAutopilot(static, "udpin:127.0.0.1:0", speedup=20.0, boot_s=None, streams_unasked=None) as sim,
                Client(sim.port) as gcs):
        assert await gcs.upload(items) == mavlink.MAV_MISSION_ACCEPTED
        await gcs.wait_ready()
        assert await gcs.set_mode(PLANE_MODES["AUTO"]) == ACCEPTED
        mark = gcs.mark()
        assert await gcs.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1) == ACCEPTED
        done = await gcs.expect("STATUSTEXT", timeout=5.0, after=mark,
                                where=lambda m: m.text.startswith("Takeoff complete at"))
        reached = await gcs.expect("MISSION_ITEM_REACHED", after=mark)
        assert reached.seq == 2  # the DO_CHANGE_SPEED, in place of the take-off
        await gcs.expect("MISSION_ITEM_REACHED", timeout=5.0, where=lambda m: m.seq == 3, after=mark)
        t0 = sim.mission_start_time
        assert t0 is not None
        flown = {it.seq: t - t0 for _, t, it in sim.flown_items}
        track = [(t - t0, x, y, z) for t, _, _, _, x, y, z in sim.truth if t >= t0]
    assert 50.0 <= float(done.text.split("at ")[1].rstrip("m")) < 51.0
    t_takeoff, t_wp3 = flown[3], flown[4]  # when the next NAV item began
    liftoff = next(r for r in track if r[3] >= 1.0)
    climb = [r for r in track if 10.0 <= r[3] <= 40.0 and r[0] < t_takeoff]
    climb_rate = (climb[-1][3] - climb[0][3]) / (climb[-1][0] - climb[0][0])
    at_takeoff = min(track, key=lambda r: abs(r[0] - t_takeoff))
    before_wp3 = [r for r in track if r[0] <= t_wp3]
    path = sum(math.hypot(b[1] - a[1], b[2] - a[2]) for a, b in zip(before_wp3, before_wp3[1:]))
    got = {"liftoff_s": liftoff[0], "liftoff_north": liftoff[2], "climb_rate": climb_rate,
           "takeoff_s": t_takeoff, "takeoff_north": at_takeoff[2],
           "peak_alt": max(r[3] for r in track if t_takeoff <= r[0] <= t_takeoff + 10.0),
           "max_north": max(r[2] for r in before_wp3), "wp3_s": t_wp3, "path_to_wp3": path}
    want = {"liftoff_s": SITL_LIFTOFF_S, "liftoff_north": SITL_LIFTOFF_NORTH, "climb_rate": SITL_CLIMB_RATE,
            "takeoff_s": SITL_TAKEOFF_COMPLETE_S, "takeoff_north": SITL_TAKEOFF_COMPLETE_NORTH,
            "peak_alt": SITL_PEAK_ALT, "max_north": SITL_MAX_NORTH, "wp3_s": SITL_WP3_REACHED_S,
            "path_to_wp3": SITL_PATH_TO_WP3}
    assert {k: _within(got[k], want[k]) for k in want} == dict.fromkeys(want, True), (got, want)
    assert abs(at_takeoff[1]) < 2.0  # straight ahead, north: no turn before the take-off is complete
