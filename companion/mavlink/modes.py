"""Flight modes by name, from HEARTBEAT fields alone (for callers with a HEARTBEAT but no link, as the simulator's
traffic feed, and for what the companion says about a vehicle's mode).

Names are pymavlink's (``mavutil``), as MAVProxy prints them: ArduPilot's mode map of the vehicle type
(``mode_mapping_bynumber``: ArduPlane's FBWA is 5, ArduCopter's BRAKE 17, Rover's HOLD 4; a QuadPlane's types use
ArduPlane's), PX4's main and sub mode of ``custom_mode`` (``interpret_px4_mode``: MISSION is AUTO.MISSION, LOITER
AUTO.LOITER). :func:`mode_number` goes the other way with the same maps, PX4's names of the autopilot's profile
(:mod:`companion.mavlink.profiles`: AUTO, HOLD) first. (The supervisor commands modes by its profile's table.)
"""

from __future__ import annotations

from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.profiles import profile_for


def mode_name(autopilot: int | None, vehicle_type: int | None, custom_mode: int) -> str:
    """The name of the mode a HEARTBEAT reports (its ``autopilot``, ``type`` and ``custom_mode``): ArduPilot's and
    PX4's from pymavlink's mode maps, any other autopilot's from its profile's table; ``MODE_<n>`` for a number none
    of them knows."""
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        name = mavutil.interpret_px4_mode(0, custom_mode)  # base_mode: not read since PX4 1.12 (pymavlink #793)
        return f"MODE_{custom_mode}" if name == "UNKNOWN" else name
    if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        names = mavutil.mode_mapping_bynumber(vehicle_type) or {}
        if custom_mode in names:
            return names[custom_mode]
    return profile_for(autopilot, vehicle_type).mode_name(custom_mode)


def heartbeat_mode(hb: object) -> str:
    """:func:`mode_name` of a HEARTBEAT message."""
    return mode_name(hb.autopilot, hb.type, hb.custom_mode)  # type: ignore[attr-defined]  # pymavlink's messages are untyped


def mode_number(autopilot: int, vehicle_type: int, name: str) -> int:
    """custom_mode for a mode name on this autopilot and vehicle type: ArduPilot's from pymavlink's map of the
    vehicle type (a Rover's AUTO is 10, not ArduCopter's 3), else the profile's (PX4's AUTO is its AUTO.MISSION, HOLD
    its AUTO.LOITER), else PX4's from pymavlink's; ``KeyError`` for a name none of them knows."""
    if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        numbers = mavutil.mode_mapping_byname(vehicle_type) or {}
        if name in numbers:
            return numbers[name]
    profile = profile_for(autopilot, vehicle_type)
    if name in profile.modes:
        return profile.mode_number(name)
    if autopilot == mavlink.MAV_AUTOPILOT_PX4 and name in mavutil.px4_map:
        _, main, sub = mavutil.px4_map[name]
        return main << 16 | sub << 24
    raise KeyError(f"mode {name!r} is not known for autopilot {autopilot}, vehicle type {vehicle_type}")
