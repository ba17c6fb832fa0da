"""The companion on a real PX4 (SIH quadrotor SITL, one instance shared by the module): the mission protocol as
PX4 speaks it, what it stores (companion.mavlink.storage's PX4 rules), set-current, and its navigator's verdict on a
mission. Every test runs through both backends, our own pymavlink link and MAVSDK (``fly --backend mavsdk``);
where they differ the test says which one shows the autopilot's behaviour."""

from __future__ import annotations

import asyncio
import math
from collections.abc import AsyncIterator
from dataclasses import replace
from pathlib import Path

import numpy as np
import pymap3d
import pytest
import pytest_asyncio
from px4_harness import FAST
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.errors import CompanionError, MissionUploadError
from companion.mavlink.fence_capacity import fence_capacity
from companion.mavlink.items import FENCE, FRAME_REL_ALT_INT, MissionItem, compare_items
from companion.mavlink.link import Link
from companion.mavlink.mavsdk_backend import MavsdkLink, MavsdkMissionClient
from companion.mavlink.protocol import MissionClient
from companion.mavlink.storage import Firmware, stored
from companion.mavlink.telemetry import request_rates
from companion.mission.builder import MissionSpec, build_mission
from companion.mission.events import EventLog
from companion.mission.geo import enu_to_geodetic, to_int_e7
from planner.world.scenario import load_scenario

pytestmark = pytest.mark.asyncio(loop_scope="module")

ROOT = Path(__file__).resolve().parents[2]
MOUNTAIN = ROOT / "sitl_scenarios" / "mountain_rescue.toml"
SC = load_scenario(MOUNTAIN)
AUTO_MISSION, AUTO_RTL = 0x04040000, 0x05040000  # PX4 custom_mode (sub << 24 | main << 16), as HEARTBEAT shows it
SPEEDUP = FAST  # SIH in lockstep, as fast as 2 cores keep up with


def _point(north_m: float, east_m: float) -> tuple[int, int]:
    lat, lon, _ = enu_to_geodetic(np.array([[east_m, north_m, 0.0]]), SC.home)
    return to_int_e7(float(lat[0])), to_int_e7(float(lon[0]))


def _offset_m(lat_e7: int, lon_e7: int) -> tuple[float, float]:
    """North and east metres of a position from the scenario's home."""
    n, e, _ = pymap3d.geodetic2ned(lat_e7 / 1e7, lon_e7 / 1e7, SC.home.alt, SC.home.lat, SC.home.lon, SC.home.alt)
    return float(n), float(e)


def _fence_item(command: int, north_m: float, east_m: float, param1: float, frame: int) -> MissionItem:
    x, y = _point(north_m, east_m)
    return MissionItem(0, frame, command, param1=param1, x=x, y=y, z=50.0, mission_type=FENCE)


@pytest.fixture(scope="module")
def px4(px4_factory):
    return px4_factory(SC.home, speedup=SPEEDUP)


@pytest_asyncio.fixture(scope="module", loop_scope="module", params=["pymavlink", "mavsdk"])
async def px4_link(request: pytest.FixtureRequest, px4) -> AsyncIterator[tuple[Link, MissionClient, FlightSupervisor]]:
    """A companion on the module's PX4 through one backend (one at a time), booted and ready to arm."""
    mavsdk = request.param == "mavsdk"
    async with (MavsdkLink if mavsdk else Link)(px4.companion_url, open_timeout=5.0) as link:
        await link.wait_heartbeat(20.0)
        client = MavsdkMissionClient(link) if mavsdk else MissionClient(link)
        sup = FlightSupervisor(link, client, EventLog(), arm=True)
        await request_rates(link)
        await sup.wait_booted(30.0)
        await sup.wait_ready(60.0)
        yield link, client, sup


def _mission(end_action: str, scale: float = 1.0) -> list[MissionItem]:
    """A 4-point route ending ``end_action``, its horizontal legs ``scale`` × 150-180 m."""
    vehicle = replace(SC.vehicle, end_action=end_action)
    route = np.array([[0.0, 0.0, 30.0], [150.0, 100.0, 40.0], [300.0, 0.0, 40.0], [300.0, -150.0, 30.0]])
    route[:, :2] *= scale
    return build_mission(route.tolist(), MissionSpec("px4", vehicle, SC.home))


@pytest.mark.parametrize("end_action", ["loiter", "rtl", "land"])
async def test_missions_upload_with_mission_request_int_and_read_back_as_sent(px4_link, end_action: str) -> None:
    """PX4 asks with MISSION_REQUEST_INT, has no home item (item 0 is the takeoff) and keeps every field of a
    mission item (RTL only in frame MISSION: any other frame is refused). (Through MAVSDK the requests are
    MAVSDK's business and not delivered to us: only our link shows their kind.)"""
    link, client, _ = px4_link
    items = _mission(end_action)
    assert items[0].command == mavlink.MAV_CMD_NAV_TAKEOFF
    with link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT") as sub:
        got = await client.upload_verified(items)
        kinds = {m.get_type() for m in sub.drain()}
    assert kinds == (set() if isinstance(link, MavsdkLink) else {"MISSION_REQUEST_INT"})
    assert len(got) == len(items)
    for sent, back in zip(items, got):
        assert compare_items(sent, back) is None, (sent, back)  # not even a storage rule needed


async def test_fence_reads_back_as_the_px4_storage_rules_say(px4_link) -> None:
    """Fence items come back in frame GLOBAL_INT with autocontinue 0, everything else kept (polygons first:
    PX4 warns wrongly that home is outside when an inclusion circle comes before an inclusion polygon)."""
    _, client, _ = px4_link
    frames = (mavlink.MAV_FRAME_GLOBAL_INT, FRAME_REL_ALT_INT)
    fence = [_fence_item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, n, e, 4.0, frames[i % 2])
             for i, (n, e) in enumerate(((-1500.0, -1500.0), (-1500.0, 1500.0), (1500.0, 1500.0), (1500.0, -1500.0)))]
    fence += [_fence_item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, n, e, 3.0, FRAME_REL_ALT_INT)
              for n, e in ((500.0, -500.0), (500.0, -400.0), (400.0, -450.0))]
    fence += [_fence_item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0.0, 2000.0, FRAME_REL_ALT_INT),
              _fence_item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 300.0, 300.0, 50.5, mavlink.MAV_FRAME_GLOBAL)]
    fence = [f.with_seq(i) for i, f in enumerate(fence)]
    got = await client.upload_verified(fence, FENCE)
    assert len(got) == len(fence)
    assert {g.autocontinue for g in got} == {0} and {g.frame for g in got} == {mavlink.MAV_FRAME_GLOBAL_INT}
    for sent, back in zip(fence, got):
        assert compare_items(stored(sent, Firmware.PX4), back) is None, (sent, back)
        assert back.z == sent.z and back.param1 == sent.param1


def _ring(vertices: int) -> list[MissionItem]:
    """One exclusion polygon of ``vertices`` vertices, 300 m round a point 3 km north of home (home stays outside)."""
    angles = [2.0 * math.pi * k / vertices for k in range(vertices)]
    return [_fence_item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, 3000.0 + 300.0 * math.sin(a),
                        300.0 * math.cos(a), float(vertices),
                        mavlink.MAV_FRAME_GLOBAL_INT).with_seq(k) for k, a in enumerate(angles)]


async def test_the_fence_capacity_the_companion_assumes_is_px4s(px4_link) -> None:
    """The pre-upload check's limit (companion.mavlink.fence_capacity) is PX4's: 64 fence items are stored; 65 the
    check refuses, and so does PX4 when sent anyway (MAV_MISSION_NO_SPACE at MISSION_COUNT); a fence refused part-way
    (a vertex count below 3 at item 5: MAV_MISSION_ERROR) leaves the stored fence as it was too, since PX4 writes an
    upload to its other fence slot and switches only when complete. The module's fence is put back afterwards."""
    link, client, _ = px4_link
    if isinstance(link, MavsdkLink):
        pytest.skip("the limit is the autopilot's, not the backend's: checked through our own link")
    cap = fence_capacity(link.autopilot, link.vehicle_type)
    before = await client.download(FENCE)
    fits, more = _ring(cap.max_items), _ring(cap.max_items + 1)
    assert cap.max_items == 64 and cap.fits(fits) and not cap.fits(more)
    try:
        await client.upload_verified(fits, FENCE)
        bad = _ring(10)
        bad[5] = replace(bad[5], param1=2.0)
        results = []
        for fence in (more, bad):
            with pytest.raises(MissionUploadError) as refused:
                await client.upload(fence, FENCE)
            results.append(refused.value.result)
        assert results == [mavlink.MAV_MISSION_NO_SPACE, mavlink.MAV_MISSION_ERROR]
        got = await client.download(FENCE)
        assert len(got) == len(fits)
        for sent, back in zip(fits, got):
            assert compare_items(stored(sent, Firmware.PX4), back) is None, (sent, back)
    finally:
        if before:
            await client.upload_verified(before, FENCE)
        else:
            await client.clear(FENCE)


async def test_set_current_falls_back_to_the_message_and_remembers(px4_link) -> None:
    """PX4 answers MAV_CMD_DO_SET_MISSION_CURRENT with UNSUPPORTED; the client then sends MISSION_SET_CURRENT
    (confirmed by MISSION_CURRENT) and does so straight away from then on. MAVSDK sends only the message (after
    a fence transfer, which MAVSDK 4.1 takes as the list to check the index against, it reads the mission first)."""
    link, client, sup = px4_link
    # through the supervisor, which uploads again after PX4's own transfer trouble (a MAV_MISSION_ERROR after the
    # last item, seen once here in CI); the fence's 1 item puts item 3 out of MAVSDK's range
    await sup.upload(_mission("loiter"), [_fence_item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0.0, 2000.0,
                                                      FRAME_REL_ALT_INT)])
    client.set_current_by_message = False
    with link.subscribe("COMMAND_ACK", predicate=lambda m: m.command == 224) as acks:
        for seq in (3, 1):
            with link.subscribe("MISSION_CURRENT", predicate=lambda m, seq=seq: m.seq == seq) as cur:
                await client.set_current(seq)
                assert (await cur.get(2.0)).seq == seq
        answers = [m.result for m in acks.drain()]
    if isinstance(link, MavsdkLink):
        assert answers == []
    else:
        assert answers == [mavlink.MAV_RESULT_UNSUPPORTED]  # asked once, never again
        assert client.set_current_by_message


async def test_a_mission_px4_stores_but_will_not_fly_is_reported_before_the_start(px4_link) -> None:
    """PX4 acknowledges and stores a mission whose takeoff is not the first item, then its navigator rejects it
    (MISSION_CURRENT mission_state NO_MISSION): the supervisor's upload says so instead of letting the start
    fail later."""
    _, _, sup = px4_link
    items = _mission("loiter")
    bad = [items[2].with_seq(0), items[0].with_seq(1), items[1].with_seq(2)] + items[3:]
    with pytest.raises(CompanionError, match="did not accept the mission"):
        await sup.upload(bad)
    await sup.upload(items)  # and a good one is accepted after it
    assert any(r["event"] == "mission_valid" for r in sup.events.records)


@pytest.mark.parametrize("px4_link", ["pymavlink"], indirect=True)  # PX4's behaviour: one backend is enough
async def test_the_rtl_end_action_returns_lands_and_disarms(px4_link) -> None:
    """The "rtl" end action as PX4 carries it out (a route with nothing between its end and home, no fence):
    after the last waypoint PX4 switches to AUTO.RTL, flies home, lands and disarms itself."""
    link, _, sup = px4_link
    await sup.upload(_mission("rtl", scale=0.5))  # a short flight: what is tested is what follows it
    seen: list[int] = []
    with link.subscribe("HEARTBEAT") as beats:
        await sup.start(0)
        async with asyncio.timeout(90.0):
            while True:
                hb = await beats.get()
                if not seen or seen[-1] != hb.custom_mode:
                    seen.append(hb.custom_mode)
                if AUTO_RTL in seen and not hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
                    break
    assert seen.index(AUTO_MISSION) < seen.index(AUTO_RTL), [hex(m) for m in seen]
    home = await link.wait_for("GLOBAL_POSITION_INT", timeout=5.0)
    north, east = _offset_m(home.lat, home.lon)
    assert math.hypot(north, east) < 10.0 and home.relative_alt < 2000  # on the ground at home (mm)


@pytest.mark.parametrize("px4_link", ["pymavlink"], indirect=True)
async def test_the_loiter_end_action_holds_over_the_goal_armed(px4_link) -> None:
    """The "loiter" end action (LOITER_UNLIM at the goal) as PX4 carries it out: once there it stays, armed, in
    AUTO.MISSION, over the goal and in the air."""
    link, _, sup = px4_link
    items = _mission("loiter", scale=0.5)
    last = len(items) - 1
    assert items[last].command == mavlink.MAV_CMD_NAV_LOITER_UNLIM
    await sup.upload(items)
    with link.subscribe("MISSION_CURRENT", predicate=lambda m: m.seq == last) as current:
        await sup.start(0)
        await current.get(90.0)
    await asyncio.sleep(2.0)  # 20 s of PX4's time: there, whatever the last leg's length
    hb = await link.wait_for("HEARTBEAT", timeout=5.0)
    pos = await link.wait_for("GLOBAL_POSITION_INT", timeout=5.0)
    assert hb.custom_mode == AUTO_MISSION and hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED, hex(hb.custom_mode)
    (n, e), (gn, ge) = _offset_m(pos.lat, pos.lon), _offset_m(items[last].x, items[last].y)
    assert math.hypot(n - gn, e - ge) < 20.0 and pos.relative_alt > 10_000  # over the goal, in the air (mm)

