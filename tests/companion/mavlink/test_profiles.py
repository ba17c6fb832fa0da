"""Autopilot profiles: each is picked from HEARTBEAT fields and holds its family's facts
(companion/mavlink/profiles.py)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.link import Link
from companion.mavlink.profiles import (
    ARDUCOPTER,
    ARDUPILOT_VTOL,
    ARDUPLANE,
    GENERIC,
    GENERIC_FIXED_WING,
    LAYOUTS,
    PROFILES,
    PX4_FIXED_WING,
    PX4_MULTICOPTER,
    PX4_VTOL,
    Firmware,
    mission_layout,
    profile_for,
)
from companion.mission.builder import MissionSpec
from planner.world.config import VehicleLimits
from planner.world.home import Home
from planner.world.scenario import load_scenario

APM, PX4, GEN = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_AUTOPILOT_PX4, mavlink.MAV_AUTOPILOT_GENERIC
FW, QUAD, HEXA = mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_TYPE_HEXAROTOR
ROVER, VTOL = mavlink.MAV_TYPE_GROUND_ROVER, mavlink.MAV_TYPE_VTOL_QUADROTOR


@pytest.mark.parametrize(("autopilot", "vehicle_type", "profile"), [
    (APM, FW, ARDUPLANE),
    (APM, QUAD, ARDUCOPTER),
    (APM, HEXA, ARDUCOPTER),
    (APM, ROVER, ARDUCOPTER),  # AP_Mission's non-plane branch
    (APM, VTOL, ARDUPILOT_VTOL),
    (PX4, QUAD, PX4_MULTICOPTER),
    (PX4, FW, PX4_FIXED_WING),
    (PX4, VTOL, PX4_VTOL),
    (PX4, 22, PX4_VTOL),  # the SIH standard VTOL (VTOL_RESERVED2 in this dialect, VTOL_FIXEDROTOR in newer ones)
    (GEN, QUAD, GENERIC),  # MAVSDK's MissionRawServer says MAV_AUTOPILOT_GENERIC
    (GEN, mavlink.MAV_TYPE_GENERIC, GENERIC),
    (GEN, FW, GENERIC_FIXED_WING),
    (mavlink.MAV_AUTOPILOT_SLUGS, QUAD, GENERIC),
    (None, None, GENERIC),  # nothing heard yet
    (APM, None, ARDUCOPTER),
])
def test_profile_is_picked_from_heartbeat_fields(autopilot, vehicle_type, profile) -> None:
    assert profile_for(autopilot, vehicle_type) is profile
    assert Firmware.of(autopilot, vehicle_type) is profile.storage


@pytest.mark.parametrize(("vehicle", "profile"), [("plane", ARDUPLANE), ("copter", ARDUCOPTER)])
def test_the_built_in_simulator_gets_the_ardupilot_profiles(vehicle, profile) -> None:
    """companion.sim's HEARTBEAT says ArduPilot with a plane's or a quadrotor's type, booting as SITL does; its
    mode numbers are the profile's."""
    from companion.sim import COPTER_MODES, PLANE_MODES, SimAutopilot

    scenario = load_scenario(Path(__file__).resolve().parents[3] / "sitl_scenarios" / "rescue_static.toml")
    booting = SimAutopilot(scenario, "udpin:127.0.0.1:0", vehicle=vehicle, boot_s=None)._heartbeat()
    booted = SimAutopilot(scenario, "udpin:127.0.0.1:0", vehicle=vehicle)._heartbeat()
    assert profile_for(booting.autopilot, booting.type) is profile_for(booted.autopilot, booted.type) is profile
    assert profile.booting(booting.system_status, booting.custom_mode)
    assert not profile.booting(booted.system_status, booted.custom_mode)
    sim_modes = PLANE_MODES if vehicle == "plane" else COPTER_MODES
    assert {name: sim_modes[name] for name in profile.modes} == dict(profile.modes)


def test_link_profile_follows_its_target_and_is_generic_until_heard() -> None:
    link = Link("udpin:127.0.0.1:0")
    assert link.profile is GENERIC
    link.autopilot, link.vehicle_type = PX4, QUAD
    assert link.profile is PX4_MULTICOPTER
    link.autopilot, link.vehicle_type = APM, FW
    assert link.profile is ARDUPLANE


def test_boot() -> None:
    booting = mavlink.MAV_STATE_BOOT
    standby = mavlink.MAV_STATE_STANDBY
    assert ARDUPLANE.booting(standby, 16)  # INITIALISING
    assert not ARDUPLANE.booting(standby, ARDUPLANE.mode_number("MANUAL"))
    assert not ARDUCOPTER.booting(standby, 16)  # 16 is ArduCopter's POSHOLD, not a boot mode
    assert not GENERIC_FIXED_WING.booting(standby, 16)
    for p in PROFILES:
        assert p.booting(booting, 0) and p.booting(mavlink.MAV_STATE_CALIBRATING, 0)
        assert not p.booting(mavlink.MAV_STATE_ACTIVE, 0)
    assert ARDUPLANE.boot_needs_status and ARDUCOPTER.boot_needs_status and PX4_MULTICOPTER.boot_needs_status
    assert not GENERIC.boot_needs_status and not GENERIC_FIXED_WING.boot_needs_status


def test_readiness_and_storage() -> None:
    assert [p.prearm_health_only for p in PROFILES] == [p in (PX4_MULTICOPTER, PX4_FIXED_WING, PX4_VTOL)
                                                        for p in PROFILES]
    assert (ARDUPLANE.storage, ARDUCOPTER.storage, ARDUPILOT_VTOL.storage) == (
        Firmware.ARDUPLANE, Firmware.ARDUCOPTER, Firmware.ARDUPLANE)
    assert PX4_MULTICOPTER.storage is PX4_FIXED_WING.storage is PX4_VTOL.storage is Firmware.PX4
    assert GENERIC.storage is GENERIC_FIXED_WING.storage is Firmware.GENERIC
    ardupilot = (ARDUPLANE, ARDUCOPTER, ARDUPILOT_VTOL)
    for p in PROFILES:
        assert p.home_at_zero == (p in ardupilot)
        assert p.min_fence_items == (3 if p in ardupilot else 0)
        assert p.error_may_be_transfer_fault == (p.storage is Firmware.PX4)


def test_modes_and_their_params() -> None:
    assert ARDUPLANE.mode_number("AUTO") == 10 and ARDUPLANE.mode_number("LOITER") == 12
    assert ARDUCOPTER.mode_number("AUTO") == 3 and ARDUCOPTER.mode_number("BRAKE") == 17
    auto = PX4_MULTICOPTER.mode_number("AUTO")
    assert auto == (4 << 16) | (4 << 24)  # main AUTO, sub MISSION
    assert PX4_MULTICOPTER.mode_number("HOLD") == (4 << 16) | (3 << 24)  # AUTO.LOITER
    assert PX4_MULTICOPTER.mode_name(PX4_MULTICOPTER.mode_number("HOLD")) == "LOITER"  # its first name
    assert ARDUPLANE.mode_name(99) == "MODE_99"
    flag = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert ARDUPLANE.set_mode_params(10) == (flag, 10)
    assert PX4_FIXED_WING.set_mode_params(auto) == (flag, 4, 4)  # main mode in param2, sub mode in param3
    with pytest.raises(KeyError):
        ARDUPLANE.mode_number("BRAKE")


def test_start_sequences() -> None:
    assert ARDUPLANE.start_sequence == ("mode:AUTO", "arm", "start")
    assert ARDUCOPTER.start_sequence == ("mode:GUIDED", "arm", "mode:AUTO", "start")  # it refuses to arm in AUTO
    assert PX4_MULTICOPTER.start_sequence == PX4_FIXED_WING.start_sequence == ("arm", "mode:AUTO", "start")
    # without --arm: planes and PX4 wait for the pilot in AUTO; a copter is armed outside AUTO, then switched
    assert ARDUPLANE.pilot_arm_sequence == PX4_MULTICOPTER.pilot_arm_sequence == ("mode:AUTO", "pilot_arm", "start")
    assert ARDUCOPTER.pilot_arm_sequence == ("pilot_arm", "mode:AUTO", "start")
    assert GENERIC_FIXED_WING.start_sequence == ARDUPLANE.start_sequence
    assert GENERIC.start_sequence == ARDUCOPTER.start_sequence


def test_a_profile_checks_its_own_sequences_and_modes() -> None:
    with pytest.raises(ValueError, match="not in its mode table"):
        replace(ARDUPLANE, hold_mode="BRAKE")
    with pytest.raises(ValueError, match="arm once and start last"):
        replace(ARDUPLANE, start_sequence=("mode:AUTO", "start", "arm"))
    with pytest.raises(ValueError, match="pilot_arm once"):
        replace(ARDUCOPTER, pilot_arm_sequence=("mode:AUTO", "arm", "start"))


def test_hold_waypoints_and_missions_in_flight() -> None:
    assert (ARDUPLANE.hold_mode, ARDUCOPTER.hold_mode, PX4_MULTICOPTER.hold_mode) == ("LOITER", "BRAKE", "HOLD")
    for p in PROFILES:
        plane_like = p in (ARDUPLANE, GENERIC_FIXED_WING)
        assert p.hold_circles == (plane_like or p is PX4_VTOL)  # a VTOL in fixed-wing flight circles its hold
        assert p.flies_copy_during_upload == plane_like  # only ArduPlane keeps flying its copy
        assert p.early_switch_m == (65.0 if plane_like else 0.0)
        px4 = p in (PX4_MULTICOPTER, PX4_FIXED_WING, PX4_VTOL)
        assert p.first_item_current_on_upload == px4 and p.awaits_mission_verdict == px4
        assert p.data_streams == (p in (ARDUPLANE, ARDUCOPTER, ARDUPILOT_VTOL))
        assert bool(p.streams_off) == px4
    assert "ATTITUDE" in PX4_MULTICOPTER.streams_off and "GLOBAL_POSITION_INT" not in PX4_MULTICOPTER.streams_off


def test_each_profile_names_a_builder_layout() -> None:
    assert {p.layout for p in PROFILES} == set(LAYOUTS)
    assert [p for p in PROFILES if p.layout == "px4"] == [PX4_MULTICOPTER, PX4_FIXED_WING]
    assert [p for p in PROFILES if p.layout == "px4-vtol"] == [PX4_VTOL]
    apm, px4, vtol = mission_layout("ardupilot"), mission_layout("px4"), mission_layout("px4-vtol")
    assert vtol.vtol and not px4.vtol and not apm.vtol and not vtol.home_item
    assert apm.home_item and not px4.home_item
    assert apm.nav_yaw == 0.0 and math.isnan(px4.nav_yaw)
    assert (apm.qgc_firmware_type, px4.qgc_firmware_type) == (APM, PX4)
    assert apm.acceptance_param(20.4, "plane") == 20.0 and apm.acceptance_param(400.0, "plane") == 255.0
    assert apm.acceptance_param(20.4, "copter") == 0.0  # ArduCopter does not store it
    assert px4.acceptance_param(20.4, "copter") == 20.4
    with pytest.raises(ValueError, match="autopilot must be 'ardupilot' or 'px4' or 'px4-vtol', got 'inav'"):
        mission_layout("inav")
    spec = MissionSpec("px4", VehicleLimits(), Home(47.0, 8.0, 500.0))
    assert spec.layout is px4 and math.isnan(spec.yaw_param)
