"""On the ground, with a booted and ready autopilot shared by the module: the mission protocol as ArduPilot
speaks it, what it stores of each item fuseplan builds (companion.mavlink.storage's rules, item type by item type),
fences, rally points, the current item, and the copter's refusal to arm in AUTO."""

from __future__ import annotations

import asyncio
import math
from dataclasses import dataclass

import pytest
from conformance.conftest import HOME, NAN, collect, home_item, item, next_matching, numbered, takeoff, texts, waypoint
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.errors import CommandError, MissionUploadError
from companion.mavlink.fence_capacity import capacity_params, fence_capacity
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, compare_items
from companion.mavlink.params import read_params

pytestmark = pytest.mark.asyncio(loop_scope="module")

FRAME_GLOBAL_INT = mavlink.MAV_FRAME_GLOBAL_INT
FRAME_REL_INT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT


def _difference(v, sent: list[MissionItem], got: list[MissionItem], skip_home: bool) -> str | None:
    """The first item whose readback is not ``stored(sent)`` field for field, described; None if all are."""
    if len(got) != len(sent):
        return f"{len(got)} items read back, {len(sent)} sent"
    for s, g in zip(sent, got):
        if skip_home and s.seq == 0:
            continue
        diff = compare_items(v.stored(s), g)
        if diff is not None:
            return f"item {s.seq} (command {s.command}): {diff[0]} stored() says {diff[1]!r}, read back {diff[2]!r}"
    return None


# ------------------------------------------------------------------------------------------------ mission protocol
async def test_upload_items_are_requested_with_legacy_mission_request(vehicle) -> None:
    mission = numbered([home_item(), takeoff(40.0), waypoint(200.0, 0.0, 40.0), waypoint(200.0, 200.0, 40.0)])
    with vehicle.link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT") as sub:
        await vehicle.client.upload(mission)
        requests = sub.drain()
    assert {r.get_type() for r in requests} == {"MISSION_REQUEST"}
    assert sorted({r.seq for r in requests}) == [0, 1, 2, 3]


async def test_item_0_is_ignored_and_reads_back_as_the_real_home(vehicle) -> None:
    fake_home = item(mavlink.MAV_CMD_NAV_WAYPOINT, 500.0, 500.0, 123.0, frame=FRAME_REL_INT)
    got = await vehicle.client.upload_verified(numbered([fake_home, waypoint(200.0, 0.0, 40.0)]))
    home = got[0]
    assert home.frame == mavlink.MAV_FRAME_GLOBAL
    assert home.command == mavlink.MAV_CMD_NAV_WAYPOINT
    assert abs(home.lat - HOME.lat) < 2e-6 and abs(home.lon - HOME.lon) < 2e-6  # ~0.2 m
    assert abs(home.z - HOME.alt) < 1.0  # AMSL


async def test_frames_read_back_as_their_non_int_twins(vehicle) -> None:
    frames = [mavlink.MAV_FRAME_GLOBAL_INT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
              mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT]
    sent = [home_item()] + [item(mavlink.MAV_CMD_NAV_WAYPOINT, 100.0 * (i + 1), 0.0,
                                 HOME.alt + 40.0 if f in (0, 5) else 40.0, frame=f) for i, f in enumerate(frames)]
    got = await vehicle.client.upload_verified(numbered(sent))
    assert [g.frame for g in got[1:]] == [0, 3, 10, 0, 3]


@dataclass(frozen=True)
class Case:
    """One mission item as fuseplan's builder makes it, with values that exercise a storage rule."""

    item: MissionItem
    why: str


CASES = {
    # NAV_WAYPOINT: ArduPlane keeps param2/param3 as whole metres ≤ 255 and no hold time; ArduCopter keeps only
    # the hold time (param1, whole seconds); param4 (yaw) is not stored by either
    "waypoint_radius_300": Case(waypoint(200.0, 0.0, 40.0, param1=3.7, param2=300.0, param4=NAN),
                                "plane 300 → 255, copter → 0; hold 3.7 s: plane 0, copter 3"),
    "waypoint_radius_20.7": Case(waypoint(200.0, 0.0, 40.0, param2=20.7, param3=20.7),
                                 "plane radius and pass-by 20.7 → 20, copter → 0"),
    "waypoint_radius_20": Case(waypoint(200.0, 0.0, 40.0, param2=20.0), "plane 20, copter → 0"),
    "takeoff": Case(takeoff(40.0, pitch=10.0), "builder's plane pitch 10° (copter 0) kept"),
    "takeoff_nan_yaw": Case(item(mavlink.MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 40.0, param4=NAN), "param4 NaN → 0"),
    "takeoff_fractional_pitch": Case(takeoff(40.0, pitch=5.5), "param1 5.5: stored() keeps it"),
    "change_speed": Case(item(mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, located=False,
                              param1=0.0, param2=18.0, param3=-1.0), "frame MISSION → GLOBAL, speed kept"),
    "change_speed_fractional": Case(item(mavlink.MAV_CMD_DO_CHANGE_SPEED, located=False, param1=1.0, param2=22.5,
                                         param3=-1.0), "frame 6 → GLOBAL, 22.5 m/s kept (float)"),
    "loiter_unlim": Case(item(mavlink.MAV_CMD_NAV_LOITER_UNLIM, 0.0, 200.0, 60.0, param1=1.0, param2=2.0,
                              param3=-60.5, param4=NAN), "radius -60.5 → -60 (sign = direction), rest 0"),
    "rtl": Case(item(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, located=False), "frame 6 → GLOBAL"),
    "land": Case(item(mavlink.MAV_CMD_NAV_LAND, 200.0, 200.0, 0.0), "builder's ArduPilot land: param4 0"),
    "land_nan_yaw": Case(item(mavlink.MAV_CMD_NAV_LAND, 200.0, 200.0, 0.0, param4=NAN), "param4 NaN (PX4's yaw)"),
}


@pytest.mark.parametrize("case", CASES)
async def test_mission_item_reads_back_as_storage_rules_say(vehicle, case) -> None:
    sent = numbered([home_item(), CASES[case].item])
    await vehicle.client.upload(sent)
    got = await vehicle.client.download()
    diff = _difference(vehicle, sent, got, skip_home=True)
    assert diff is None, f"{case} ({CASES[case].why}): {diff}"


# ------------------------------------------------------------------------------------------------ fence
def _fence() -> list[MissionItem]:
    """Every fence item type; fields a fence item does not use are set, to see them dropped."""
    fence = [
        item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0.0, frame=FRAME_GLOBAL_INT, param1=2000.0),
        item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 300.0, 300.0, 100.0, frame=FRAME_GLOBAL_INT, param1=50.0,
             param2=3.0, param3=4.0, param4=5.0),
        item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, -300.0, 300.0, frame=FRAME_REL_INT, param1=50.5),
        item(mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT, 50.0, 50.0, 40.0, frame=FRAME_REL_INT),
    ]
    fence += [item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, n, e, frame=FRAME_GLOBAL_INT, param1=4.0)
              for n, e in ((-1500.0, -1500.0), (-1500.0, 1500.0), (1500.0, 1500.0), (1500.0, -1500.0))]
    fence += [item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, n, e, frame=FRAME_GLOBAL_INT, param1=3.0)
              for n, e in ((500.0, -500.0), (500.0, -400.0), (400.0, -450.0))]
    return numbered(fence, FENCE)


async def test_fence_reads_back_as_storage_rules_say(vehicle) -> None:
    fence = _fence()
    got = await vehicle.client.upload_verified(fence, FENCE)
    assert _difference(vehicle, fence, got, skip_home=False) is None, _difference(vehicle, fence, got, False)


async def test_fence_circle_radius_keeps_its_fraction(vehicle, measure) -> None:
    fence = _fence()
    circle = 2  # the exclusion circle of radius 50.5
    assert fence[circle].param1 == 50.5
    got = await vehicle.client.upload_verified(fence, FENCE)
    measure(f"fence circle radius 50.5 reads back {got[circle].param1!r}")
    assert compare_items(vehicle.stored(fence[circle]), got[circle]) is None


async def test_a_single_circle_over_a_longer_fence_stays(vehicle) -> None:
    """ArduPilot sets FENCE_TOTAL to 0 for a fence of fewer than 3 vertices (each circle counts as one), and its
    fence loader clears the stored fence when FENCE_TOTAL goes from non-zero to 0 (AC_PolyFence_loader: "an older
    GCS sets the fence point count to zero"): a single circle uploaded straight over a longer fence is
    acknowledged, verified by a readback in the first ~10 ms of wall time at speed-up 10, and then gone. The
    client clears an ArduPilot fence before uploading (companion.mavlink.protocol), so the circle stays."""
    single = numbered([_fence()[2]], FENCE)
    await vehicle.client.upload_verified(_fence(), FENCE)
    await vehicle.client.upload_verified(single, FENCE)
    await asyncio.sleep(0.5)  # 5 s of the autopilot's time
    got = await vehicle.client.download(FENCE)
    assert len(got) == 1 and compare_items(vehicle.stored(single[0]), got[0]) is None


async def test_fence_enabled_by_parameters_as_a_user_would(vehicle) -> None:
    """FENCE_ENABLE=1 and FENCE_TYPE = circle|polygon (bits: 1 max alt, 2 circle, 4 polygon, 8 min alt) with
    PARAM_SET, each confirmed by PARAM_VALUE; the fence then uploads and verifies, and SYS_STATUS reports the
    geofence enabled."""
    await vehicle.param_set("FENCE_TYPE", 2 | 4)
    await vehicle.param_set("FENCE_ENABLE", 1)
    try:
        fence = _fence()
        got = await vehicle.client.upload_verified(fence, FENCE)
        assert len(got) == len(fence)
        status = await vehicle.link.wait_for("SYS_STATUS", timeout=5.0)
        assert status.onboard_control_sensors_enabled & mavlink.MAV_SYS_STATUS_GEOFENCE
    finally:
        await vehicle.param_set("FENCE_ENABLE", 0)


# ------------------------------------------------------------------------------------------------ rally
def _rally(altitudes: tuple[float, float, float]) -> list[MissionItem]:
    return numbered([
        item(mavlink.MAV_CMD_NAV_RALLY_POINT, 100.0, -100.0, altitudes[0], param1=1.0, param2=2.0, param3=3.0,
             param4=4.0),
        item(mavlink.MAV_CMD_NAV_RALLY_POINT, -100.0, 100.0, altitudes[1], frame=FRAME_GLOBAL_INT),
        item(mavlink.MAV_CMD_NAV_RALLY_POINT, -100.0, -100.0, altitudes[2],
             frame=mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT),
    ], RALLY)


async def test_rally_points_read_back_as_storage_rules_say(vehicle) -> None:
    rally = _rally((60.0, HOME.alt + 100.0, 80.0))
    got = await vehicle.client.upload_verified(rally, RALLY)
    assert _difference(vehicle, rally, got, skip_home=False) is None, _difference(vehicle, rally, got, False)


async def test_rally_fractional_altitude_reads_back_as_storage_rules_say(vehicle, measure) -> None:
    rally = _rally((60.5, HOME.alt + 100.25, 80.0))
    await vehicle.client.upload(rally, RALLY)
    got = await vehicle.client.download(RALLY)
    measure(f"rally altitudes 60.5 / {HOME.alt + 100.25} read back {got[0].z!r} / {got[1].z!r}")
    assert _difference(vehicle, rally, got, skip_home=False) is None, _difference(vehicle, rally, got, False)


# ------------------------------------------------------------------------------------------------ current item
def _six() -> list[MissionItem]:
    return numbered([home_item(), takeoff(40.0)] + [waypoint(150.0 * i, 0.0, 40.0) for i in range(1, 5)])


async def test_set_current_makes_that_item_current(vehicle) -> None:
    await vehicle.client.upload(_six())
    for seq in (3, 1, 5):
        with vehicle.link.subscribe("MISSION_CURRENT") as sub:
            await vehicle.client.set_current(seq)
            current = await next_matching(sub, lambda m: m.seq == seq, timeout=2.0)  # noqa: B023 - awaited in this pass
        assert current.seq == seq


async def test_set_current_0_makes_item_1_current(vehicle) -> None:
    await vehicle.client.upload(_six())
    await vehicle.client.set_current(4)
    await vehicle.client.set_current(0)
    current = await vehicle.link.wait_for("MISSION_CURRENT", timeout=2.0)  # sent after the COMMAND_ACK
    assert current.seq == 1


async def test_set_current_past_the_end_is_denied(vehicle) -> None:
    await vehicle.client.upload(_six())
    with pytest.raises(CommandError) as refused:
        await vehicle.client.set_current(6)
    assert refused.value.result == mavlink.MAV_RESULT_DENIED


# ------------------------------------------------------------------------------------------------ arming in AUTO
async def test_copter_refuses_to_arm_in_auto_with_a_reason(vehicle, measure) -> None:
    if vehicle.plane:
        pytest.skip("ArduPlane arms in AUTO: that is its start sequence (test_flight)")
    await vehicle.client.upload(numbered([home_item(), takeoff(20.0), waypoint(150.0, 0.0, 20.0)]))
    await vehicle.supervisor.set_mode("AUTO")
    try:
        with vehicle.link.subscribe("STATUSTEXT") as sub:
            with pytest.raises(CommandError) as refused:
                await vehicle.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, retries=0)
            said = texts(sub.drain() + await collect(sub, 0.5))
        measure(f"arming in AUTO: COMMAND_ACK result {refused.value.result}, STATUSTEXT {said}")
        assert refused.value.result == mavlink.MAV_RESULT_FAILED
        assert "Arm: AUTO mode not armable" in said
    finally:
        hb = vehicle.link.last_heartbeat_msg
        if hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
            await vehicle.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
        await vehicle.supervisor.set_mode("STABILIZE")


# ------------------------------------------------------------------------------------------------ abandoned uploads
async def _abandoned_upload(vehicle, items: list[MissionItem], answered: int, mission_type: int) -> list:
    """Start an upload of ``items`` by hand, answer the first ``answered`` requests, then fall silent as a
    companion that lost its link would; returns the MISSION_ACKs and STATUSTEXTs seen until the autopilot gives
    up (8 s of its time: 0.8 s wall at speed-up 10)."""
    link = vehicle.link
    ts, tc = link.target_system, link.target_component
    is_request = lambda m: m.get_type() in ("MISSION_REQUEST", "MISSION_REQUEST_INT") \
        and m.mission_type == mission_type  # noqa: E731 - a predicate kept beside its subscription
    with link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK", "STATUSTEXT") as sub:
        link.send(mavlink.MAVLink_mission_count_message(ts, tc, len(items), mission_type))
        sent = 0
        while sent < answered:
            req = await next_matching(sub, is_request, timeout=2.0)
            if req.seq == sent:
                link.send(items[sent].to_message(ts, tc))
                sent += 1
        ack = await next_matching(sub, lambda m: m.get_type() == "MISSION_ACK"
                                  and m.mission_type == mission_type, timeout=5.0)
        return [ack] + sub.drain() + await collect(sub, 0.2)


def _ack_results(seen: list) -> list[int]:
    return [m.type for m in seen if m.get_type() == "MISSION_ACK"]


async def test_a_mission_upload_abandoned_part_way_leaves_old_and_new_items_mixed(vehicle, measure) -> None:
    """docs/autopilots.md §3.7 "Uploads are not atomic": MISSION_COUNT truncates the stored mission to the new count at
    once and each item is written into place as it arrives, so an upload abandoned after k items leaves
    new items 1..k-1, then the old mission's items up to the new count (companion.sim.mission_server)."""
    old = numbered([home_item(), takeoff(40.0)] + [waypoint(100.0 * i, 0.0, 40.0) for i in range(1, 6)])  # 7
    new = numbered([home_item(), takeoff(60.0)] + [waypoint(0.0, 100.0 * i, 60.0) for i in range(1, 4)])  # 5
    await vehicle.client.upload_verified(old)
    seen = await _abandoned_upload(vehicle, new, answered=3, mission_type=MISSION)  # home, takeoff, wp 1
    measure(f"mission upload abandoned after 3 of 5 items: MISSION_ACK {_ack_results(seen)}, "
            f"STATUSTEXT {texts(seen)}")
    assert _ack_results(seen)[0] == mavlink.MAV_MISSION_OPERATION_CANCELLED
    assert "Mission upload timeout" in texts(seen)
    got = await vehicle.client.download()
    measure(f"… then {len(got)} items stored, commands {[g.command for g in got]}, "
            f"z {[round(g.z) for g in got[1:]]}")
    expected = [new[1], new[2], old[3], old[4]]  # new items 1-2, old 3-4: 5 items in all
    assert len(got) == 5
    for want, have in zip(expected, got[1:]):
        assert compare_items(vehicle.stored(want), have) is None, (want, have)


async def test_a_fence_upload_abandoned_part_way_leaves_the_old_fence(vehicle, measure) -> None:
    """A fence, unlike the mission, is staged and replaces the stored one only when complete (ArduPilot's
    polygon fence loader)."""
    fence = _fence()
    await vehicle.client.upload_verified(fence, FENCE)
    other = numbered([item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0.0, param1=900.0),
                      item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 300.0, 300.0, param1=40.0),
                      item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, -300.0, 300.0, param1=40.0)], FENCE)
    seen = await _abandoned_upload(vehicle, other, answered=1, mission_type=FENCE)
    measure(f"fence upload abandoned after 1 of 3 items: MISSION_ACK {_ack_results(seen)}, "
            f"STATUSTEXT {texts(seen)}")
    assert _ack_results(seen)[0] == mavlink.MAV_MISSION_OPERATION_CANCELLED
    assert "Fence upload timeout" in texts(seen)
    got = await vehicle.client.download(FENCE)
    assert _difference(vehicle, fence, got, skip_home=False) is None, _difference(vehicle, fence, got, False)


def _ring(vertices: int, radius_m: float = 300.0, north_m: float = 3000.0) -> list[MissionItem]:
    """One exclusion polygon of ``vertices`` vertices on a circle ``north_m`` north of home (home stays outside)."""
    angles = [2.0 * math.pi * k / vertices for k in range(vertices)]
    return numbered([item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, north_m + radius_m * math.sin(a),
                          radius_m * math.cos(a), frame=mavlink.MAV_FRAME_GLOBAL_INT, param1=float(vertices))
                     for a in angles], FENCE)


async def test_the_fence_capacity_the_companion_assumes_is_the_vehicles(vehicle, measure) -> None:
    """The capacity the companion's pre-upload check uses (companion.mavlink.fence_capacity, from the HEARTBEAT and
    BRD_SD_FENCE) is the vehicle's: the largest polygon it says fits is stored; one vertex more it refuses, and so
    does the autopilot when sent anyway (after the last item, "Fence exceeds storage size"), as it refuses a count
    above its item limit at MISSION_COUNT (MAV_MISSION_NO_SPACE); the fence stored before stays."""
    link = vehicle.link
    cap = fence_capacity(link.autopilot, link.vehicle_type, await read_params(link, capacity_params(link.autopilot)))
    largest = (cap.storage_bytes - 6) // 8  # 4 bytes of header, 2 for the polygon, 8 a vertex
    fits, more = _ring(largest), _ring(largest + 1)
    assert cap.fits(fits) and not cap.fits(more)
    await vehicle.client.upload_verified(fits, FENCE)
    refusals = []
    for fence in (more, _ring(cap.max_items + 1)):
        with link.subscribe("STATUSTEXT") as sub:
            with pytest.raises(MissionUploadError) as refused:
                await vehicle.client.upload(fence, FENCE)
            said = [t.strip() for t in texts(sub.drain() + await collect(sub, 0.2))]
        refusals.append((refused.value.result, [t for t in said if "Fence" in t or "items are" in t]))
    measure(f"fence capacity {cap.max_items} items, {cap.storage_bytes} bytes: {largest} vertices stored; "
            f"refused {refusals}")
    assert refusals == [(mavlink.MAV_MISSION_ERROR, ["Fence exceeds storage size"]),
                        (mavlink.MAV_MISSION_NO_SPACE, [f"Only {cap.max_items} items are supported"])]
    got = await vehicle.client.download(FENCE)
    assert _difference(vehicle, fits, got, skip_home=False) is None, _difference(vehicle, fits, got, False)
