"""companion.mavlink.protocol over real sockets on 127.0.0.1, against three autopilots:

* a scripted ArduPilot-like peer (raw UDP socket) that requests in an awkward order, to pin the state machine;
* MAVSDK 4.x (libcmavsdk, bundled with the ``mavsdk`` wheel) as an autopilot with MissionRawServer;
* companion.sim.SimAutopilot, our simulated ArduPilot (home at 0, frame renumbering, loss).
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import socket
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from readback import same_item, same_mission

from companion.mavlink.errors import (
    CommandError,
    MissionTimeout,
    MissionUploadError,
    MissionVerifyError,
)
from companion.mavlink.items import (
    FENCE,
    FRAME_GLOBAL_INT,
    FRAME_MISSION,
    FRAME_REL_ALT_INT,
    MISSION,
    MissionItem,
    compare_items,
    mission_result_name,
)
from companion.mavlink.link import Link
from companion.mavlink.protocol import FINAL_ACK_MISSES, READ_WINDOW, MissionClient

pytestmark = pytest.mark.asyncio

SCENARIOS = Path(__file__).resolve().parents[3] / "sitl_scenarios"


def sample_mission() -> list[MissionItem]:
    """Six items: takeoff, speed change (MAV_FRAME_MISSION), three waypoints, loiter."""
    lat, lon = -353632610, 1491652300

    def wp(seq: int, dx: int, dy: int, z: float, cmd: int = mavlink.MAV_CMD_NAV_WAYPOINT, **kw) -> MissionItem:
        return MissionItem(seq, FRAME_REL_ALT_INT, cmd, x=lat + dx, y=lon + dy, z=z, **kw)

    return [
        wp(0, 0, 0, 50.0, mavlink.MAV_CMD_NAV_TAKEOFF, param1=10.0),
        MissionItem(1, FRAME_MISSION, mavlink.MAV_CMD_DO_CHANGE_SPEED, param1=0.0, param2=18.0, param3=-1.0),
        wp(2, 18000, 9000, 60.0, param2=20.0),
        wp(3, 36000, 27000, 75.5, param2=20.0, param3=5.0),
        wp(4, 54000, 54000, 80.0, param2=20.0),
        wp(5, 54000, 54000, 80.0, mavlink.MAV_CMD_NAV_LOITER_UNLIM, param3=60.0),
    ]


def sample_fence() -> list[MissionItem]:
    return [MissionItem(i, FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, param1=r,
                        x=-353632610 + dx, y=1491652300 + dy, mission_type=FENCE)
            for i, (dx, dy, r) in enumerate([(27000, 18000, 80.0), (9000, 36000, 70.0), (40000, 5000, 71.0)])]


def assert_same_items(sent: list[MissionItem], got: list[MissionItem], *, exact_frames: bool = True) -> None:
    assert len(got) == len(sent)
    for a, b in zip(sent, got):
        assert compare_items(a, b) is None, (a.seq, compare_items(a, b))
        if exact_frames:
            assert a.frame == b.frame, a.seq


# ---------------------------------------------------------------------------------------------------------------
# scripted ArduPilot-like peer
# ---------------------------------------------------------------------------------------------------------------

def ap_heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             0, 0, mavlink.MAV_STATE_STANDBY, 3)


async def _linked(raw_peer, **kw) -> tuple[Link, MissionClient]:
    link = Link(f"udpout:127.0.0.1:{raw_peer.port}")
    await link.open()
    await raw_peer.recv_type("HEARTBEAT")
    raw_peer.send(ap_heartbeat())
    await link.wait_heartbeat(2.0)
    return link, MissionClient(link, **kw)


async def test_upload_answers_legacy_repeated_earlier_and_out_of_order_requests(raw_peer):
    link, client = await _linked(raw_peer)
    items = sample_mission()
    try:
        upload = asyncio.create_task(client.upload(items))
        count = await raw_peer.recv_type("MISSION_COUNT")
        assert (count.count, count.mission_type, count.target_system, count.target_component) == (6, MISSION, 1, 1)
        order = [0, 1, 1, 0, 2, 4, 3, 5]  # a repeat, an earlier seq, out of order
        for n, seq in enumerate(order):
            req = (mavlink.MAVLink_mission_request_message if n % 2 == 0
                   else mavlink.MAVLink_mission_request_int_message)(1, 191, seq, MISSION)
            raw_peer.send(req)
            got = await raw_peer.recv_type("MISSION_ITEM_INT")
            assert got.seq == seq and got.get_srcComponent() == 191
            assert compare_items(items[seq], MissionItem.from_message(got)) is None
            assert got.frame == items[seq].frame
        assert not upload.done()
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_ACCEPTED, MISSION))
        await asyncio.wait_for(upload, 2.0)
    finally:
        await link.close()


async def test_upload_resends_count_then_times_out(raw_peer):
    # item_giveup_s=0: no extra patience for a live autopilot, so exactly the protocol's retries
    link, client = await _linked(raw_peer, timeout=0.1, retries=3, item_giveup_s=0.0)
    try:
        upload = asyncio.create_task(client.upload(sample_mission()))
        counts = 0
        with pytest.raises(MissionTimeout) as err:
            while not upload.done():
                try:
                    for m in await raw_peer.recv(0.2):
                        counts += m.get_type() == "MISSION_COUNT"
                except TimeoutError:
                    pass
            await upload
        assert counts == 4  # first + 3 retries
        assert err.value.operation == "upload" and err.value.seq is None
    finally:
        await link.close()


async def test_live_but_lossy_autopilot_gets_more_patience(raw_peer):
    """While the autopilot's HEARTBEATs keep coming, the client keeps resending past its retries (a lossy
    link), up to item_giveup_s; then it fails."""
    link, client = await _linked(raw_peer, timeout=0.1, retries=3, item_giveup_s=1.0)
    try:
        upload = asyncio.create_task(client.upload(sample_mission()))
        counts = 0
        t0 = time.monotonic()
        with pytest.raises(MissionTimeout):
            while not upload.done():
                raw_peer.send(ap_heartbeat())  # alive
                try:
                    for m in await raw_peer.recv(0.1):
                        counts += m.get_type() == "MISSION_COUNT"
                except TimeoutError:
                    pass
            await upload
        assert counts > 4 and 0.9 <= time.monotonic() - t0 < 3.0
    finally:
        await link.close()


async def test_invalid_sequence_is_not_fatal_but_other_nacks_are(raw_peer):
    link, client = await _linked(raw_peer)
    items = sample_mission()
    try:
        upload = asyncio.create_task(client.upload(items))
        await raw_peer.recv_type("MISSION_COUNT")
        raw_peer.send(mavlink.MAVLink_mission_request_message(1, 191, 0, MISSION))
        await raw_peer.recv_type("MISSION_ITEM_INT")
        # what ArduPilot says to a duplicate item: the transfer goes on
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_INVALID_SEQUENCE, MISSION))
        raw_peer.send(mavlink.MAVLink_mission_request_message(1, 191, 1, MISSION))
        assert (await raw_peer.recv_type("MISSION_ITEM_INT")).seq == 1
        raw_peer.send(mavlink.MAVLink_mission_request_message(1, 191, 2, MISSION))
        await raw_peer.recv_type("MISSION_ITEM_INT")
        # a NACK for another mission type or another system is not ours
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_DENIED, FENCE))
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_DENIED, MISSION), system=9)
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_INVALID_PARAM1, MISSION))
        with pytest.raises(MissionUploadError) as err:
            await asyncio.wait_for(upload, 2.0)
        assert err.value.result == mavlink.MAV_MISSION_INVALID_PARAM1 and err.value.seq == 2
        assert "MAV_MISSION_INVALID_PARAM1" in str(err.value)
    finally:
        await link.close()


def _item_int(item: MissionItem):
    return item.to_message(1, 191)


async def test_lost_final_ack_with_a_silent_autopilot_is_settled_by_readback(raw_peer):
    """MAVSDK and PX4 answer nothing to an item sent after the transfer ended: when the final ACK is lost, the
    client resends the last item a couple of times and then reads the list back, instead of waiting out its
    whole give-up time."""
    link, client = await _linked(raw_peer, timeout=0.1, item_giveup_s=30.0)
    items = sample_mission()
    try:
        t0 = time.monotonic()
        upload = asyncio.create_task(client.upload(items))
        await raw_peer.recv_type("MISSION_COUNT")
        for seq in range(len(items)):
            raw_peer.send(mavlink.MAVLink_mission_request_int_message(1, 191, seq, MISSION))
            await raw_peer.recv_type("MISSION_ITEM_INT")
        # the final ACK "goes missing": nothing is sent; the last item comes again until a readback starts
        resent = 0
        while True:
            kinds = [m.get_type() for m in await raw_peer.recv(2.0)]
            resent += kinds.count("MISSION_ITEM_INT")
            if "MISSION_REQUEST_LIST" in kinds:
                break
        assert resent == FINAL_ACK_MISSES - 1 and time.monotonic() - t0 < 2.0
        raw_peer.send(mavlink.MAVLink_mission_count_message(1, 191, len(items), MISSION))
        for _ in range(len(items)):
            req = await raw_peer.recv_type("MISSION_REQUEST_INT")
            raw_peer.send(_item_int(items[req.seq]))
        await asyncio.wait_for(upload, 2.0)  # confirmed by the readback
    finally:
        await link.close()


async def test_a_mission_error_after_the_last_item_with_a_different_readback_is_a_transfer_fault(raw_peer):
    """MAV_MISSION_ERROR right after the last item (PX4 busy, or ArduPilot answering a duplicate of that item) and
    a readback that is not the mission: the upload did not complete, but nothing was refused; the supervisor
    must upload again rather than give up (seen on PX4 SITL at 20x while it still flooded the link)."""
    link, client = await _linked(raw_peer, timeout=0.1, item_giveup_s=30.0)
    items = sample_mission()
    try:
        upload = asyncio.create_task(client.upload(items))
        await raw_peer.recv_type("MISSION_COUNT")
        for seq in range(len(items)):
            raw_peer.send(mavlink.MAVLink_mission_request_int_message(1, 191, seq, MISSION))
            await raw_peer.recv_type("MISSION_ITEM_INT")
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_ERROR, MISSION))
        await raw_peer.recv_type("MISSION_REQUEST_LIST")
        raw_peer.send(mavlink.MAVLink_mission_count_message(1, 191, 0, MISSION))  # nothing stored
        with pytest.raises(MissionUploadError) as err:
            await asyncio.wait_for(upload, 2.0)
        assert err.value.result == mavlink.MAV_MISSION_ERROR and err.value.transfer_fault
        assert not err.value.refused
    finally:
        await link.close()


async def test_a_stalled_download_is_started_again(raw_peer):
    """A server that dropped the download (MAVSDK after missing our requests) answers no more item requests
    but a new MISSION_REQUEST_LIST: the client starts again from the list request. (The peer says ArduPilot, so
    the requests for items 1 and 2 are in flight together, and each try asks for both again.)"""
    link, client = await _linked(raw_peer, timeout=0.1, item_timeout=0.05, item_giveup_s=30.0)
    items = sample_mission()[:3]
    try:
        download = asyncio.create_task(client.download())
        lists, ignored, dropped = 0, 0, False
        while not download.done():
            try:
                msgs = await raw_peer.recv(0.5)
            except TimeoutError:
                continue
            for m in msgs:
                if m.get_type() == "MISSION_REQUEST_LIST":
                    lists += 1
                    dropped = False
                    raw_peer.send(mavlink.MAVLink_mission_count_message(1, 191, len(items), MISSION))
                elif m.get_type() == "MISSION_REQUEST_INT":
                    if m.seq == 1 and lists == 1:
                        dropped = True  # from here the first download is dead
                    if dropped:
                        ignored += 1
                    else:
                        raw_peer.send(_item_int(items[m.seq]))
        got = await download
        assert lists == 2 and ignored == 2 * (client.retries + 1)
        assert_same_items(items, got)
    finally:
        await link.close()


async def test_command_long_counts_confirmations_and_maps_results(raw_peer):
    link, client = await _linked(raw_peer)
    try:
        cmd = asyncio.create_task(client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=0.2))
        first = await raw_peer.recv_type("COMMAND_LONG")
        second = await raw_peer.recv_type("COMMAND_LONG")  # no ACK for 0.2 s: resent
        assert (first.confirmation, second.confirmation) == (0, 1)
        assert (second.param1, second.param7, second.target_component) == (1.0, 0.0, 1)
        raw_peer.send(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                                          mavlink.MAV_RESULT_ACCEPTED, 0, 0, 1, 191))
        assert await asyncio.wait_for(cmd, 2.0) == mavlink.MAV_RESULT_ACCEPTED

        cmd = asyncio.create_task(client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1))
        await raw_peer.recv_type("COMMAND_LONG")
        raw_peer.send(mavlink.MAVLink_command_ack_message(mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                                          mavlink.MAV_RESULT_FAILED, 0, 0, 1, 191))
        with pytest.raises(CommandError) as err:
            await asyncio.wait_for(cmd, 2.0)
        assert err.value.result == mavlink.MAV_RESULT_FAILED and "MAV_RESULT_FAILED" in str(err.value)

        with pytest.raises(CommandError) as err:
            await client.command_long(mavlink.MAV_CMD_MISSION_START, timeout=0.05, retries=2)
        assert err.value.result is None
    finally:
        await link.close()


# ---------------------------------------------------------------------------------------------------------------
# MAVSDK 4.x MissionRawServer as the autopilot
# ---------------------------------------------------------------------------------------------------------------

def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class MavsdkAutopilot:
    """MAVSDK as an autopilot (system 1, component 1) listening on udpin://127.0.0.1:PORT; every uploaded plan
    (mission or fence) lands in :attr:`plans`."""

    async def __aenter__(self) -> MavsdkAutopilot:
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.mission_raw_server import MissionRawServerAsync

        self.port = _free_udp_port()
        config = Configuration.create_with_component_type(ComponentType.AUTOPILOT)
        self.sdk = Mavsdk(config)
        config.destroy()
        self.version = await self.sdk.version()
        await self.sdk.add_any_connection(f"udpin://127.0.0.1:{self.port}")
        self.server = MissionRawServerAsync(await self.sdk.server_component())
        self.plans: asyncio.Queue = asyncio.Queue()
        self._stream = self.server.subscribe_incoming_mission()
        self._collector = asyncio.create_task(self._collect(), name="mavsdk incoming_mission")
        await asyncio.sleep(0.01)  # the generator has subscribed
        return self

    async def _collect(self) -> None:
        async for result, plan in self._stream:
            await self.plans.put((result, plan))

    async def __aexit__(self, *exc: object) -> None:
        self._collector.cancel()
        await asyncio.gather(self._collector, return_exceptions=True)
        await self._stream.aclose()  # unsubscribes in its finally
        self.server.destroy()
        self.sdk.destroy()
        # MAVSDK's async wrapper runs blocking calls on the loop's default executor: end its threads here
        await asyncio.get_running_loop().shutdown_default_executor()


def from_mavsdk(item) -> MissionItem:
    return MissionItem(item.seq, item.frame, item.command, item.param1, item.param2, item.param3, item.param4,
                       item.x, item.y, item.z, item.current, item.autocontinue, item.mission_type)


async def test_mavsdk_mission_raw_server_mission_and_fence():
    import mavsdk

    assert mavsdk.__version__.startswith("4.")
    async with MavsdkAutopilot() as ap:
        assert ap.version.startswith("v4.")
        async with Link(f"udpout:127.0.0.1:{ap.port}") as link:  # first HEARTBEAT goes out on open
            await link.wait_heartbeat(5.0)
            assert (link.target_system, link.target_component) == (1, 1)
            assert link.autopilot == mavlink.MAV_AUTOPILOT_GENERIC  # MAVSDK's server says "generic"
            client = MissionClient(link)

            mission = sample_mission()
            await client.upload(mission)
            result, plan = await asyncio.wait_for(ap.plans.get(), 5.0)
            assert int(result) == 1  # MissionRawServerResult.SUCCESS
            assert_same_items(mission, [from_mavsdk(i) for i in plan.mission_items])  # no home-at-0 here
            assert [i.mission_type for i in plan.mission_items] == [MISSION] * 6

            fence = sample_fence()
            await client.upload(fence, mission_type=FENCE)
            result, plan = await asyncio.wait_for(ap.plans.get(), 5.0)
            assert int(result) == 1
            assert_same_items(fence, [from_mavsdk(i) for i in plan.mission_items])

            # readback: MAVSDK keeps both lists and answers downloads with exactly what it got
            assert_same_items(mission, await client.download(MISSION))
            assert_same_items(fence, await client.download(FENCE))
            got = await client.upload_verified(mission)  # home_at_zero: False (autopilot is not ArduPilot)
            assert len(got) == 6
            await asyncio.wait_for(ap.plans.get(), 5.0)

            # no COMMAND_ACK for DO_SET_MISSION_CURRENT: the MISSION_SET_CURRENT fallback confirms it
            await client.set_current(3, timeout=0.3, retries=1)


async def test_mavsdk_verified_uploads_through_a_lossy_link():
    """MAVSDK's MissionRawServer behind the fault proxy (30 % drop, 10 % duplicates, 10 % reordering each way):
    mission and fence uploads must still end verified by readback, through the supervisor's retries (MAVSDK has
    its own timeouts, answers no item after a transfer ended and drops a download whose requests it misses; the
    client's answers to those are pinned by the two scripted tests above). This seed takes 7–17 s here; others
    took up to 45 s, so one is run."""
    from companion.flight.supervisor import FlightSupervisor
    from companion.mission.events import EventLog
    from companion.sim.faultproxy import FaultProxy, Faults

    faults = Faults(drop=0.3, duplicate=0.1, reorder=0.1)
    async with MavsdkAutopilot() as ap:
        async with FaultProxy(("127.0.0.1", ap.port), faults, seed=1) as proxy:
            async with Link(f"udpout:127.0.0.1:{proxy.port}") as link:
                await link.wait_heartbeat(10.0)
                client = MissionClient(link)
                events = EventLog()
                mission, fence = sample_mission(), sample_fence()
                await FlightSupervisor(link, client, events, arm=False).upload(mission, fence)
                assert_same_items(mission, await client.download(MISSION))
                assert_same_items(fence, await client.download(FENCE))
                counters = proxy.counters
    assert counters.dropped > 0 and counters.duplicated > 0 and counters.reordered > 0
    assert events.records[-1]["event"] == "upload_verified"


# ---------------------------------------------------------------------------------------------------------------
# companion.sim.SimAutopilot: our simulated ArduPilot
# ---------------------------------------------------------------------------------------------------------------

def rescue_static_mission():
    from companion.mission.builder import MissionSpec, build_fence, build_mission
    from planner.world.scenario import load_scenario

    scenario = load_scenario(SCENARIOS / "rescue_static.toml")
    # a simple dog-leg route; the protocol does not care whether it is a planned one
    route = np.array([scenario.start, [300.0, 650.0, 80.0], [650.0, 800.0, 90.0], scenario.goal])
    spec = MissionSpec("ardupilot", scenario.vehicle, scenario.home)
    return scenario, build_mission(route, spec), build_fence(scenario.environment.cylinders, scenario.home)


@pytest.fixture
def sim_cls():
    from companion.sim import SimAutopilot  # written alongside; must exist for these tests to run

    return SimAutopilot


async def test_sim_upload_verified_download_set_current(sim_cls):
    scenario, mission, fence = rescue_static_mission()
    assert mission[0].seq == 0 and mission[1].command == mavlink.MAV_CMD_NAV_TAKEOFF
    async with sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim:
        async with Link(f"udpout:127.0.0.1:{sim.port}") as link:
            await link.wait_heartbeat(5.0)
            assert link.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
            client = MissionClient(link)
            got = await client.upload_verified(mission)  # home_at_zero inferred from HEARTBEAT.autopilot
            # item 0 is the sim's home (GLOBAL, AMSL); the rest reads back with plain frame numbers
            assert got[0].frame == mavlink.MAV_FRAME_GLOBAL
            assert got[1].frame == mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT  # 6 → 3
            again = await client.download()
            assert all(same_item(a, b) for a, b in zip(mission[1:], again[1:])) and len(again) == len(mission)
            await client.upload_verified(fence, mission_type=FENCE)
            await client.set_current(3)
            current = await link.wait_for("MISSION_CURRENT", predicate=lambda m: m.seq == 3, timeout=3.0)
            assert current.seq == 3
            await client.clear(FENCE)
            assert await client.download(FENCE) == []


async def test_sim_nack_maps_to_mission_upload_error(sim_cls):
    scenario, mission, _ = rescue_static_mission()
    bad = list(mission)
    bad[3] = replace(bad[3], param1=math.nan)  # NaN in param1 of a NAV_WAYPOINT
    async with sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim:
        async with Link(f"udpout:127.0.0.1:{sim.port}") as link:
            await link.wait_heartbeat(5.0)
            with pytest.raises(MissionUploadError) as err:
                await MissionClient(link).upload(bad)
            assert err.value.seq == 3
            assert mission_result_name(err.value.result) == "MAV_MISSION_INVALID_PARAM1"


@pytest.mark.parametrize("speedup", [5.0, 1.0])
async def test_sim_upload_survives_loss(sim_cls, speedup):
    """30 % loss each way: a request/answer round trip gets through about half the time. At real time the
    autopilot re-requests only every second (its own clock), so the client must not give up on a count of
    its own resends (that failed 6 of 6 seeds at 1x): it waits as long as the autopilot keeps the upload
    alive (ArduPilot abandons after 8 s without an item)."""
    scenario, mission, _ = rescue_static_mission()
    async with sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=speedup, loss=0.3, seed=7) as sim:
        async with Link(f"udpout:127.0.0.1:{sim.port}") as link:
            await link.wait_heartbeat(5.0)
            got = await MissionClient(link, retries=10).upload_verified(mission)
            assert len(got) == len(mission)


# ---------------------------------------------------------------------------------------------------------------
# upload_changed_verified: only the changed tail, where the autopilot takes MISSION_WRITE_PARTIAL_LIST
# ---------------------------------------------------------------------------------------------------------------

MISSION_MESSAGES = ("MISSION_COUNT", "MISSION_WRITE_PARTIAL_LIST", "MISSION_REQUEST_LIST", "MISSION_REQUEST_INT",
                    "MISSION_REQUEST", "MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_CLEAR_ALL")


class Sent:
    """Records the mission-protocol messages a :class:`Link` sends (its ``send`` wrapped)."""

    def __init__(self, link: Link) -> None:
        self.messages: list = []
        send = link.send

        def recording(msg) -> None:
            if msg.get_type() in MISSION_MESSAGES:
                self.messages.append(msg)
            send(msg)
        link.send = recording

    def of(self, mtype: str) -> list:
        return [m for m in self.messages if m.get_type() == mtype]

    def clear(self) -> None:
        self.messages.clear()


def moved_tail(mission: list[MissionItem], n: int, dz: float = 10.0) -> list[MissionItem]:
    """``mission`` with its last ``n`` items ``dz`` metres higher."""
    return mission[:-n] + [replace(it, z=it.z + dz) for it in mission[-n:]]


async def test_partial_write_only_where_the_autopilot_takes_it() -> None:
    """ArduPilot takes MISSION_WRITE_PARTIAL_LIST (MissionItemProtocol.cpp); PX4 ignores it without an answer;
    other autopilots are not assumed to."""
    from companion.mavlink.profiles import PROFILES

    takes = {p.name for p in PROFILES if p.partial_write}
    assert takes == {"ArduPlane", "ArduCopter", "ArduPilot VTOL"}


@pytest.mark.parametrize("vehicle", ["plane", "copter"])
async def test_sim_changed_tail_is_written_and_read_back_alone(sim_cls, vehicle):
    """Same length, the last two items changed: MISSION_WRITE_PARTIAL_LIST(n-2, n-1), the simulator requests
    only those two (legacy MISSION_REQUEST) and they alone are read back (MISSION_REQUEST_INT each, with the
    count); the stored mission is the new one. Nothing changed: nothing sent. Changes in the middle: that range
    alone. Another length: the whole list."""
    scenario, mission, _ = rescue_static_mission()
    new = moved_tail(mission, 2)
    n = len(mission)
    async with (sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0, vehicle=vehicle) as sim,
                Link(f"udpout:127.0.0.1:{sim.port}") as link):
        await link.wait_heartbeat(5.0)
        client = MissionClient(link)
        await client.upload_verified(mission)
        sent = Sent(link)
        with link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT") as requests:
            assert await client.upload_changed_verified(new, mission) == f"partial {n - 2}-{n - 1}"
            asked = requests.drain()
        assert [(r.get_type(), r.seq) for r in asked] == [("MISSION_REQUEST", n - 2), ("MISSION_REQUEST", n - 1)]
        partial = sent.of("MISSION_WRITE_PARTIAL_LIST")
        assert [(m.start_index, m.end_index) for m in partial] == [(n - 2, n - 1)]
        assert not sent.of("MISSION_COUNT") and len(sent.of("MISSION_REQUEST_LIST")) == 1
        assert [m.seq for m in sent.of("MISSION_REQUEST_INT")] == [n - 2, n - 1]
        assert [m.seq for m in sent.of("MISSION_ITEM_INT")] == [n - 2, n - 1]
        assert same_mission(new, await client.download())
        assert same_mission(new, sim.mission)

        sent.clear()
        assert await client.upload_changed_verified(new, new) == "unchanged"
        assert sent.messages == []

        middle = new[:n - 4] + [replace(it, z=it.z + 7.0) for it in new[n - 4:n - 2]] + new[n - 2:]
        sent.clear()
        with link.subscribe("MISSION_REQUEST", "MISSION_REQUEST_INT") as requests:  # ends where the changes end
            assert await client.upload_changed_verified(middle, new) == f"partial {n - 4}-{n - 3}"
            assert [r.seq for r in requests.drain()] == [n - 4, n - 3]
        assert [(m.start_index, m.end_index) for m in sent.of("MISSION_WRITE_PARTIAL_LIST")] == [(n - 4, n - 3)]
        assert [m.seq for m in sent.of("MISSION_REQUEST_INT")] == [n - 4, n - 3]
        assert same_mission(middle, await client.download())
        new = middle

        sent.clear()
        longer = new + [replace(new[-2], seq=n, z=123.0)]
        assert await client.upload_changed_verified(longer, new) == "whole"
        assert len(sent.of("MISSION_COUNT")) == 1 and not sent.of("MISSION_WRITE_PARTIAL_LIST")
        assert same_mission(longer, await client.download())


async def test_sim_a_change_at_item_0_alone_is_no_change_on_ardupilot(sim_cls):
    """ArduPilot ignores an uploaded item 0 (its home) and the readback never compares it: a mission that differs
    only there is unchanged; the first item that differs beyond it starts the range (and, alone, ends it)."""
    scenario, mission, _ = rescue_static_mission()
    other_home = [replace(mission[0], z=mission[0].z + 50.0)] + mission[1:]
    changed = [mission[0], replace(mission[1], z=mission[1].z + 5.0)] + mission[2:]
    async with (sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim,
                Link(f"udpout:127.0.0.1:{sim.port}") as link):
        await link.wait_heartbeat(5.0)
        client = MissionClient(link)
        await client.upload_verified(mission)
        assert await client.upload_changed_verified(other_home, mission) == "unchanged"
        assert await client.upload_changed_verified(changed, mission) == "partial 1-1"
        assert same_mission(changed, await client.download())


async def test_sim_partial_write_checks_what_the_vehicle_holds(sim_cls):
    """``previous`` is not what the vehicle holds. Shorter there: ArduPilot refuses the range (MAV_MISSION_ERROR,
    nothing written) and the whole list goes up, verified. Longer there: the range is written, but the count read
    back differs: MissionVerifyError, as a whole upload's readback would raise."""
    scenario, mission, _ = rescue_static_mission()
    n = len(mission)
    new = moved_tail(mission, 2)
    async with (sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim,
                Link(f"udpout:127.0.0.1:{sim.port}") as link):
        await link.wait_heartbeat(5.0)
        client = MissionClient(link)
        await client.upload_verified(mission[:3])
        assert await client.upload_changed_verified(new, mission) == "whole"
        assert same_mission(new, await client.download())

        await client.upload_verified(mission + [mission[-1], mission[-1]])
        with pytest.raises(MissionVerifyError) as err:
            await client.upload_changed_verified(new, mission)
        assert (err.value.seq, err.value.field, err.value.sent, err.value.got) == (n, "count", n, n + 2)


async def test_sim_refused_item_in_a_partial_write_is_a_refusal(sim_cls):
    """An item of the range refused: MissionUploadError naming it, a refusal (not retried by the supervisor);
    the items of the range before it are written, as in a whole upload (docs/autopilots.md §3.7)."""
    scenario, mission, _ = rescue_static_mission()
    n = len(mission)
    new = moved_tail(mission, 3)
    async with (sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim,
                Link(f"udpout:127.0.0.1:{sim.port}") as link):
        await link.wait_heartbeat(5.0)
        client = MissionClient(link)
        await client.upload_verified(mission)
        sim.inject_item_refusal(n - 2, mavlink.MAV_MISSION_INVALID_PARAM1)
        with pytest.raises(MissionUploadError) as err:
            await client.upload_changed_verified(new, mission)
        assert err.value.seq == n - 2 and err.value.refused
        left = sim.mission
        assert same_item(new[n - 3], left[n - 3]) and same_item(mission[n - 1], left[n - 1])


async def test_lost_final_ack_of_a_partial_write_is_settled_by_reading_the_range(raw_peer):
    """The final ACK of a partial write lost, the resent last item answered MAV_MISSION_ERROR (ArduPilot's
    answer to an item outside a transfer): the count and the range are read back, and they match."""
    link, client = await _linked(raw_peer, timeout=0.1, item_giveup_s=30.0)
    old = sample_mission()
    new = moved_tail(old, 2)
    try:
        upload = asyncio.create_task(client.upload_changed_verified(new, old))
        partial = await raw_peer.recv_type("MISSION_WRITE_PARTIAL_LIST")
        assert (partial.start_index, partial.end_index, partial.mission_type) == (4, 5, MISSION)
        for seq in (4, 5):
            raw_peer.send(mavlink.MAVLink_mission_request_message(1, 191, seq, MISSION))
            assert (await raw_peer.recv_type("MISSION_ITEM_INT")).seq == seq
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_ERROR, MISSION))
        await raw_peer.recv_type("MISSION_REQUEST_LIST")
        raw_peer.send(mavlink.MAVLink_mission_count_message(1, 191, len(new), MISSION))
        for seq in (4, 5):
            req = await raw_peer.recv_type("MISSION_REQUEST_INT")
            assert req.seq == seq
            raw_peer.send(_item_int(new[seq]))
        assert await asyncio.wait_for(upload, 2.0) == "partial 4-5"
    finally:
        await link.close()


async def test_px4_gets_the_whole_list(raw_peer):
    """PX4 ignores MISSION_WRITE_PARTIAL_LIST: the changed mission goes as a whole upload (MISSION_COUNT)."""
    link = Link(f"udpout:127.0.0.1:{raw_peer.port}")
    await link.open()
    try:
        await raw_peer.recv_type("HEARTBEAT")
        raw_peer.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4,
                                                        0, 0, mavlink.MAV_STATE_STANDBY, 3))
        await link.wait_heartbeat(2.0)
        assert not link.profile.partial_write
        old = sample_mission()
        new = moved_tail(old, 2)
        upload = asyncio.create_task(MissionClient(link).upload_changed_verified(new, old))
        assert (await raw_peer.recv_type("MISSION_COUNT")).count == len(new)
        for seq in range(len(new)):
            raw_peer.send(mavlink.MAVLink_mission_request_int_message(1, 191, seq, MISSION))
            await raw_peer.recv_type("MISSION_ITEM_INT")
        raw_peer.send(mavlink.MAVLink_mission_ack_message(1, 191, mavlink.MAV_MISSION_ACCEPTED, MISSION))
        await raw_peer.recv_type("MISSION_REQUEST_LIST")
        raw_peer.send(mavlink.MAVLink_mission_count_message(1, 191, len(new), MISSION))
        for _ in range(len(new)):
            req = await raw_peer.recv_type("MISSION_REQUEST_INT")
            raw_peer.send(_item_int(new[req.seq]))
        assert await asyncio.wait_for(upload, 2.0) == "whole"
    finally:
        await link.close()


@contextlib.asynccontextmanager
async def _mavsdk_client(sim, mission, shutdown_s: float | None = None):
    """The MAVSDK backend's client on ``sim`` with ``mission`` uploaded and verified. Afterwards MAVSDK is closed
    and the loop's default executor, where MAVSDK's async wrapper runs its blocking calls, shut down (within
    ``shutdown_s`` if given: a blocking call that never ended would hold it)."""
    from companion.mavlink.mavsdk_backend import MavsdkLink, MavsdkMissionClient

    link = MavsdkLink(f"udpout:127.0.0.1:{sim.port}")
    try:
        await link.open()
        await link.wait_heartbeat(5.0)
        client = MavsdkMissionClient(link)
        await client.upload_verified(mission)
        yield client
    finally:
        await link.close()
        await asyncio.wait_for(asyncio.get_running_loop().shutdown_default_executor(), shutdown_s)


async def test_mavsdk_backend_uploads_the_whole_list(sim_cls):
    """MAVSDK's mission_raw has no partial write: the MAVSDK backend's client does the whole verified upload, also
    on an ArduPilot vehicle."""
    scenario, mission, _ = rescue_static_mission()
    new = moved_tail(mission, 2)
    async with sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim, \
            _mavsdk_client(sim, mission) as client:
        assert await client.upload_changed_verified(new, mission) == "whole"
        assert same_mission(new, sim.mission)


async def test_mavsdk_set_current_unconfirmed_by_mavsdk_is_sent_as_the_message(sim_cls, monkeypatch, caplog):
    """An autopilot that ignores the first MISSION_SET_CURRENTs for a while (MAVSDK's call then waits beyond
    SET_CURRENT_S, or ends TIMEOUT: CI saw it twice on PX4): the MAVSDK client sends the message itself until
    MISSION_CURRENT confirms the item, and MAVSDK's abandoned call ends with it (no thread left behind)."""
    from companion.mavlink import mavsdk_backend

    monkeypatch.setattr(mavsdk_backend, "SET_CURRENT_S", 1.0)
    scenario, mission, _ = rescue_static_mission()
    async with sim_cls(scenario, listen="udpin:127.0.0.1:0", speedup=10.0) as sim, \
            _mavsdk_client(sim, mission, shutdown_s=10.0) as client:
        real = sim._server._on_set_current  # the autopilot's own handler, made hostile below
        calls: list[float] = []

        def deaf_at_first(seq: int) -> bool:  # nothing at all for 1.2 s after the first one: no MISSION_CURRENT
            calls.append(time.monotonic())
            return True if calls[-1] - calls[0] < 1.2 else real(seq)

        sim._server._on_set_current = deaf_at_first
        with caplog.at_level("WARNING", logger="companion.mavlink.mavsdk_backend"):
            await client.set_current(3)
        assert sim._nav.current_seq == 3
        assert "sending MISSION_SET_CURRENT itself" in caplog.text and len(calls) >= 2


@pytest.mark.parametrize("autopilot", ["ArduPilot", "PX4"])
async def test_a_readback_asks_for_a_window_of_items_at_once_only_from_ardupilot(raw_peer, autopilot):
    """ArduPilot answers single item requests outside a transfer, so a download has READ_WINDOW requests in flight
    (one of its loops per window, not per item); PX4 keeps download state, so it gets one request at a time. The
    items still come back in order, whatever order the answers arrive in."""
    link = Link(f"udpout:127.0.0.1:{raw_peer.port}")
    await link.open()
    items = (sample_mission() * 3)[:12]
    items = [replace(it, seq=i) for i, it in enumerate(items)]
    try:
        await raw_peer.recv_type("HEARTBEAT")
        ap = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA if autopilot == "ArduPilot" else mavlink.MAV_AUTOPILOT_PX4
        raw_peer.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_QUADROTOR, ap, 0, 0,
                                                        mavlink.MAV_STATE_STANDBY, 3))
        await link.wait_heartbeat(2.0)
        download = asyncio.create_task(MissionClient(link, item_timeout=1.0).download())
        await raw_peer.recv_type("MISSION_REQUEST_LIST")
        raw_peer.send(mavlink.MAVLink_mission_count_message(1, 191, len(items), MISSION))
        in_flight: list[int] = []
        deadline = time.monotonic() + 0.3  # shorter than the client's item timeout: no resends yet
        while time.monotonic() < deadline:
            with contextlib.suppress(TimeoutError):
                in_flight += [m.seq for m in await raw_peer.recv(0.02) if m.get_type() == "MISSION_REQUEST_INT"]
        want = list(range(READ_WINDOW)) if autopilot == "ArduPilot" else [0]
        assert in_flight == want
        answered = 0
        while not download.done():
            for seq in reversed(in_flight):  # answered last first
                raw_peer.send(_item_int(items[seq]))
                answered += 1
            in_flight = []
            with contextlib.suppress(TimeoutError):
                in_flight = [m.seq for m in await raw_peer.recv(0.1) if m.get_type() == "MISSION_REQUEST_INT"]
        assert_same_items(items, await download)
        assert answered == len(items)
    finally:
        await link.close()
