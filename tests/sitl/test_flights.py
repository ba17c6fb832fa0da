"""Whole flights on real ArduPilot SITL, as a user runs them: ``fuseplan fly SCENARIO --connect URL --arm``
against an autopilot started a moment before, default options (fence included), in both wirings (the companion as
the only client on SERIAL0, and on SERIAL1 while a ground station holds SERIAL0), and live replanning around
scripted intruders that an ADS-B receiver (component 156, ``--traffic``) reports on the autopilot's SERIAL2."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path

import pytest
from readback import first_difference, vehicle_mission, waypoints_file

from companion.cli import main
from planner.world.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[2] / "sitl_scenarios"
FAST = 20.0  # SITL speed-up of the flights without replanning (the replanning ones fly at 10: wall-clock budgets)


def _fly(scenario: Path, url: str, report: Path, *extra: str) -> tuple[int, dict, list[dict]]:
    code = main(["fly", str(scenario), "--connect", url, "--arm", "--report", str(report), "-q", *extra])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    return code, flight, events


def _assert_started_once_verified(events: list[dict]) -> None:
    """Upload verified, then armed, then MISSION_START, with no upload failing on the way."""
    kinds = [e["event"] for e in events]
    assert kinds.index("upload_verified") < kinds.index("armed") < kinds.index("mission_start")
    assert "upload_failed" not in kinds


def _steps_into_unverified_items(events: list[dict]) -> list[dict]:
    """Every change of the active item, during a replan's upload, to an item being rewritten (seq ≥ the first new
    one) while the vehicle was not held: the vehicle then flew an item of an unverified, maybe mixed, mission."""
    bad, held, upload_from = [], False, None
    pending = []  # "current" events seen since the last replan_planned
    for e in events:
        kind = e["event"]
        if kind == "hold":
            held = True
        elif kind == "resume":
            held = False
        elif kind == "replan_planned":
            upload_from, pending = e["t"], []
        elif kind == "current" and upload_from is not None and not held:
            pending.append(e)
        elif kind == "replan_verified" and upload_from is not None:
            bad += [c for c in pending if c["seq"] >= e["first_new"]]
            upload_from, pending = None, []
    return bad


@pytest.mark.parametrize("name", ["rescue_static", pytest.param(
    # a booting ArduPlane's SERIAL0, the fence verified as stored and every waypoint reached: by rescue_static; a
    # larger fence (polygons and a circle) flown round to its end on ArduPlane by fuseplan serve's ArduPlane test (the
    # operator-world course)
    "large_obstacle_field", marks=pytest.mark.slow(covered_by=(
        "test_plane_scenarios_fly_on_arduplane_with_default_options[rescue_static]",
        "sitl/test_serve_arduplane.py::"
        "test_serve_on_arduplane_replaces_flies_and_survives_a_reboot"))), pytest.param(
    # a booting ArduPlane's SERIAL0 by the two above; rescue_dynamic flown on ArduPlane to its end with defaults, its
    # intruder reported, by test_vehicle_facts.py (ROLL_LIMIT_DEG / WP_LOITER_RAD) and crossing_traffic below
    "rescue_dynamic", marks=pytest.mark.slow(covered_by=(
        "test_plane_scenarios_fly_on_arduplane_with_default_options[rescue_static]",
        "sitl/test_vehicle_facts.py::test_the_plan_and_the_hold_follow_roll_limit_and_wp_loiter_rad",
        "test_crossing_traffic_on_serial1_with_adsb_from_a_receiver[replan]"))), pytest.param(
    # flown on ArduPlane below, to its end, by the first client on SERIAL1 of a booting ArduPlane
    "crossing_traffic", marks=pytest.mark.slow(covered_by="test_crossing_traffic_on_serial1_with_adsb_from_a_receiver"
                                                          "[replan]"))])
def test_plane_scenarios_fly_on_arduplane_with_default_options(sitl_factory_fn, tmp_path: Path, name: str) -> None:
    """The first client on SERIAL0 of an ArduPlane that is still booting: boot wait, fence and mission verified as
    ArduPilot stores them, AUTO → arm → start, every waypoint reached."""
    scenario = SCENARIOS / f"{name}.toml"
    sc = load_scenario(scenario)
    assert sc.vehicle.type == "plane"
    sitl = sitl_factory_fn("plane", sc.home, speedup=FAST)
    code, flight, events = _fly(scenario, sitl.serial0_url, tmp_path / "rep")
    assert code == 0, flight
    assert flight["completed"] is True and flight["fence_items"] > 0
    assert flight["items_reached"][-1] == max(flight["items_reached"])
    _assert_started_once_verified(events)


def test_copter_scenario_flies_on_arducopter(sitl_factory_fn, tmp_path: Path) -> None:
    """mountain_rescue (terrain) on ArduCopter: it streams nothing until asked, boots in BOOT, is armed in
    GUIDED and started in AUTO."""
    scenario = SCENARIOS / "mountain_rescue.toml"
    sc = load_scenario(scenario)
    assert sc.vehicle.type == "copter"
    sitl = sitl_factory_fn("copter", sc.home, speedup=FAST)
    code, flight, events = _fly(scenario, sitl.serial0_url, tmp_path / "rep")
    assert code == 0, flight
    assert flight["completed"] is True
    modes = [e["mode"] for e in events if e["event"] == "mode"]
    assert modes[:2] == ["GUIDED", "AUTO"]


@pytest.mark.parametrize("replan", [True, False], ids=["replan", "no-replan"])
def test_crossing_traffic_on_serial1_with_adsb_from_a_receiver(sitl_factory_fn, tmp_path: Path,
                                                              replan: bool) -> None:
    """The usual companion wiring: a ground station on SERIAL0, the companion on SERIAL1, an ADS-B receiver
    (component 156) on SERIAL2 reporting the two scripted intruders, timed to meet the vehicle wherever its real
    climb-out brings it. Without replanning both really conflict (separation from SITL's own positions below
    d_coll); with it, both keep d_coll and no item is flown from an unverified mission, and the report's
    mission.waypoints is the last mission verified, which ArduPlane gives back after the flight item by item."""
    scenario = SCENARIOS / "crossing_traffic.toml"
    sc = load_scenario(scenario)
    sitl = sitl_factory_fn("plane", sc.home)
    report = tmp_path / "rep"
    with sitl.hold_serial0():
        code, flight, events = _fly(scenario, sitl.serial1_url, report, "--traffic", sitl.serial2_url,
                                    *([] if replan else ["--no-replan"]))
        stored = asyncio.run(vehicle_mission(sitl.serial1_url)) if replan else None
    assert code == (0 if replan else 6) and flight["completed"] is True, flight  # 6: completed but unsafe
    assert flight["flown_safe"] is replan and flight["min_static_clearance_m"] >= flight["d_coll_m"], flight
    seps = flight["min_separation_m"]
    assert sorted(seps) == sorted(i.id for i in sc.intruders), seps
    assert any(e["event"] == "track" for e in events) is replan  # the companion heard them (it listens only then)
    if replan:
        assert min(seps.values()) >= flight["d_coll_m"], seps
        assert flight["replan_attempts"] >= 1
        assert _steps_into_unverified_items(events) == []
        _assert_started_once_verified(events)
        verified = [e for e in events if e["event"] == "replan_verified"]
        assert [m["reason"] for m in flight["missions"]] == ["initial", *(f"replan {e['n']}" for e in verified)]
        assert first_difference(waypoints_file(report / "mission.waypoints"), stored) is None
    else:
        assert max(seps.values()) < flight["d_coll_m"], seps


def test_copter_replans_around_an_intruder(sitl_factory_fn, tmp_path: Path) -> None:
    """rescue_dynamic flown by ArduCopter (it climbs vertically, so its route start comes much later than the
    plane's: the intruder's meet timing follows it), the companion alone on SERIAL0, the receiver on SERIAL1."""
    scenario = SCENARIOS / "rescue_dynamic.toml"
    sitl = sitl_factory_fn("copter", load_scenario(scenario).home)
    code, flight, events = _fly(scenario, sitl.serial0_url, tmp_path / "rep", "--traffic", sitl.serial1_url,
                                "--set", 'vehicle.type="copter"')
    assert code == 0 and flight["completed"] is True, flight
    assert min(flight["min_separation_m"].values()) >= flight["d_coll_m"], flight["min_separation_m"]
    assert flight["replan_attempts"] >= 1
    assert _steps_into_unverified_items(events) == []
