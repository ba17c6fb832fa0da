"""Flight-mode numbers per autopilot (ArduPilot custom modes; PX4 main/sub modes), from their sources."""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

ARDUPLANE = {"MANUAL": 0, "AUTO": 10, "RTL": 11, "LOITER": 12, "TAKEOFF": 13, "GUIDED": 15}
ARDUCOPTER = {"STABILIZE": 0, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9, "BRAKE": 17}
# PX4: custom_mode = main << 16 | sub << 24 (px4_custom_mode.h)
PX4 = {"AUTO": (4 << 16) | (4 << 24), "LOITER": (4 << 16) | (3 << 24), "RTL": (4 << 16) | (5 << 24),
       "HOLD": (4 << 16) | (3 << 24)}


def mode_number(autopilot: int, vehicle_type: int, name: str) -> int:
    """custom_mode for a mode name on this autopilot and vehicle type."""
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return PX4[name]
    if vehicle_type == mavlink.MAV_TYPE_FIXED_WING:
        return ARDUPLANE[name]
    return ARDUCOPTER[name]


def set_mode_params(autopilot: int, custom_mode: int) -> tuple[int, ...]:
    """MAV_CMD_DO_SET_MODE's params for ``custom_mode``: ArduPilot takes the custom mode in param2; PX4 its main
    mode in param2 and sub mode in param3."""
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)
    return (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode)


def hold_mode(autopilot: int, vehicle_type: int) -> str:
    """The mode that stops a vehicle where it is without a pilot: ArduPlane LOITER (circles the spot),
    ArduCopter BRAKE (LOITER would need the pilot's sticks for throttle), PX4 AUTO.LOITER (Hold)."""
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return "HOLD"
    return "LOITER" if vehicle_type == mavlink.MAV_TYPE_FIXED_WING else "BRAKE"


def mode_name(autopilot: int, vehicle_type: int, custom_mode: int) -> str:
    table = PX4 if autopilot == mavlink.MAV_AUTOPILOT_PX4 else (
        ARDUPLANE if vehicle_type == mavlink.MAV_TYPE_FIXED_WING else ARDUCOPTER)
    for name, number in table.items():
        if number == custom_mode:
            return name
    return f"MODE_{custom_mode}"
