"""Mode names from pymavlink's mode maps, for HEARTBEATs that came over a real UDP socket: ArduPlane, ArduCopter,
Rover and PX4 (main and sub mode), and the supervisor's words about an armed vehicle in such a mode."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.errors import CompanionError
from companion.mavlink.link import Link
from companion.mavlink.modes import heartbeat_mode, mode_name, mode_number
from companion.mavlink.protocol import MissionClient
from companion.mission.events import EventLog

AP, PX4, GENERIC = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_AUTOPILOT_PX4, mavlink.MAV_AUTOPILOT_GENERIC
PLANE, QUAD, ROVER = mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_TYPE_GROUND_ROVER
QUADPLANE = mavlink.MAV_TYPE_VTOL_QUADROTOR


def px4(main: int, sub: int = 0) -> int:
    """PX4's custom_mode (px4_custom_mode.h): main mode in bits 16-23, sub mode in bits 24-31."""
    return main << 16 | sub << 24


# (autopilot, type, base_mode, custom_mode, name): the base modes as ArduPilot 4.7 SITL and PX4 SITL send them
CASES = [
    (AP, PLANE, 81, 5, "FBWA"), (AP, PLANE, 89, 10, "AUTO"), (AP, PLANE, 89, 12, "LOITER"),
    (AP, PLANE, 81, 6, "FBWB"), (AP, PLANE, 17, 16, "INITIALISING"), (AP, QUADPLANE, 89, 19, "QLOITER"),
    (AP, QUAD, 89, 3, "AUTO"), (AP, QUAD, 89, 17, "BRAKE"), (AP, QUAD, 89, 16, "POSHOLD"),
    (AP, QUAD, 81, 0, "STABILIZE"), (AP, ROVER, 89, 4, "HOLD"), (AP, ROVER, 89, 10, "AUTO"),
    (AP, ROVER, 89, 15, "GUIDED"), (AP, ROVER, 81, 0, "MANUAL"),
    (PX4, QUAD, 157, px4(4, 4), "MISSION"), (PX4, QUAD, 157, px4(4, 3), "LOITER"), (PX4, QUAD, 157, px4(4, 5), "RTL"),
    (PX4, QUAD, 157, px4(4, 2), "TAKEOFF"), (PX4, QUAD, 81, px4(3), "POSCTL"), (PX4, PLANE, 81, px4(2), "ALTCTL"),
    (PX4, QUAD, 81, px4(9), "MODE_589824"),  # a main mode pymavlink does not know
    (GENERIC, PLANE, 89, 10, "AUTO"), (GENERIC, PLANE, 81, 5, "MODE_5"),  # another autopilot: its profile's table
    (AP, PLANE, 89, 99, "MODE_99"),
]


@pytest.mark.asyncio
async def test_mode_names_of_real_heartbeats(raw_peer) -> None:
    """Each HEARTBEAT sent over UDP by a different system, received by the link, named as pymavlink names it."""
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")  # learn the link's address
        with link.subscribe("HEARTBEAT", any_source=True) as sub:
            for system, (autopilot, vtype, base, custom, _) in enumerate(CASES, start=2):
                raw_peer.send(mavlink.MAVLink_heartbeat_message(vtype, autopilot, base, custom,
                                                                mavlink.MAV_STATE_STANDBY, 3), system, 1)
            got = {}
            while len(got) < len(CASES):
                hb = await sub.get(2.0)
                got[hb.get_srcSystem()] = heartbeat_mode(hb)
    assert [got[s] for s in range(2, len(CASES) + 2)] == [c[-1] for c in CASES]


def test_mode_numbers_from_pymavlink_and_the_profile() -> None:
    """Numbers by name: ArduPilot's from its vehicle type's map (FBWA, POSHOLD; a Rover's AUTO is 10, where
    ArduCopter's 3 is its STEERING), PX4's profile names (AUTO is AUTO.MISSION, HOLD AUTO.LOITER), else pymavlink's
    (POSCTL); unknown names are refused. Each name of the cases above goes back to its number."""
    assert mode_number(AP, PLANE, "AUTO") == 10 and mode_number(AP, PLANE, "FBWA") == 5
    assert mode_number(AP, ROVER, "AUTO") == 10 and mode_number(AP, QUADPLANE, "AUTO") == 10
    assert mode_number(AP, QUAD, "BRAKE") == 17 and mode_number(AP, QUAD, "POSHOLD") == 16
    assert mode_number(PX4, QUAD, "AUTO") == px4(4, 4) and mode_number(PX4, QUAD, "HOLD") == px4(4, 3)
    assert mode_number(PX4, QUAD, "POSCTL") == px4(3) and mode_number(PX4, QUAD, "MISSION") == px4(4, 4)
    for autopilot, vtype, _, _, name in CASES:
        if not name.startswith("MODE_"):
            assert mode_name(autopilot, vtype, mode_number(autopilot, vtype, name)) == name
    with pytest.raises(KeyError):
        mode_number(AP, PLANE, "WARP")


@pytest.mark.asyncio
async def test_an_armed_vehicle_is_refused_naming_its_mode(raw_peer) -> None:
    """The supervisor names the mode of the vehicle it finds (the ``connected`` event, the refusal of an armed one):
    an armed ArduPlane in FBWA is refused as being in FBWA, not in MODE_5."""
    events = EventLog()
    async with Link(f"udpout:127.0.0.1:{raw_peer.port}") as link:
        await raw_peer.recv_type("HEARTBEAT")
        armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED | 81
        raw_peer.send(mavlink.MAVLink_heartbeat_message(PLANE, AP, armed, 5, mavlink.MAV_STATE_ACTIVE, 3))
        sup = FlightSupervisor(link, MissionClient(link), events, arm=False)
        with pytest.raises(CompanionError, match=r"armed \(mode FBWA\)"):
            await sup.fly([])
    connected = next(r for r in events.records if r["event"] == "connected")
    assert connected["mode"] == "FBWA" and connected["armed"] is True
