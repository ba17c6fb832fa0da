"""What an autopilot keeps of a mission, fence or rally item: the readback comparison rules, written once.

An autopilot does not store a MISSION_ITEM_INT as sent. ArduPilot packs each command into a 15-byte record
(AP_Mission) and each fence or rally point into its own small record, so a readback returns only what that
record carries: frames as their non-INT twins, commands without a position in frame GLOBAL, fence and rally
points with autocontinue 0 and without the fields they do not use, NAV_WAYPOINT's acceptance and pass-by
radii as whole metres up to 255 on a plane and not at all on a copter (which keeps the hold time instead),
NAV_LAND's yaw as a sign. Whole-number fields are truncated toward zero, as a C cast does.
:func:`stored` maps an item to that form; an upload is verified by comparing ``stored(sent)`` with
``stored(got)`` (:func:`companion.mavlink.items.compare_items`), and the built-in simulator stores ``stored(item)``
so that its readback is the real one. Every rule here was seen on ArduPilot 4.7 SITL (plane and copter) or PX4
SITL and is checked by the conformance tests (tests/conformance, tests/px4). PX4 keeps every field of a mission
item and only drops a fence item's frame and autocontinue. Commands not listed keep every field (strict).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import FENCE, RALLY, MissionItem, compare_items, normalise_frame
from companion.mavlink.profiles import Firmware  # which of these rules an autopilot follows: its profile's ``storage``

# ArduPilot commands kept without a position: read back in frame GLOBAL with x = y = z = 0
_NO_POSITION = frozenset({mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH})
_BYTE_MAX = 255  # ArduPlane packs NAV_WAYPOINT's acceptance and pass-by radii in one byte each
_POLYGON_VERTEX = frozenset({mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                             mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION})


def stored(item: MissionItem, firmware: Firmware) -> MissionItem:
    """``item`` as ``firmware`` stores it and returns it in a readback (frames always normalised)."""
    item = replace(item, frame=normalise_frame(item.frame))
    if firmware is Firmware.PX4:
        return _stored_px4(item)
    if not firmware.ardupilot:
        return item
    if item.frame == mavlink.MAV_FRAME_MISSION:  # no position: ArduPilot keeps no frame
        item = replace(item, frame=mavlink.MAV_FRAME_GLOBAL)
    if item.mission_type in (FENCE, RALLY):
        return _stored_point(item)
    cmd = item.command
    if cmd in _NO_POSITION:
        item = replace(item, frame=mavlink.MAV_FRAME_GLOBAL, x=0, y=0, z=0.0)
    if cmd == mavlink.MAV_CMD_NAV_WAYPOINT:
        if firmware is Firmware.ARDUPLANE:  # radii in whole metres (truncated, as a C cast), no hold time
            return replace(item, param1=0.0, param2=_byte(item.param2), param3=_byte(item.param3), param4=0.0)
        return replace(item, param1=_whole(item.param1), param2=0.0, param3=0.0, param4=0.0)  # hold time, s
    if cmd == mavlink.MAV_CMD_NAV_LOITER_UNLIM:  # radius as whole metres, its sign is the direction
        return replace(item, param1=0.0, param2=0.0, param3=math.copysign(_whole(abs(item.param3)), item.param3),
                       param4=0.0)
    if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:  # minimum pitch, whole degrees
        return replace(item, param1=_whole(item.param1), param2=0.0, param3=0.0, param4=0.0)
    if cmd == mavlink.MAV_CMD_NAV_LAND:  # abort altitude in whole metres; param4 (yaw) as its sign only
        return replace(item, param1=_whole(item.param1), param2=0.0, param3=0.0,
                       param4=-1.0 if item.param4 < 0 else 1.0)
    if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
        return replace(item, param1=0.0, param2=0.0, param3=0.0, param4=0.0)
    return item


def _stored_point(item: MissionItem) -> MissionItem:
    """An ArduPilot fence or rally point: position (and param1: a circle's radius or a polygon's vertex
    count, a byte: 4.4 and 3.6 read back 4 and 3) only; stored without a frame for fences, with autocontinue 0 for
    both (rally: whole-metre altitude)."""
    if item.mission_type == FENCE:
        count = _byte(item.param1) if item.command in _POLYGON_VERTEX else item.param1  # vertex count: a uint8
        return replace(item, frame=mavlink.MAV_FRAME_GLOBAL, param1=count, param2=0.0, param3=0.0, param4=0.0, z=0.0,
                       autocontinue=0)
    return replace(item, param1=0.0, param2=0.0, param3=0.0, param4=0.0, z=float(math.trunc(item.z)),
                   autocontinue=0)  # rally altitude in whole metres


def _stored_px4(item: MissionItem) -> MissionItem:
    """PX4 (navigator's dataman records, measured on PX4 SITL main 2026-05): mission and rally items come back
    as sent (frames as their INT twins, normalised here); fence items in frame GLOBAL_INT whatever was sent,
    with autocontinue 0, position, altitude and params kept, a polygon's vertex count rounded to a whole number
    (a uint16: 4.4 and 3.6 read back 4)."""
    if item.mission_type == FENCE:
        count = float(math.floor(item.param1 + 0.5)) if item.command in _POLYGON_VERTEX else item.param1
        return replace(item, frame=mavlink.MAV_FRAME_GLOBAL, param1=count, autocontinue=0)
    return item


def _whole(value: float) -> float:
    """A float param kept as an unsigned 16-bit integer (truncated; NaN → 0)."""
    return float(int(value)) if math.isfinite(value) and value > 0 else 0.0


def _byte(value: float) -> float:
    """A float param kept in one byte: whole metres up to 255; a negative one wraps and reads back 255."""
    return float(_BYTE_MAX) if value < 0 else min(float(_BYTE_MAX), _whole(value))


def changed_range(new: Sequence[MissionItem], old: Sequence[MissionItem], home_at_zero: bool = True,
                  firmware: Firmware = Firmware.GENERIC) -> tuple[int, int] | None:
    """``(first, last)`` seqs of the items that differ between two lists of one length as ``firmware`` stores them
    (item 0 skipped with ``home_at_zero``), or None when none does: the range a partial write must cover."""
    if len(new) != len(old):
        raise ValueError(f"lists of {len(new)} and {len(old)} items have no common range")
    changed = [a.seq for a, b in zip(new, old) if not (home_at_zero and a.seq == 0)
               and compare_items(stored(a, firmware), stored(b, firmware)) is not None]
    return (changed[0], changed[-1]) if changed else None


def mission_difference(sent: Sequence[MissionItem], got: Sequence[MissionItem], home_at_zero: bool = True,
                       firmware: Firmware = Firmware.GENERIC) -> tuple[int, str, object, object] | None:
    """First ``(seq, field, sent, got)`` difference between an upload and its readback (or any two lists) as
    ``firmware`` stores them, or None. ``home_at_zero``: skip item 0, which ArduPilot replaces with its home."""
    if len(got) != len(sent):
        return min(len(got), len(sent)), "count", len(sent), len(got)
    for a, b in zip(sent, got):
        if home_at_zero and a.seq == 0:
            continue  # ArduPilot's home: acknowledged, ignored, read back as the real home
        diff = compare_items(stored(a, firmware), stored(b, firmware))
        if diff is not None:
            return (a.seq, *diff)
    return None
