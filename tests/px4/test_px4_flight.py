"""`fuseplan fly` on a real PX4 (SIH quadrotor SITL, and its standard VTOL) started a moment before, default
options; and what PX4 does with the mission's end action once the companion has seen the goal reached."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from px4_harness import FAST
from pymavlink import mavutil

from companion.cli import main
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
MOUNTAIN = ROOT / "sitl_scenarios" / "mountain_rescue.toml"
SC = load_scenario(MOUNTAIN)
SPEEDUP = FAST  # SIH in lockstep, as fast as 2 cores keep up with
VTOL_MODEL = "sihsim_standard_vtol"  # airframe 10043
VTOL_TAKEOFF, VTOL_LAND = 84, 85  # MAV_CMD_NAV_VTOL_TAKEOFF, MAV_CMD_NAV_VTOL_LAND
AUTO_MISSION = 0x04040000  # PX4 custom_mode (sub << 24 | main << 16), as HEARTBEAT shows it
ARMED = 0x80  # MAV_MODE_FLAG_SAFETY_ARMED


def _after_the_flight(url: str, until: Callable[[object], bool], timeout: float = 60.0) -> object:
    """Listen where the companion sat (it has exited) for PX4's first HEARTBEAT that satisfies ``until``."""
    conn = mavutil.mavlink_connection(url, source_system=1, source_component=191)
    try:
        deadline = time.monotonic() + timeout
        seen = []
        while time.monotonic() < deadline:
            conn.mav.heartbeat_send(18, 8, 0, 0, 4)  # so that PX4 keeps talking to this port
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if hb is not None and hb.autopilot == 12:
                if until(hb):
                    return hb
                seen.append((hex(hb.custom_mode), hb.base_mode & ARMED))
        raise AssertionError(f"no such HEARTBEAT from PX4 within {timeout:.0f} s: {sorted(set(seen))}")
    finally:
        conn.close()


@pytest.fixture(scope="module")
def mountain_plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from companion.cli import _plan_doc_for

    doc, _ = _plan_doc_for(MOUNTAIN, None, [], None, feasible_only=True, for_flight=True)
    path = tmp_path_factory.mktemp("mountain") / "PLAN.json"
    path.write_text(json.dumps(doc))
    return path


# a whole flight of the PX4 quad by `fly --arm`, boot to goal (the operator-world flight, which was named here, is
# itself left to --with-covered now: fuseplan serve's PX4 test flies its course)
OPERATOR_FLIGHT = "test_px4_replans_around_an_intruder[pymavlink]"


@pytest.mark.slow(covered_by=(
    # a whole flight of the PX4 quad, boot to goal (arm, AUTO.MISSION, set-current, the navigator's acceptance)
    OPERATOR_FLIGHT,
    # the companion's fence and mission verified as PX4 stores them, flown to a landing
    "test_rescue_static_flies_on_the_px4_standard_vtol",
    # the quad landing and disarming itself after the mission
    "px4/test_px4_companion.py::test_the_rtl_end_action_returns_lands_and_disarms[pymavlink]",
    # mountain_rescue (terrain) flown to its end by an autopilot
    "sitl/test_flights.py::test_copter_scenario_flies_on_arducopter"))
def test_mountain_rescue_flies_on_px4_with_the_default_options(px4_factory_fn, mountain_plan: Path,
                                                                tmp_path: Path) -> None:
    """`fuseplan fly PLAN --connect udpin:127.0.0.1:14540 --arm` against a PX4 started a moment before: boot
    and readiness, mission and fence verified, PX4's navigator accepts, set-current by message, arm, AUTO.MISSION,
    the route flown to the landing at the casualty site."""
    px4 = px4_factory_fn(SC.home, speedup=SPEEDUP)
    report = tmp_path / "report"
    code = main(["fly", str(mountain_plan), "--connect", px4.companion_url, "--arm", "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert code == 0 and flight["completed"] is True, flight.get("reason")
    names = [e["event"] for e in events]
    start = next(e for e in events if e["event"] == "upload_start")
    assert start["fence_items"] > 0
    assert names.index("mission_valid") < names.index("upload_verified") < names.index("armed") \
        < names.index("mission_start")
    reached = sorted({e["seq"] for e in events if e["event"] == "reached"})
    assert len(flight["items_reached"]) >= 5 and reached[-1] >= flight["mission_items"] - 3  # the goal, before LAND
    assert flight["autopilot"] in ("px4", 12) and flight["min_clearance_m"] > 0.0
    # end action "land": PX4 lands at the casualty site and disarms itself, staying in AUTO.MISSION
    hb = _after_the_flight(px4.companion_url, lambda m: not m.base_mode & ARMED)
    assert hb.custom_mode == AUTO_MISSION


@pytest.mark.slow(covered_by=(  # a whole flight of the PX4 quad, and the end action "loiter" on PX4
    OPERATOR_FLIGHT,
    "px4/test_px4_companion.py::test_the_loiter_end_action_holds_over_the_goal_armed[pymavlink]"))
def test_rescue_static_flies_on_px4_as_a_copter(px4_factory_fn, tmp_path: Path) -> None:
    """`fuseplan fly rescue_static.toml --set vehicle.type=copter --arm` on the PX4 quad, default options:
    planned, uploaded with its fence, flown to the goal clear of every cylinder; then PX4 carries out the end
    action "loiter" (LOITER_UNLIM): armed over the goal in AUTO.MISSION. (Through MAVSDK: the replan flight
    below. With end action "rtl" PX4 held at the goal in AUTO.LOITER instead of returning, because our fence lies
    across its straight line home; without the fence it returned, landed and disarmed: measured by hand, twice
    each, not repeated here for the suite's time; the RTL itself is flown in test_px4_companion.)"""
    scenario = ROOT / "sitl_scenarios" / "rescue_static.toml"
    px4 = px4_factory_fn(load_scenario(scenario).home, speedup=SPEEDUP)
    report = tmp_path / "report"
    code = main(["fly", str(scenario), "--connect", px4.companion_url, "--arm", "--set", 'vehicle.type="copter"',
                 "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    assert code == 0 and flight["completed"] is True, flight.get("reason")
    assert flight["backend"] == "pymavlink" and flight["fence_items"] > 0
    assert flight["track_points"] > 10 and flight["min_clearance_m"] > 0.0
    time.sleep(2.0)  # 20 s of PX4's time after the goal
    hb = _after_the_flight(px4.companion_url, lambda m: True)
    assert hb.custom_mode == AUTO_MISSION and hb.base_mode & ARMED, hex(hb.custom_mode)


def test_rescue_static_flies_on_the_px4_standard_vtol(px4_factory_fn, tmp_path: Path) -> None:
    """PX4's SIH standard VTOL (airframe 10043, MAV_TYPE 22), `fuseplan fly rescue_static.toml --arm` with its
    trim airspeed and a landing (PX4 rejects a VTOL mission without one): the PX4 VTOL layout (VTOL_TAKEOFF first,
    VTOL_LAND last), the limits read from its fixed-wing parameters, the departure checked as a vertical climb and
    a transition on any heading, the route flown as a fixed-wing clear of every obstacle by d_coll, then PX4's
    back-transition and landing at the goal."""
    scenario = ROOT / "sitl_scenarios" / "rescue_static.toml"
    sc = load_scenario(scenario)
    px4 = px4_factory_fn(sc.home, speedup=SPEEDUP, model=VTOL_MODEL)
    report = tmp_path / "report"
    code = main(["fly", str(scenario), "--connect", px4.companion_url, "--arm", "--set", "vehicle.cruise_speed=10",
                 "--set", 'vehicle.end_action="land"', "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    assert code == 0 and flight["completed"] is True, flight.get("reason")
    assert flight["autopilot"] == "px4-vtol"
    assert flight["vehicle_limits"]["vertical_takeoff"] and "FW_AIRSPD_TRIM" in flight["vehicle_limits"]["read"]
    items = json.loads((report / "mission.plan").read_text())["mission"]["items"]
    assert (items[0]["command"], items[-1]["command"]) == (VTOL_TAKEOFF, VTOL_LAND)
    assert flight["min_static_clearance_m"] >= sc.hazard.d_coll, flight["min_static_clearance_m"]
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    departure = next(e for e in events if e["event"] == "departure")
    assert departure["refusal"] is None and departure["paths"] > 1  # the transition on every heading
    # flown as a fixed-wing: the airframe's multicopter flew this route at about 6 m/s (docs/px4.md), its
    # fixed-wing at its 10 m/s trim airspeed
    cruise = [e["gs"] for e in events if e["event"] == "position" and e["z"] > sc.vehicle.takeoff_alt]
    assert len(cruise) > 20 and float(np.median(cruise)) >= 8.5, float(np.median(cruise))
    # PX4 back-transitions and lands at the goal, then disarms itself, staying in AUTO.MISSION
    hb = _after_the_flight(px4.companion_url, lambda m: not m.base_mode & ARMED)
    assert hb.custom_mode == AUTO_MISSION


@pytest.mark.parametrize("backend", ["pymavlink", pytest.param("mavsdk", marks=pytest.mark.slow(covered_by=(
    # PX4's side of it through our link, and an in-flight replan through MAVSDK on the built-in simulator
    "test_px4_replans_around_an_intruder[pymavlink]",
    "companion/mavlink/test_mavsdk_backend.py::test_fly_and_replan_through_mavsdk_on_the_simulator")))])
def test_px4_replans_around_an_intruder(px4_factory_fn, tmp_path: Path, backend: str) -> None:
    """rescue_dynamic flown by the PX4 quad (10x), its intruder reported as ADSB_VEHICLE by an ADS-B source on
    PX4's ground-station link (system 1, component 156), which PX4 passes on to the companion's link as its own.
    Without replanning this flight comes to −19.8 m of the intruder (measured by hand, same set-up with
    --no-replan). PX4 keeps the current index when a mission is uploaded in flight and turns at once to the new
    item there, so the swap holds first (AUTO.LOITER), uploads, sets the item and resumes. Through MAVSDK as
    through our own link (measured by hand: 2 replans, 180.5 m at the closest through MAVSDK)."""
    scenario = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
    px4 = px4_factory_fn(load_scenario(scenario).home, speedup=SPEEDUP)
    report = tmp_path / "report"
    code = main(["fly", str(scenario), "--connect", px4.companion_url, "--arm", "--set", 'vehicle.type="copter"',
                 "--traffic", f"udpout:127.0.0.1:{px4.gcs_port}", "--backend", backend, "--report", str(report),
                 "-q"])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert code == 0 and flight["completed"] is True, flight.get("reason")
    assert flight["separation_source"].endswith("(traffic feed)")
    assert flight["replan_attempts"] >= 1 and any(e["event"] == "track" for e in events)
    assert min(flight["min_separation_m"].values()) >= flight["d_coll_m"], flight["min_separation_m"]
    names = [e["event"] for e in events]
    if "replanned" in names:  # a new mission went live: the vehicle was held while it was swapped
        assert names.index("hold") < names.index("replanned")
