"""The flight's one telemetry subscription, read by the supervisor into the vehicle state, over real UDP on
127.0.0.1 with a raw MAVLink peer playing the autopilot and its ADS-B receiver.

What it must get right: messages read late (the backlog of the start sequence, read when the monitor starts) are
timed by their arrival, not by when they are read; and a lost autopilot is noticed even while an ADS-B receiver on
another path keeps sending.
"""

from __future__ import annotations

import asyncio
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.flight.supervisor import FixedMission, FlightOutcome, FlightSupervisor
from companion.mavlink.link import MAV_COMP_ID_ADSB, Link
from companion.mavlink.protocol import MissionClient
from companion.mission.builder import MissionSpec, build_mission
from companion.mission.events import EventLog
from companion.mission.vehicle_state import VehicleState, subscribe
from planner.world.scenario import load_scenario

SC = load_scenario(Path(__file__).resolve().parents[3] / "sitl_scenarios" / "rescue_static.toml")
VEHICLE = 2


def _heartbeat():
    return mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                             mavlink.MAV_MODE_FLAG_SAFETY_ARMED, 10, mavlink.MAV_STATE_ACTIVE, 3)


def _position(boot_ms: int):
    home = SC.home
    return mavlink.MAVLink_global_position_int_message(boot_ms, round(home.lat * 1e7), round(home.lon * 1e7),
                                                       round((home.alt + 60.0) * 1000), 60000, 1800, 0, 0, 0)


def _adsb(icao: int):
    flags = mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_VELOCITY
    return mavlink.MAVLink_adsb_vehicle_message(icao, -352000000, 1493000000, mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC,
                                                900000, 9000, 2500, 0, b"TEST", mavlink.ADSB_EMITTER_TYPE_LIGHT, 0,
                                                flags, 0)


async def _identified(raw_peer, link: Link) -> None:
    await raw_peer.recv_type("HEARTBEAT")  # the peer learns the link's address
    raw_peer.send(_heartbeat(), VEHICLE, 1)
    await link.wait_heartbeat(2.0)


@pytest.mark.asyncio
async def test_a_backlog_read_late_is_timed_by_its_arrival(raw_peer) -> None:
    """1.5 s of positions (10 Hz, vehicle time = wall time) wait unread, as they do during a start sequence, then
    1.2 s more are read as they come. Timed by when they were read, the backlog's first position would be 1.5
    vehicle seconds late, and the vehicle clock's rate 2.2 instead of 1."""
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await _identified(raw_peer, link)
        state = VehicleState(SC.home)  # no rate given: measured, as on a real autopilot
        boot_ms = 100_000
        with subscribe(link) as sub:
            t0 = time.monotonic()
            while (elapsed := time.monotonic() - t0) < 2.7:
                raw_peer.send(_position(boot_ms + round(1000 * elapsed)), VEHICLE, 1)
                await asyncio.sleep(0.1)
                if elapsed >= 1.5:  # the monitor has started: the backlog, then each message as it comes
                    for msg in sub.drain():
                        state.observe(msg)
            for msg in sub.drain():
                state.observe(msg)
            sent_up_to = boot_ms / 1000 + time.monotonic() - t0
    assert abs(state.clock.rate - 1.0) < 0.1, state.clock.rate
    assert abs(state.clock.now(time.monotonic()) - sent_up_to) < 0.3


@pytest.mark.asyncio
async def test_a_lost_autopilot_is_noticed_while_adsb_keeps_coming(raw_peer) -> None:
    """The autopilot falls silent while the vehicle's ADS-B receiver (component 156, on its own path) keeps
    reporting 20 times a second: the supervisor must still find the link lost, within its heartbeat timeout and
    a look, and the vehicle state must say so."""
    items = build_mission(np.array([[200.0, 200.0, 60.0], [600.0, 600.0, 80.0]]),
                          MissionSpec("ardupilot", SC.vehicle, SC.home))
    events = EventLog()
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}", heartbeat_timeout=1.0) as link:
        await _identified(raw_peer, link)
        pilot = FixedMission(items, VehicleState(SC.home))
        sup = FlightSupervisor(link, MissionClient(link), events, arm=False, home=SC.home)
        monitor = asyncio.create_task(sup.monitor(pilot, 30.0, FlightOutcome(False, "")))
        try:
            silent_at = time.monotonic()  # the last HEARTBEAT was just sent
            while time.monotonic() - silent_at < 2.5 and not pilot.state.link_down:
                raw_peer.send(_adsb(0xA00002), VEHICLE, MAV_COMP_ID_ADSB)
                await asyncio.sleep(0.05)
            found = time.monotonic() - silent_at
        finally:
            monitor.cancel()
            await asyncio.gather(monitor, return_exceptions=True)
    assert pilot.state.link_down and found < 1.0 + 0.5, found
    assert [r["event"] for r in events.records].count("link_lost") == 1
