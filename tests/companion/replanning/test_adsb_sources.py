"""Where ADS-B reports may come from: the target autopilot and an ADS-B receiver (component 156) of the same
vehicle, nothing else (another vehicle's receiver, a camera of ours, a GCS). Real UDP sockets on 127.0.0.1: a
raw peer plays the vehicle's components and other systems; the replanner's own subscription and, end to end, its
track picture are checked. Also: the same report arriving twice (receiver + autopilot relay, ArduPilot's 1 Hz
re-sends) is one contact, not a fresher one."""

from __future__ import annotations

import asyncio
import contextlib
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.flight.supervisor import FlightOutcome, FlightSupervisor
from companion.mavlink.link import MAV_COMP_ID_ADSB, Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import mission_from_plan_json, spec_from_plan_json
from companion.mission.events import EventLog
from companion.mission.geo import enu_to_geodetic
from companion.mission.vehicle_state import subscribe
from companion.replanning.replanner import LiveReplanner
from companion.replanning.threats import TrackPicture
from planner.world.home import Home
from planner.world.scenario import load_scenario

VEHICLE = 2  # the target system (not 1, so that it differs from our own system id)
OTHER = 3  # another vehicle
CAMERA = 100  # MAV_COMP_ID_CAMERA of our vehicle
GCS = (255, 190)
ALL_VALID = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_HEADING
             | mavlink.ADSB_FLAGS_VALID_VELOCITY)
# (system, component) → ICAO address of the report it sends; which ones must arrive
SOURCES = {(VEHICLE, 1): 0xA00001, (VEHICLE, MAV_COMP_ID_ADSB): 0xA00002, (OTHER, MAV_COMP_ID_ADSB): 0xA00003,
           (VEHICLE, CAMERA): 0xA00004, (OTHER, 1): 0xA00005, GCS: 0xA00006}
ACCEPTED = {0xA00001, 0xA00002}


def heartbeat(autopilot=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, vehicle=mavlink.MAV_TYPE_FIXED_WING, custom_mode=10):
    return mavlink.MAVLink_heartbeat_message(vehicle, autopilot, 0, custom_mode, mavlink.MAV_STATE_ACTIVE, 3)


def adsb(icao: int, lat: float = -35.2, lon: float = 149.3, alt_m: float = 900.0):
    return mavlink.MAVLink_adsb_vehicle_message(
        icao, round(lat * 1e7), round(lon * 1e7), mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC, round(alt_m * 1000), 9000,
        2500, 0, b"TEST", mavlink.ADSB_EMITTER_TYPE_LIGHT, 0, ALL_VALID, 0)


async def _vehicle_identified(raw_peer, link: Link) -> None:
    await raw_peer.recv_type("HEARTBEAT")  # the peer learns the link's address
    raw_peer.send(heartbeat(), VEHICLE, 1)
    await link.wait_heartbeat(2.0)
    assert (link.target_system, link.target_component) == (VEHICLE, 1)


def _send_from_everyone(raw_peer) -> None:
    # what an ADS-B receiver and the other components also send: none of it is the replanner's business
    raw_peer.send(heartbeat(mavlink.MAV_AUTOPILOT_INVALID, mavlink.MAV_TYPE_ADSB, custom_mode=77),
                  VEHICLE, MAV_COMP_ID_ADSB)
    raw_peer.send(heartbeat(mavlink.MAV_AUTOPILOT_INVALID, mavlink.MAV_TYPE_GCS, custom_mode=78), *GCS)
    raw_peer.send(mavlink.MAVLink_mission_current_message(9), VEHICLE, MAV_COMP_ID_ADSB)
    for (system, component), icao in SOURCES.items():
        raw_peer.send(adsb(icao), system, component)


async def _drain_after(sub, marker_icao: int, timeout: float = 2.0) -> list:
    """Everything ``sub`` got up to and including the ADSB_VEHICLE ``marker_icao`` (sent last, by the autopilot)."""
    got = []
    async with asyncio.timeout(timeout):
        while True:
            msg = await sub.get()
            got.append(msg)
            if msg.get_type() == "ADSB_VEHICLE" and msg.ICAO_address == marker_icao:
                return got


@pytest.mark.asyncio
async def test_extra_components_admit_only_those_components_of_the_target_system(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await _vehicle_identified(raw_peer, link)
        adsb_too = link.subscribe("ADSB_VEHICLE", "HEARTBEAT", "MISSION_CURRENT",
                                  extra_components={"ADSB_VEHICLE": [MAV_COMP_ID_ADSB]})
        autopilot_only = link.subscribe("ADSB_VEHICLE")
        everyone = link.subscribe("ADSB_VEHICLE", any_source=True)
        _send_from_everyone(raw_peer)
        raw_peer.send(adsb(0xFFFFFF), VEHICLE, 1)  # end marker
        got = await _drain_after(adsb_too, 0xFFFFFF)
        assert [m.ICAO_address for m in got if m.get_type() == "ADSB_VEHICLE"] == [0xA00001, 0xA00002, 0xFFFFFF]
        # the receiver's HEARTBEAT and MISSION_CURRENT are not ADSB_VEHICLE: not admitted from component 156
        assert [m.get_type() for m in got if m.get_type() != "ADSB_VEHICLE"] == []
        assert [m.ICAO_address for m in await _drain_after(autopilot_only, 0xFFFFFF)] == [0xA00001, 0xFFFFFF]
        # any_source is unchanged: every system and component
        assert [m.ICAO_address for m in await _drain_after(everyone, 0xFFFFFF)] == [*SOURCES.values(), 0xFFFFFF]
        for sub in (adsb_too, autopilot_only, everyone):
            sub.close()


@pytest.mark.asyncio
async def test_replanner_subscription_takes_adsb_from_the_autopilot_and_its_receiver(raw_peer):
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await _vehicle_identified(raw_peer, link)
        with subscribe(link) as sub:
            _send_from_everyone(raw_peer)
            raw_peer.send(heartbeat(custom_mode=11), VEHICLE, 1)
            raw_peer.send(adsb(0xFFFFFF), VEHICLE, 1)
            got = await _drain_after(sub, 0xFFFFFF)
        reports = [(m.get_srcSystem(), m.get_srcComponent(), m.ICAO_address)
                   for m in got if m.get_type() == "ADSB_VEHICLE"]
        assert reports == [(VEHICLE, 1, 0xA00001), (VEHICLE, MAV_COMP_ID_ADSB, 0xA00002), (VEHICLE, 1, 0xFFFFFF)]
        # only the autopilot's HEARTBEAT (the replanner reads the flight mode from it), not the receiver's, and
        # not the receiver's MISSION_CURRENT
        others = [(m.get_type(), m.get_srcComponent()) for m in got if m.get_type() != "ADSB_VEHICLE"]
        assert others == [("HEARTBEAT", 1)]


async def _until(condition, timeout: float = 2.0) -> None:
    async with asyncio.timeout(timeout):
        while not condition():
            await asyncio.sleep(0.02)


@pytest.mark.asyncio
async def test_replanner_track_picture_from_the_autopilot_and_its_receiver(raw_peer, static_plan_doc):
    """End to end through the flight's one subscription, read by the supervisor's monitor into the vehicle state,
    and LiveReplanner.run beside it: tracks from the two accepted sources, none from the others."""
    scenario = load_scenario(Path(__file__).resolve().parents[3] / "sitl_scenarios" / "rescue_static.toml")
    doc = static_plan_doc()
    items = mission_from_plan_json(doc, scenario, "ardupilot")
    spec = spec_from_plan_json(doc, scenario, "ardupilot")
    home = scenario.home
    far_lat, far_lon, _ = enu_to_geodetic(np.array([20000.0, 20000.0, 0.0]), home)  # well clear of the route
    events = EventLog()
    async with contextlib.AsyncExitStack() as stack:
        # LiveReplanner.aclose stops its planner process from a thread of the loop's default executor
        stack.push_async_callback(asyncio.get_running_loop().shutdown_default_executor)
        link = await stack.enter_async_context(Link(f"udpout:127.0.0.1:{raw_peer.port}"))
        await _vehicle_identified(raw_peer, link)
        rp = await stack.enter_async_context(
            LiveReplanner(link, MissionClient(link), events, scenario, spec, items, rate=1.0))
        sup = FlightSupervisor(link, MissionClient(link), events, arm=False, home=home)
        task = asyncio.create_task(sup.monitor(rp, 30.0, FlightOutcome(False, "")))
        stack.push_async_callback(asyncio.gather, task, return_exceptions=True)
        stack.callback(task.cancel)
        await asyncio.sleep(0.1)  # subscribed
        raw_peer.send(mavlink.MAVLink_global_position_int_message(
            5000, round(home.lat * 1e7), round(home.lon * 1e7), 0, 0, 0, 0, 0, 0), VEHICLE, 1)
        await _until(lambda: rp.state.clock.synced)
        rp.state.mission_started(time.monotonic())
        raw_peer.send(heartbeat(custom_mode=10), VEHICLE, 1)  # AUTO
        for source in ((VEHICLE, MAV_COMP_ID_ADSB), GCS):
            raw_peer.send(heartbeat(mavlink.MAV_AUTOPILOT_INVALID, mavlink.MAV_TYPE_ADSB, custom_mode=77), *source)
        for source, icao in SOURCES.items():
            raw_peer.send(adsb(icao, float(far_lat), float(far_lon)), *source)
        await _until(lambda: len(rp.prediction.tracks) >= len(ACCEPTED))
        await asyncio.sleep(0.2)  # anything else would have arrived by now
        assert set(rp.prediction.tracks.tracks) == ACCEPTED
        assert {e["id"] for e in events.records if e["event"] == "track"} == {f"adsb-{i:06x}" for i in ACCEPTED}
        assert rp.state.custom_mode == 10  # the receiver's and the GCS's HEARTBEATs were not taken for the mode


# --- the same report twice -------------------------------------------------------------------------------------

HOME = Home(47.0, 8.0, 500.0)


def _report(enu, tslc=0, icao=0xABC123, speed_cms=2500):
    lat, lon, _ = enu_to_geodetic(np.asarray(enu, dtype=float), HOME)
    return mavlink.MAVLink_adsb_vehicle_message(
        icao, round(float(lat) * 1e7), round(float(lon) * 1e7), mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC,
        round((HOME.alt + enu[2]) * 1000), 9000, speed_cms, 0, b"INTRUDR1", mavlink.ADSB_EMITTER_TYPE_UAV, tslc,
        ALL_VALID, 0)


def test_a_repeated_report_is_not_a_fresher_contact():
    picture = TrackPicture(HOME)
    first = picture.update(_report([0.0, 0, 50]), now=10.0)  # from the receiver
    # the autopilot relays it (and ArduPilot re-sends it every second) with the tslc it arrived with
    again = picture.update(_report([0.0, 0, 50]), now=10.8)
    assert again.t_contact == first.t_contact == 10.0 and again.last_heard == 10.8
    picture.update(_report([0.0, 0, 50]), now=13.0)
    # prediction and radius growth run from the contact, expiry from the last time it was heard
    (threat,) = picture.threat_items(40.0, 0.5)
    assert threat.t_ref == 10.0
    assert picture.expire(now=20.0, max_age=8.0) == []
    assert picture.expire(now=21.5, max_age=8.0) == ["adsb-abc123"]
    # a report that moved is a new contact
    picture.update(_report([0.0, 0, 50]), now=30.0)
    moved = picture.update(_report([25.0, 0, 50]), now=31.0)
    assert moved.t_contact == 31.0 and moved.t_heard is None


def test_a_stationary_object_reported_again_is_a_fresh_contact():
    # ArduPilot's simulated ADS-B reports its point obstacles unchanged, with zero velocity, every second
    picture = TrackPicture(HOME)
    picture.update(_report([500.0, 0, 50], tslc=1, speed_cms=0), now=10.0)
    again = picture.update(_report([500.0, 0, 50], tslc=1, speed_cms=0), now=11.0)
    assert again.t_contact == 10.0 and again.velocity == (0.0, 0.0, 0.0)  # its radius does not grow for ever
