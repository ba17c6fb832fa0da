"""Boot: what a companion that powers up with its autopilot sees (docs/autopilots.md §1.3 "Boot").

Each test starts its own autopilot and connects at once. On SITL the companion is SERIAL0's first client, and
SITL's clock starts only then, so the first HEARTBEAT it reads is one of the boot's; the boot itself lasts about
0.1 s of wall time at speed-up 10 (plane) and 0.2 s (copter).
"""

from __future__ import annotations

import time

import pytest
from conformance.conftest import booting, collect, home_item, item, numbered, takeoff, texts, waypoint
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import CommandError, MissionUploadError
from companion.mavlink.items import FENCE, compare_items

pytestmark = pytest.mark.asyncio(loop_scope="module")


def _mission() -> list:
    return numbered([home_item(), takeoff(40.0), waypoint(200.0, 0.0, 40.0)])


async def test_upload_refused_while_booting_then_accepted_once_booted(fresh, measure) -> None:
    async with fresh() as v:
        t0 = time.monotonic()
        first = await v.link.wait_heartbeat(10.0)
        measure(f"first HEARTBEAT after {time.monotonic() - t0:.3f} s: system_status {first.system_status}, "
                f"custom_mode {first.custom_mode}")
        assert booting(first, v.plane), (
            f"first HEARTBEAT: system_status {first.system_status}, custom_mode {first.custom_mode} "
            f"(expected {'BOOT/CALIBRATING in mode 16' if v.plane else 'BOOT'})")
        try:
            await v.client.upload(_mission())
        except MissionUploadError as e:
            assert e.result == mavlink.MAV_MISSION_NO_SPACE, f"refused with {e}"
            measure("upload at the first HEARTBEAT: refused with MAV_MISSION_NO_SPACE")
        else:
            # only acceptable if the boot ended between that HEARTBEAT and our MISSION_COUNT (a slow machine)
            hb = await v.link.wait_for("HEARTBEAT", timeout=2.0)
            assert not booting(hb, v.plane), "upload accepted while the autopilot still says it is booting"
            measure("upload at the first HEARTBEAT: accepted (the boot had ended)")
        await v.request_telemetry()
        await v.supervisor.wait_booted(30.0)
        measure(f"wait_booted returned {time.monotonic() - t0:.3f} s after connecting")
        assert not booting(v.link.last_heartbeat_msg, v.plane)
        got = await v.client.upload_verified(_mission())
        assert len(got) == 3


async def test_fence_upload_refused_while_booting_is_retried_after_boot(fresh, measure) -> None:
    """ArduPilot refuses a fence with MAV_MISSION_UNSUPPORTED until its fence storage is up; the supervisor's
    upload at the first HEARTBEAT takes that for the boot's answer, waits for the boot and uploads again."""
    fence = numbered([item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0.0, param1=1500.0),
                      item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 300.0, 300.0, param1=40.0),
                      item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, -300.0, 300.0, param1=40.0)], FENCE)
    async with fresh() as v:
        await v.link.wait_heartbeat(10.0)
        await v.request_telemetry()
        await v.supervisor.upload((), fence)
        failed = [e for e in v.events.records if e["event"] == "upload_failed"]
        measure(f"fence at the first HEARTBEAT: {[e['error'] for e in failed] or 'accepted at once'}")
        assert all(e["retrying"] for e in failed), failed
        got = await v.client.download(FENCE)
        assert len(got) == 3 and all(compare_items(v.stored(s), g) is None for s, g in zip(fence, got))


async def test_arming_before_ready_is_refused_with_a_reason(fresh, measure) -> None:
    async with fresh() as v:
        await v.link.wait_heartbeat(10.0)
        await v.request_telemetry()
        await v.supervisor.wait_booted(30.0)
        with v.link.subscribe("STATUSTEXT") as sub:
            with pytest.raises(CommandError) as refused:
                await v.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
            said = texts(sub.drain() + await collect(sub, 0.5))
        measure(f"arming right after boot: COMMAND_ACK result {refused.value.result}, STATUSTEXT {said}")
        assert refused.value.result == mavlink.MAV_RESULT_FAILED
        reasons = [t for t in said if t.startswith(("Arm: ", "PreArm: "))]
        assert reasons, f"no 'Arm: …' / 'PreArm: …' reason among {said}"
        hb = await v.link.wait_for("HEARTBEAT", timeout=2.0)
        assert not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
