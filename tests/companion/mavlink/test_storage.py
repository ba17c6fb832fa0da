"""The readback rules (companion.mavlink.storage) against values read back from ArduPilot 4.7 SITL (plane and copter).

Each case is an item as sent and the fields SITL returned for it (tests/conformance checks the same rules
against a live SITL where one is available; these keep the rules honest everywhere else).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, compare_items
from companion.mavlink.storage import Firmware, mission_difference, stored

PLANE, COPTER = Firmware.ARDUPLANE, Firmware.ARDUCOPTER
WP, TAKEOFF, LAND = mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_TAKEOFF, mavlink.MAV_CMD_NAV_LAND
REL, REL_INT, GLOBAL = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0
LAT, LON = -353622610, 1491662300


def _item(command: int, frame: int = REL_INT, mission_type: int = MISSION, **kw) -> MissionItem:
    return MissionItem(1, frame, command, x=kw.pop("x", LAT), y=kw.pop("y", LON), z=kw.pop("z", 60.0),
                       mission_type=mission_type, **kw)


# (firmware, sent, fields SITL read back)
SEEN = {
    "plane waypoint: radii in whole metres, no hold time, no yaw": (
        PLANE, _item(WP, param1=2.0, param2=30.0, param3=5.0, param4=math.nan),
        dict(frame=REL, param1=0.0, param2=30.0, param3=5.0, param4=0.0)),
    "plane waypoint: radius over a byte": (PLANE, _item(WP, param2=300.0), dict(param2=255.0)),
    "plane waypoint: fractional radius": (PLANE, _item(WP, param2=20.7), dict(param2=20.0)),
    "plane waypoint: negative pass-by wraps": (PLANE, _item(WP, param3=-20.7), dict(param3=255.0)),
    "copter waypoint: hold time only": (
        COPTER, _item(WP, param1=2.0, param2=30.0, param3=5.0, param4=math.nan),
        dict(param1=2.0, param2=0.0, param3=0.0, param4=0.0)),
    "takeoff pitch in whole degrees": (PLANE, _item(TAKEOFF, x=0, y=0, param1=5.5), dict(param1=5.0)),
    "land: whole-metre abort altitude, yaw as a sign": (
        COPTER, _item(LAND, param1=12.5, param4=0.0), dict(param1=12.0, param4=1.0)),
    "land: NaN yaw": (PLANE, _item(LAND, param4=math.nan), dict(param4=1.0)),
    "land: negative yaw": (PLANE, _item(LAND, param4=-30.0), dict(param4=-1.0)),
    "loiter radius in whole metres, sign kept": (
        PLANE, _item(mavlink.MAV_CMD_NAV_LOITER_UNLIM, param3=-60.5), dict(param3=-60.0)),
    "change speed: no frame, no position": (
        PLANE, _item(mavlink.MAV_CMD_DO_CHANGE_SPEED, frame=mavlink.MAV_FRAME_MISSION, param2=18.0, param3=-1.0),
        dict(frame=GLOBAL, x=0, y=0, z=0.0, param2=18.0, param3=-1.0)),
    "return to launch: no frame, no position": (
        COPTER, _item(mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH), dict(frame=GLOBAL, x=0, y=0, z=0.0)),
    "fence circle: position and radius only, no autocontinue": (
        PLANE, _item(mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, frame=mavlink.MAV_FRAME_GLOBAL_INT, z=12.0,
                     mission_type=FENCE, param1=50.5, param2=3.0),
        dict(frame=GLOBAL, z=0.0, param1=50.5, param2=0.0, autocontinue=0)),
    "fence polygon vertex: the count a whole number, cut (ArduPlane SITL: 4.4 → 4, 3.6 → 3)": (
        PLANE, _item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, mission_type=FENCE, param1=3.6, z=12.5),
        dict(frame=GLOBAL, param1=3.0, z=0.0, autocontinue=0)),
    "PX4 fence polygon vertex: the count rounded, altitude kept (PX4 SITL: 4.4 → 4, 3.6 → 4)": (
        Firmware.PX4, _item(mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, mission_type=FENCE, param1=3.6,
                            z=12.5), dict(frame=mavlink.MAV_FRAME_GLOBAL_INT, param1=4.0, autocontinue=0)),
    "rally point: whole-metre altitude, no autocontinue": (
        COPTER, _item(mavlink.MAV_CMD_NAV_RALLY_POINT, mission_type=RALLY, z=60.5), dict(z=60.0, autocontinue=0)),
}


@pytest.mark.parametrize("case", list(SEEN), ids=list(SEEN))
def test_stored_form_is_what_sitl_read_back(case: str) -> None:
    firmware, sent, readback = SEEN[case]
    got = replace(sent, **readback)
    assert compare_items(stored(sent, firmware), got) is None, (stored(sent, firmware), got)
    assert stored(got, firmware) == stored(stored(sent, firmware), firmware)  # applying the rules twice changes nothing


def test_a_real_difference_is_still_found() -> None:
    """The rules drop only what the autopilot does not keep: a moved waypoint or a changed radius differs."""
    sent = [MissionItem(0, GLOBAL, WP), _item(WP, param2=30.0)]
    assert mission_difference(sent, [sent[0], replace(sent[1], x=LAT + 100)], firmware=PLANE)[:2] == (1, "x")
    assert mission_difference(sent, [sent[0], replace(sent[1], param2=31.0)], firmware=PLANE)[:2] == (1, "param2")
    assert mission_difference(sent, [sent[0], replace(sent[1], param2=0.0)], firmware=COPTER) is None


def test_an_altitude_cut_to_whole_centimetres_from_float32_is_the_same_and_2_cm_is_not() -> None:
    """ArduPlane SITL read z 134.65000017 back as 134.63999939 (float32 z x 100 cut to whole centimetres): the same
    altitude; a 2 cm move is a difference."""
    sent = _item(WP, param2=30.0, z=134.65000017258637)
    assert mission_difference([sent], [replace(sent, z=134.63999938964844)], home_at_zero=False,
                              firmware=PLANE) is None
    assert mission_difference([sent], [replace(sent, z=134.63)], home_at_zero=False, firmware=PLANE)[:2] == (
        sent.seq, "z")


def test_other_autopilots_keep_every_field() -> None:
    sent = _item(WP, param1=2.0, param2=30.0, param4=math.nan)
    assert compare_items(stored(sent, Firmware.GENERIC), replace(sent, param2=0.0)) is not None
    assert Firmware.of(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_TYPE_FIXED_WING) is PLANE
    assert Firmware.of(mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_TYPE_QUADROTOR) is COPTER
    assert Firmware.of(mavlink.MAV_AUTOPILOT_PX4, mavlink.MAV_TYPE_QUADROTOR) is Firmware.PX4
