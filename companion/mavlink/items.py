"""Mission items as plain values, and their MAVLink conversions (docs/design.md, "Companion"; how autopilots
read them back: docs/autopilots.md §4).

One :class:`MissionItem` is one MISSION_ITEM_INT: lat/lon as degrees × 1e7 integers, altitude in metres
(relative to home for ``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``). Shared by the mission builder, the mission
protocol client, the exports and the simulated autopilot.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
FENCE = mavlink.MAV_MISSION_TYPE_FENCE
RALLY = mavlink.MAV_MISSION_TYPE_RALLY
FRAME_GLOBAL = mavlink.MAV_FRAME_GLOBAL
FRAME_GLOBAL_INT = mavlink.MAV_FRAME_GLOBAL_INT
FRAME_REL_ALT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
FRAME_REL_ALT_INT = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
FRAME_MISSION = mavlink.MAV_FRAME_MISSION

# ArduPilot answers downloads with the non-INT frame numbers even inside MISSION_ITEM_INT
_INT_TO_PLAIN = {
    mavlink.MAV_FRAME_GLOBAL_INT: mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT: mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT: mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
}


@dataclass(frozen=True)
class MissionItem:
    seq: int
    frame: int
    command: int
    param1: float = 0.0
    param2: float = 0.0
    param3: float = 0.0
    param4: float = 0.0
    x: int = 0  # latitude, degrees × 1e7
    y: int = 0  # longitude, degrees × 1e7
    z: float = 0.0  # altitude, metres (frame decides the reference)
    current: int = 0
    autocontinue: int = 1
    mission_type: int = MISSION

    @property
    def lat(self) -> float:
        return self.x / 1e7

    @property
    def lon(self) -> float:
        return self.y / 1e7

    def with_seq(self, seq: int) -> MissionItem:
        return replace(self, seq=seq)

    def to_message(self, target_system: int, target_component: int) -> mavlink.MAVLink_mission_item_int_message:
        """A MISSION_ITEM_INT message for this item."""
        return mavlink.MAVLink_mission_item_int_message(
            target_system, target_component, self.seq, self.frame, self.command, self.current,
            self.autocontinue, self.param1, self.param2, self.param3, self.param4, self.x, self.y,
            self.z, self.mission_type)

    @classmethod
    def from_message(cls, msg: Any) -> MissionItem:  # a pymavlink message
        """From MISSION_ITEM_INT, or the legacy float MISSION_ITEM (lat/lon in degrees)."""
        is_int = msg.get_type() == "MISSION_ITEM_INT"
        x = msg.x if is_int else round(msg.x * 1e7)
        y = msg.y if is_int else round(msg.y * 1e7)
        return cls(msg.seq, msg.frame, msg.command, msg.param1, msg.param2, msg.param3,
                   msg.param4, int(x), int(y), float(msg.z), msg.current, msg.autocontinue,
                   getattr(msg, "mission_type", MISSION))


def normalise_frame(frame: int) -> int:
    """The frame number with INT variants mapped to their plain twins (5→0, 6→3, 11→10)."""
    return _INT_TO_PLAIN.get(frame, frame)


# altitudes compare within this: ArduPilot keeps them as whole centimetres cut from float32 z × 100 (a C cast), so
# up to 1 cm lower plus float32's rounding; on SITL under load z 134.65000017 was read back as 134.63999939, and a
# 1.0 cm tolerance failed a replan's upload three times over
ALT_TOL_M = 0.011


def compare_items(sent: MissionItem, got: MissionItem, alt_tol: float = ALT_TOL_M,
                  param_tol: float = 1e-4) -> tuple[str, object, object] | None:
    """First ``(field, sent, got)`` difference between two items, or None: frames normalised, float params
    compared with a tolerance (they travel as float32), NaN equal to NaN, the current flag ignored. What an
    autopilot does not store is :func:`companion.mavlink.storage.stored`'s business, not this one's."""
    for f in fields(MissionItem):
        a, b = getattr(sent, f.name), getattr(got, f.name)
        if f.name == "current":
            continue  # the autopilot owns the current flag
        if f.name == "frame":
            a, b = normalise_frame(a), normalise_frame(b)
        if isinstance(a, float) or isinstance(b, float):
            if a != a and b != b:  # both NaN
                continue
            tol = alt_tol if f.name == "z" else param_tol * max(1.0, abs(a))
            if not abs(a - b) <= tol:
                return f.name, a, b
        elif a != b:
            return f.name, a, b
    return None


def mission_result_name(result: int) -> str:
    """MAV_MISSION_RESULT name for a number, e.g. 'MAV_MISSION_INVALID_PARAM1'."""
    entry = mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_MISSION_RESULT {result}"
