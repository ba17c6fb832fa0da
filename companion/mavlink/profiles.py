"""Autopilot profiles: what the companion knows of each autopilot family, written once, as data.

ArduPlane, ArduCopter, PX4 and other MAVLink autopilots differ in how they boot, when they are ready to arm, how
they store items, how a mission is started, how a vehicle is held, when a waypoint counts as reached and what
they do with a mission uploaded in flight. The layers above ask the target's :class:`AutopilotProfile`
(``link.profile``, from its HEARTBEAT through :func:`profile_for`) instead of branching on its identity. The
facts were measured on ArduPilot 4.7 SITL and PX4 SITL (or read in their sources where said so) and are checked
by the conformance tests (tests/conformance, tests/px4).

The mission builder works from a layout key that PLAN.json and the exports carry (``"ardupilot"``, ``"px4"``):
:data:`LAYOUTS` holds each layout's facts, and every profile names its :attr:`AutopilotProfile.layout`.

A value module: it imports nothing of the companion.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Literal

from pymavlink.dialects.v20 import common as mavlink


class Firmware(enum.Enum):
    """How an autopilot stores items (:func:`companion.mavlink.storage.stored`): ArduPlane and the other ArduPilot
    vehicles differ in NAV_WAYPOINT."""

    ARDUPLANE = "arduplane"
    ARDUCOPTER = "arducopter"  # also Rover and Sub: AP_Mission's non-plane branch
    PX4 = "px4"
    GENERIC = "generic"  # stores every field (MAVSDK's MissionRawServer)

    @classmethod
    def of(cls, autopilot: int | None, vehicle_type: int | None) -> Firmware:
        """From a HEARTBEAT's ``autopilot`` and ``type``: its profile's :attr:`AutopilotProfile.storage`."""
        return profile_for(autopilot, vehicle_type).storage

    @property
    def ardupilot(self) -> bool:
        return self in (Firmware.ARDUPLANE, Firmware.ARDUCOPTER)


# --- mission layout (the builder's key) --------------------------------------------------------------------------

LayoutKey = Literal["ardupilot", "px4", "px4-vtol"]  # the keys of LAYOUTS (the builder's Autopilot)


@dataclass(frozen=True)
class MissionLayout:
    """How the builder lays out a mission for one layout key (PLAN.json's and the exports' ``autopilot``)."""

    key: LayoutKey
    # item 0 is a NAV_WAYPOINT at home, frame GLOBAL, AMSL altitude (ArduPilot: ignored on upload, the autopilot's
    # home); PX4 has no home item, so its first item is the takeoff at seq 0
    home_item: bool
    # param4 (yaw) of NAV commands: PX4 reads NaN as "keep heading" (0 would mean north); ArduPilot does not store
    # it and reads back 0, so 0 keeps upload verification exact
    nav_yaw: float
    # NAV_WAYPOINT param2 (acceptance radius): vehicle types that do not store it get 0 (ArduCopter reads back 0
    # and uses its WPNAV_RADIUS); the others get whole metres up to ``acceptance_max_m`` (ArduPlane keeps them in
    # one byte, so send exactly what it will read back), or the radius as it is when that is None
    acceptance_dropped: frozenset[str]
    acceptance_max_m: int | None
    qgc_firmware_type: int  # a QGroundControl .plan's firmwareType (MAV_AUTOPILOT)
    # a VTOL's mission: NAV_VTOL_TAKEOFF (a vertical climb, then the transition towards the item's position) and
    # NAV_VTOL_LAND (back-transition, vertical landing) instead of NAV_TAKEOFF and NAV_LAND
    vtol: bool = False

    def acceptance_param(self, radius: float, vehicle_type: str) -> float:
        """NAV_WAYPOINT param2 for an acceptance ``radius`` (m) on a ``vehicle_type`` ("plane", "copter")."""
        if vehicle_type in self.acceptance_dropped:
            return 0.0
        if self.acceptance_max_m is None:
            return float(radius)
        return float(min(self.acceptance_max_m, max(0, round(radius))))


ARDUPILOT_LAYOUT = MissionLayout("ardupilot", home_item=True, nav_yaw=0.0, acceptance_dropped=frozenset({"copter"}),
                                 acceptance_max_m=255, qgc_firmware_type=mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
PX4_LAYOUT = MissionLayout("px4", home_item=False, nav_yaw=math.nan, acceptance_dropped=frozenset(),
                           acceptance_max_m=None, qgc_firmware_type=mavlink.MAV_AUTOPILOT_PX4)
# PX4's VTOLs (the SIH standard VTOL, airframe 10043, flies it: docs/px4.md)
PX4_VTOL_LAYOUT = replace(PX4_LAYOUT, key="px4-vtol", vtol=True)
LAYOUTS: Mapping[str, MissionLayout] = MappingProxyType(
    {lay.key: lay for lay in (ARDUPILOT_LAYOUT, PX4_LAYOUT, PX4_VTOL_LAYOUT)})


def mission_layout(key: str) -> MissionLayout:
    """The layout for a PLAN.json/export key; ValueError for an unknown one."""
    try:
        return LAYOUTS[key]
    except KeyError:
        raise ValueError(f"autopilot must be {' or '.join(map(repr, LAYOUTS))}, got {key!r}") from None


# --- the profile ---------------------------------------------------------------------------------------------------

# the steps of a start sequence
MODE = "mode:"  # "mode:NAME": MAV_CMD_DO_SET_MODE to the mode NAME
ARM = "arm"  # MAV_CMD_COMPONENT_ARM_DISARM by the companion (only when it may arm)
PILOT_ARM = "pilot_arm"  # wait for the pilot to arm
START = "start"  # MAV_CMD_MISSION_START


@dataclass(frozen=True, eq=False)
class AutopilotProfile:
    """What one autopilot family does where the companion must know it. Picked by :func:`profile_for`; compare
    profiles by identity (``is``). Mode names are keys of ``modes``."""

    name: str
    layout: LayoutKey  # key of LAYOUTS the builder uses for this autopilot

    # -- boot: a HEARTBEAT in one of these states (or custom modes) is still booting; with ``boot_needs_status``
    #    a first SYS_STATUS must come too before the mission is touched (ArduPilot refuses every upload with
    #    MAV_MISSION_NO_SPACE while it boots)
    booting_states: frozenset[int]
    booting_modes: frozenset[int]
    boot_needs_status: bool

    # -- readiness: read the pre-arm bit of SYS_STATUS's health even when it is not in present
    prearm_health_only: bool

    # -- storage and readback
    storage: Firmware  # what it keeps of each item (companion.mavlink.storage.stored)
    home_at_zero: bool  # replaces mission item 0 by its home (upload and readback compare from seq 1)
    min_fence_items: int  # a fence upload of fewer items needs a cleared fence first (0: never)
    error_may_be_transfer_fault: bool  # its MAV_MISSION_ERROR may stand for its own transfer trouble
    # takes MISSION_WRITE_PARTIAL_LIST (overwrites a range in place, requesting it item by item) and answers a
    # single MISSION_REQUEST_INT outside a transfer, so a changed tail is written and read back alone
    # (MissionClient.upload_changed_verified); PX4 ignores a partial list without an answer
    partial_write: bool

    # -- start
    modes: Mapping[str, int]  # mode name → HEARTBEAT custom_mode
    set_mode_fields: tuple[tuple[int, int], ...]  # DO_SET_MODE param2, param3…: (shift, mask) of custom_mode
    start_sequence: tuple[str, ...]  # after set-current, when the companion arms
    pilot_arm_sequence: tuple[str, ...]  # after set-current, when the pilot arms

    # -- hold: the mode that stops the vehicle where it is without a pilot; a vehicle held there circles (it may
    #    take up to one circle to be back on its route when resumed) or stops dead
    hold_mode: str
    hold_circles: bool
    # the circle is one of ours, commanded with MAV_CMD_DO_REPOSITION (GUIDED, a centre and radius), as ArduPlane
    # takes it; else a circling hold is the hold mode's own circle around where the vehicle is
    hold_reposition: bool

    # -- waypoints: how far before a waypoint it may count it reached, beyond its acceptance radius (m)
    early_switch_m: float

    # -- a new mission in flight
    flies_copy_during_upload: bool  # keeps flying its active item, unaffected by an upload in progress
    first_item_current_on_upload: bool  # the pre-flight upload flags item 0 current
    awaits_mission_verdict: bool  # judges a verified mission after the upload (MISSION_CURRENT mission_state)

    # -- telemetry (companion.mavlink.telemetry)
    data_streams: bool  # REQUEST_DATA_STREAM for the legacy stream groups, before SET_MESSAGE_INTERVAL
    streams_off: tuple[str, ...]  # messages it streams to the companion unasked, which the companion turns off

    def __post_init__(self) -> None:
        mission_layout(self.layout)
        named = [s.removeprefix(MODE) for s in self.start_sequence + self.pilot_arm_sequence if s.startswith(MODE)]
        for mode in [*named, self.hold_mode, "AUTO"]:
            if mode not in self.modes:
                raise ValueError(f"{self.name}: mode {mode!r} is not in its mode table")
        for seq, arm in ((self.start_sequence, ARM), (self.pilot_arm_sequence, PILOT_ARM)):
            steps = [s for s in seq if not s.startswith(MODE)]
            if steps != [arm, START] or seq[-1] != START:
                raise ValueError(f"{self.name}: a start sequence must {arm} once and start last: {seq}")

    def mode_number(self, name: str) -> int:
        """custom_mode of the mode ``name``."""
        return self.modes[name]

    def mode_name(self, custom_mode: int) -> str:
        """The first name of ``custom_mode`` in the mode table, else ``MODE_<n>``."""
        for name, number in self.modes.items():
            if number == custom_mode:
                return name
        return f"MODE_{custom_mode}"

    def set_mode_params(self, custom_mode: int) -> tuple[int, ...]:
        """MAV_CMD_DO_SET_MODE's params for ``custom_mode``."""
        return (mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                *((custom_mode >> shift) & mask for shift, mask in self.set_mode_fields))

    def booting(self, system_status: int, custom_mode: int) -> bool:
        """A HEARTBEAT with these fields comes from an autopilot that has not finished booting."""
        return system_status in self.booting_states or custom_mode in self.booting_modes


# Mode numbers from the autopilots' sources: ArduPilot custom modes; PX4 custom_mode = main << 16 | sub << 24
# (px4_custom_mode.h), HOLD being AUTO.LOITER
ARDUPLANE_MODES = MappingProxyType({"MANUAL": 0, "AUTO": 10, "RTL": 11, "LOITER": 12, "TAKEOFF": 13, "GUIDED": 15})
ARDUCOPTER_MODES = MappingProxyType({"STABILIZE": 0, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6, "LAND": 9,
                                     "BRAKE": 17})
PX4_MODES = MappingProxyType({"AUTO": (4 << 16) | (4 << 24), "LOITER": (4 << 16) | (3 << 24),
                              "RTL": (4 << 16) | (5 << 24), "HOLD": (4 << 16) | (3 << 24)})

BOOTING_STATES = frozenset({mavlink.MAV_STATE_UNINIT, mavlink.MAV_STATE_BOOT, mavlink.MAV_STATE_CALIBRATING})
ARDUPLANE_INITIALISING = 16  # ArduPlane's custom mode until its setup has finished
PLANE_EARLY_SWITCH_M = 65.0  # ArduPlane counts a waypoint reached up to this far before it (docs/autopilots.md §8.4)
ARDUPILOT_SET_MODE = ((0, 0xFFFFFFFF),)  # ArduPilot takes the custom mode in param2
PX4_SET_MODE = ((16, 0xFF), (24, 0xFF))  # PX4 its main mode in param2 and sub mode in param3

# PX4 streams its onboard (companion) link at full tilt by default: ATTITUDE ~100 Hz, GLOBAL_POSITION_INT,
# HIGHRES_IMU, ATTITUDE_QUATERNION ~50 Hz, … (~500 messages/s measured on PX4 SITL; N times that at speed-up N),
# none of which the companion reads. It turns them off on its own link (interval -1) so that what it reads is
# not queued behind them (at 20x a mission download stalled for 20 s in that flood).
PX4_UNUSED_STREAMS: tuple[str, ...] = (
    "ATTITUDE", "ATTITUDE_QUATERNION", "HIGHRES_IMU", "ODOMETRY", "LOCAL_POSITION_NED", "ALTITUDE",
    "ATTITUDE_TARGET", "POSITION_TARGET_LOCAL_NED", "SERVO_OUTPUT_RAW", "VFR_HUD", "DISTANCE_SENSOR",
    "TIMESYNC", "ESTIMATOR_STATUS", "SCALED_PRESSURE", "VIBRATION", "BATTERY_STATUS",
)

ARDUPLANE = AutopilotProfile(
    name="ArduPlane",
    layout="ardupilot",
    booting_states=BOOTING_STATES,
    booting_modes=frozenset({ARDUPLANE_INITIALISING}),
    boot_needs_status=True,
    prearm_health_only=False,
    storage=Firmware.ARDUPLANE,
    home_at_zero=True,
    # ArduPilot counts a fence of fewer than 3 items as none (FENCE_TOTAL 0), and its fence loader erases the
    # stored fence a few milliseconds after acknowledging the upload when that count drops from non-zero to 0
    # (seen on 4.7 SITL: one circle over six)
    min_fence_items=3,
    error_may_be_transfer_fault=False,
    # MissionItemProtocol::handle_mission_write_partial_list: DENIED during an upload, ERROR unless
    # start <= end <= count; the range is requested with the legacy MISSION_REQUEST, written in place (seq ==
    # count appends one, nothing is truncated) and ACKed ACCEPTED (seen on 4.7 SITL, plane and copter)
    partial_write=True,
    modes=ARDUPLANE_MODES,
    set_mode_fields=ARDUPILOT_SET_MODE,
    start_sequence=("mode:AUTO", "arm", "start"),
    pilot_arm_sequence=("mode:AUTO", "pilot_arm", "start"),  # it may be armed in AUTO: waits there
    hold_mode="LOITER",  # circles the spot
    hold_circles=True,
    hold_reposition=True,
    early_switch_m=PLANE_EARLY_SWITCH_M,
    # it keeps flying its active command from a copy and reads the next slot from storage when it gets there
    flies_copy_during_upload=True,
    first_item_current_on_upload=False,
    awaits_mission_verdict=False,
    # older firmware knows only REQUEST_DATA_STREAM; it goes first because a stream request overrides the
    # group's per-message intervals (companion.mavlink.telemetry)
    data_streams=True,
    streams_off=(),
)

ARDUCOPTER = replace(  # also Rover and Sub, and any ArduPilot vehicle that is not a plane
    ARDUPLANE,
    name="ArduCopter",
    booting_modes=frozenset(),
    storage=Firmware.ARDUCOPTER,
    modes=ARDUCOPTER_MODES,
    start_sequence=("mode:GUIDED", "arm", "mode:AUTO", "start"),  # it refuses to arm in AUTO
    pilot_arm_sequence=("pilot_arm", "mode:AUTO", "start"),  # so it is armed outside AUTO, then switched
    hold_mode="BRAKE",  # LOITER would need the pilot's sticks for throttle
    hold_circles=False,  # stops dead
    hold_reposition=False,
    early_switch_m=0.0,
    # ArduCopter (and Rover) re-read the current and the next two NAV items from storage as soon as one of them
    # changes (AP_Mission's change detector), so an upload in progress is flown at once
    flies_copy_during_upload=False,
)

PX4_MULTICOPTER = AutopilotProfile(
    name="PX4 multicopter",
    layout="px4",
    booting_states=BOOTING_STATES,
    booting_modes=frozenset(),
    boot_needs_status=True,
    # PX4 sets the pre-arm bit in health only (never in present), ~2 s after its checks pass
    prearm_health_only=True,
    storage=Firmware.PX4,
    home_at_zero=False,
    min_fence_items=0,
    # PX4 answers MAV_MISSION_ERROR for its own transfer trouble too (busy, a sync timeout)
    error_may_be_transfer_fault=True,
    partial_write=False,  # mavlink_mission.cpp ignores MISSION_WRITE_PARTIAL_LIST (no ACK at all)
    modes=PX4_MODES,
    set_mode_fields=PX4_SET_MODE,
    start_sequence=("arm", "mode:AUTO", "start"),  # arm, then mission mode
    pilot_arm_sequence=("mode:AUTO", "pilot_arm", "start"),
    hold_mode="HOLD",  # AUTO.LOITER
    hold_circles=False,
    hold_reposition=False,
    early_switch_m=0.0,
    flies_copy_during_upload=False,  # its behaviour during an upload is not ours to assume
    # PX4 keeps its current item across uploads (and judges a new mission from it): a mission flown before, or a
    # set-current, would leave it mid-list. The first item flagged current resets it.
    first_item_current_on_upload=True,
    # PX4 acknowledges an upload before its navigator has checked that the mission can be flown (takeoff first,
    # supported commands, a landing for planes); the verdict comes 30–210 ms later as MISSION_CURRENT with the
    # new total and mission_state (companion.flight.supervisor waits for it: starting before it is DENIED)
    awaits_mission_verdict=True,
    data_streams=False,
    streams_off=PX4_UNUSED_STREAMS,
)

PX4_FIXED_WING = replace(PX4_MULTICOPTER, name="PX4 fixed-wing")  # nothing the companion does differs (yet)
# a PX4 VTOL: its own mission layout (VTOL take-off and landing), and in fixed-wing flight its hold (AUTO.LOITER)
# circles NAV_LOITER_RAD around where it was, as ArduPlane's LOITER does
PX4_VTOL = replace(PX4_MULTICOPTER, name="PX4 VTOL", layout=PX4_VTOL_LAYOUT.key, hold_circles=True)

# Other MAVLink autopilots (MAVSDK's MissionRawServer says MAV_AUTOPILOT_GENERIC) store items as sent and are
# commanded with ArduPilot's conventions for their vehicle type: ArduPlane's for a fixed-wing, ArduCopter's else.
def _not_ardupilot(profile: AutopilotProfile, name: str) -> AutopilotProfile:
    return replace(profile, name=name, booting_modes=frozenset(), boot_needs_status=False, storage=Firmware.GENERIC,
                   home_at_zero=False, min_fence_items=0, partial_write=False, data_streams=False)


GENERIC = _not_ardupilot(ARDUCOPTER, "generic")
GENERIC_FIXED_WING = _not_ardupilot(ARDUPLANE, "generic fixed-wing")

# ArduPlane as a QuadPlane (HEARTBEAT type VTOL_*): its items are stored as ArduPlane stores them, while mode
# numbers, start, hold and in-flight uploads follow ArduCopter, as the companion has always done for these types.
# ArduPlane's modes are not ArduCopter's (its 3 is TRAINING, 4 ACRO): not flown with the companion yet.
ARDUPILOT_VTOL = replace(ARDUCOPTER, name="ArduPilot VTOL", storage=Firmware.ARDUPLANE)

PROFILES: tuple[AutopilotProfile, ...] = (ARDUPLANE, ARDUCOPTER, ARDUPILOT_VTOL, PX4_MULTICOPTER, PX4_FIXED_WING,
                                          PX4_VTOL, GENERIC, GENERIC_FIXED_WING)

# the VTOL types, MAV_TYPE 19-25 (QuadPlanes on ArduPilot, which stores their items as a plane's; VTOLs on PX4:
# the SIH standard VTOL says 22, which older MAVLink dialects call VTOL_RESERVED2 and newer ones VTOL_FIXEDROTOR)
VTOL_TYPES = frozenset(range(mavlink.MAV_TYPE_VTOL_DUOROTOR, mavlink.MAV_TYPE_VTOL_DUOROTOR + 7))


def profile_for(autopilot: int | None, vehicle_type: int | None) -> AutopilotProfile:
    """The profile of an autopilot from its HEARTBEAT's ``autopilot`` (MAV_AUTOPILOT) and ``type`` (MAV_TYPE);
    a generic one when the autopilot is neither ArduPilot nor PX4, or not known yet (None)."""
    fixed_wing = vehicle_type == mavlink.MAV_TYPE_FIXED_WING
    if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return ARDUPLANE if fixed_wing else ARDUPILOT_VTOL if vehicle_type in VTOL_TYPES else ARDUCOPTER
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return PX4_FIXED_WING if fixed_wing else PX4_VTOL if vehicle_type in VTOL_TYPES else PX4_MULTICOPTER
    return GENERIC_FIXED_WING if fixed_wing else GENERIC


__all__ = [
    "ARDUCOPTER", "ARDUPILOT_VTOL", "ARDUPLANE", "AutopilotProfile", "Firmware", "GENERIC", "GENERIC_FIXED_WING",
    "LAYOUTS", "LayoutKey", "MissionLayout", "PROFILES", "PX4_FIXED_WING", "PX4_MULTICOPTER", "PX4_VTOL",
    "PX4_VTOL_LAYOUT", "VTOL_TYPES", "mission_layout", "profile_for",
]
