"""The departure from where the vehicle stands to the route's start, checked before anything is uploaded; and the
vehicle's limits from its parameters."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.flight.departure import VehicleFix, check_departure, departure_paths, turn_then_straight
from companion.mavlink.vehicle_limits import limits_from
from planner.world.config import VehicleLimits
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
SITL_PLANE = {"ROLL_LIMIT_DEG": 65.0, "AIRSPEED_CRUISE": 22.0, "WP_RADIUS": 50.0, "WP_LOITER_RAD": 80.0,
              "NAVL1_PERIOD": 15.0}  # shared/sitl/plane.parm


@pytest.fixture(scope="module")
def dynamic():
    return load_scenario(ROOT / "sitl_scenarios" / "rescue_dynamic.toml")


def _check(sc, xy, heading=0.0, home_up=0.0, params=SITL_PLANE, on_ground=True):
    lim = limits_from(params, "ardupilot", sc.vehicle, 60.0)
    fix = VehicleFix(np.array([*xy, home_up]), heading, np.array([*xy, home_up]))
    return check_departure(fix, np.asarray(sc.start), sc.vehicle.takeoff_alt, lim, sc.environment,
                           sc.hazard.d_coll, on_ground)


def test_limits_come_from_the_parameters_read_and_the_scenario_fills_the_rest(dynamic) -> None:
    lim = limits_from(SITL_PLANE, "ardupilot", dynamic.vehicle, 60.0)
    assert (lim.max_bank_deg, lim.cruise_speed, lim.loiter_radius) == (65.0, 22.0, 80.0)
    assert lim.read == SITL_PLANE
    assert abs(lim.turn_radius - 22.0**2 / (9.80665 * np.tan(np.radians(65.0)))) < 1e-9
    assert abs(lim.wide_turn_radius(27.0) - 0.75 * 15.0 * 27.0 / np.pi / 2.25) < 1e-9  # L1 / (4 damping²)
    # ArduPlane's swing past a new leg scales with its L1 distance at the mission's speed (SITL: NAVL1_PERIOD 15)
    assert lim.turn_overshoot(18.0) == pytest.approx(0.35 * 0.75 * 15.0 * 18.0 / np.pi)
    none = limits_from({}, "ardupilot", dynamic.vehicle, 60.0)
    assert none.turn_overshoot(18.0) == pytest.approx(0.35 * 0.75 * 17.0 * 18.0 / np.pi)  # ArduPlane's default
    # PX4's NPFG swing scales with its period and the speed (measured on SIH, tests/px4/test_px4_turns.py)
    px4 = limits_from({"NAV_ACC_RAD": 10.0}, "px4-vtol", dynamic.vehicle, 80.0)
    assert px4.turn_overshoot(10.0) == pytest.approx(0.1 * 10.0 * 10.0)  # NPFG_PERIOD's default, 10 s
    slow = limits_from({"NPFG_PERIOD": 20.0}, "px4-vtol", dynamic.vehicle, 80.0)
    assert slow.turn_overshoot(10.0) == pytest.approx(2.0 * px4.turn_overshoot(10.0))
    assert slow.read == {"NPFG_PERIOD": 20.0}
    px4_copter = limits_from({"NPFG_PERIOD": 20.0}, "px4", VehicleLimits(type="copter"), 60.0)
    assert px4_copter.turn_overshoot() == 0.0 and px4_copter.read == {}  # a multicopter has no NPFG to read
    assert (none.max_bank_deg, none.cruise_speed, none.loiter_radius, none.read) == (45.0, 18.0, 60.0, {})
    copter = limits_from({"WPNAV_SPEED": 1000.0, "WPNAV_ACCEL": 250.0}, "ardupilot", VehicleLimits(type="copter"), 60.0)
    assert copter.cruise_speed == 10.0 and copter.stopping_distance == pytest.approx(20.0)


def test_from_the_scenario_home_the_plane_climbs_out_clear(dynamic) -> None:
    d = _check(dynamic, (0.0, 0.0))
    assert d.refusal is None and d.clearance_m >= dynamic.hazard.d_coll + 5.0
    # the envelope reaches as far north as SITL's plane flew before turning (y ≈ 270 m, docs/autopilots.md)
    assert min(p[:, 1].max() for p in d.paths) < 270.0 < max(p[:, 1].max() for p in d.paths)
    assert all(np.allclose(p[-1], dynamic.start) for p in d.paths)


def test_300_m_east_the_climb_out_crosses_cylinder_3_and_is_refused_in_one_line(dynamic) -> None:
    """SITL started 300 m east of the scenario's home took off north through cylinders[3] (−18.7 m)."""
    d = _check(dynamic, (300.0, 0.0))
    assert d.refusal is not None and "\n" not in d.refusal
    assert d.nearest_obstacle == "cylinders[3]" and d.clearance_m < 0
    assert "nothing uploaded" in d.refusal and "cylinders[3]" in d.refusal
    # turned west instead, the same vehicle climbs out clear
    assert _check(dynamic, (300.0, 0.0), heading=270.0).refusal is None


def test_outside_the_region_or_a_home_at_another_altitude_is_refused(dynamic) -> None:
    assert "outside the scenario's region" in _check(dynamic, (-80.0, 10.0)).refusal
    assert "home altitude" in _check(dynamic, (0.0, 0.0), home_up=25.0).refusal


def test_an_airborne_vehicle_flies_straight_to_the_start(dynamic) -> None:
    assert _check(dynamic, (100.0, 100.0), on_ground=False).refusal is None
    blocked = _check(dynamic, (420.0, 200.0), on_ground=False)  # east of cylinders[3]: the leg crosses it
    assert blocked.refusal is not None and blocked.nearest_obstacle == "cylinders[3]"


def test_a_turn_ends_pointing_at_its_target_and_never_tighter_than_its_radius() -> None:
    path = turn_then_straight(np.zeros(2), np.array([0.0, 1.0]), np.array([300.0, -100.0]), 100.0)
    assert np.allclose(path[-1], (300.0, -100.0))
    centre = np.array([100.0, 0.0])  # a right turn from north: the centre is east
    arc = path[:-1]
    assert np.allclose(np.linalg.norm(arc - centre, axis=1), 100.0)
    last = arc[-1] - centre
    assert abs(np.dot(last, (300.0, -100.0) - arc[-1])) < 1e-6 * 1e4  # the exit leg is tangent to the circle


def test_a_copter_climbs_vertically_then_flies_straight(dynamic) -> None:
    copter = VehicleLimits(type="copter", cruise_speed=10.0)
    lim = limits_from({}, "ardupilot", copter, 60.0)
    (path,) = departure_paths(VehicleFix(np.array([300.0, 0.0, 0.0]), 0.0, None), np.asarray(dynamic.start),
                              50.0, lim)
    assert np.allclose(path[0], (300.0, 0.0, 0.0)) and np.allclose(path[-1], dynamic.start)
    assert np.isclose(path[:, :2], (300.0, 0.0)).all(axis=1).sum() >= 2  # straight up first


PX4_VTOL = {"FW_AIRSPD_TRIM": 10.0, "FW_R_LIM": 50.0, "NAV_ACC_RAD": 10.0, "NAV_LOITER_RAD": 80.0}  # SIH 10043


def test_a_vtol_climbs_vertically_and_transitions_on_any_heading(dynamic) -> None:
    """PX4's VTOL (layout px4-vtol): the limits come from its fixed-wing parameters, and the departure is a vertical
    climb where it stands, then a transition straight on whatever heading it has at the top (PX4's SIH VTOL yawed
    75° in its climb), then the turn to the start: every heading is checked, whatever the autopilot says."""
    lim = limits_from(PX4_VTOL, "px4-vtol", dynamic.vehicle, 60.0)
    assert lim.vertical_takeoff and lim.cruise_speed == 10.0 and lim.read == PX4_VTOL
    assert not limits_from(PX4_VTOL, "px4", dynamic.vehicle, 60.0).vertical_takeoff
    fix = VehicleFix(np.zeros(3), 0.0, np.zeros(3))
    paths = departure_paths(fix, np.asarray(dynamic.start), dynamic.vehicle.takeoff_alt, lim)
    alt = dynamic.vehicle.takeoff_alt
    assert len(paths) == 12 and all(np.allclose(p[-1], dynamic.start) for p in paths)
    for p in paths:  # straight up first: no horizontal move until the take-off altitude
        climb = p[: int(np.argmax(p[:, 2] >= alt - 1e-9)) + 1]
        assert np.allclose(climb[:, :2], 0.0) and climb[-1, 2] == pytest.approx(alt)
    # then the transition, straight out 40 m: all round the vehicle
    tops = np.array([p[np.flatnonzero(np.linalg.norm(p[:, :2], axis=1) >= 40.0 - 1e-6)[0], :2] for p in paths])
    assert np.allclose(np.linalg.norm(tops, axis=1), 40.0) and tops[:, 0].min() < -30.0 < 30.0 < tops[:, 0].max()
    # 30 m from cylinders[3]'s edge (x 350, y 200, r 70): a plane heading west climbs out clear; a VTOL, which may
    # transition towards the cylinder whatever its heading on the ground, is refused
    near = np.array([250.0, 200.0])
    vtol = check_departure(VehicleFix(np.array([*near, 0.0]), 270.0, np.array([*near, 0.0])), np.asarray(dynamic.start),
                           dynamic.vehicle.takeoff_alt, lim, dynamic.environment, dynamic.hazard.d_coll)
    assert vtol.refusal is not None and vtol.nearest_obstacle == "cylinders[3]"


def test_the_turn_from_the_climb_out_onto_a_first_leg_that_doubles_back_is_checked(dynamic) -> None:
    """A plane reaches the route's start on the heading its climb-out gives it and then turns onto the first leg;
    a first leg that doubles back swings it wide, past the start. On rescue_static with d_coll 60 m (simulator run:
    a roadmap route whose first leg turned back north-west was flown 14 m from cylinders[3]) the departure itself
    keeps its margin, its join does not: a one-line warning naming the heading and the obstacle (advisory: the model
    is not calibrated against SITL yet), never a refusal. At the scenario's own d_coll, or for a copter, none."""
    static = load_scenario(ROOT / "sitl_scenarios" / "rescue_static.toml", ["hazard.d_coll=60", "hazard.d_safe=80"])
    lim = limits_from(SITL_PLANE, "ardupilot", static.vehicle, 60.0)
    fix = VehicleFix(np.zeros(3), 0.0, np.zeros(3))
    start = np.asarray(static.start)  # (200, 200, 50), 80 m west of cylinders[3]'s surface
    back = start + np.array([-25.0, 41.0, 6.0])  # the first leg heads north-west, back across the arrival
    bare = check_departure(fix, start, static.vehicle.takeoff_alt, lim, static.environment, 60.0)
    assert bare.refusal is None and bare.join_warning is None
    joined = check_departure(fix, start, static.vehicle.takeoff_alt, lim, static.environment, 60.0, onto=back)
    assert joined.refusal is None and joined.join_warning is not None
    assert "turn onto the first leg" in joined.join_warning and "cylinders[3]" in joined.join_warning
    assert "\n" not in joined.join_warning and joined.summary()["join_warning"] == joined.join_warning
    # at the scenario's own d_coll (10 m) the same join keeps its margin; a copter turns on the spot
    assert check_departure(fix, start, static.vehicle.takeoff_alt, lim, static.environment, 10.0,
                           onto=back).join_warning is None
    copter = limits_from({}, "ardupilot", VehicleLimits(type="copter"), 60.0)
    assert check_departure(fix, start, static.vehicle.takeoff_alt, copter, static.environment, 60.0,
                           onto=back).join_warning is None
