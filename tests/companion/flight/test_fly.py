"""`fuseplan fly --sim`, `demo`, `sim` and `export` end to end over real UDP sockets on 127.0.0.1."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil, mavwp

from companion.cli import main
from planner.distribution import fuseplan_version

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
FAST = ["--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"]


def _flight(report: Path) -> dict:
    return json.loads((report / "flight.json").read_text())


def test_fly_sim_completes_and_writes_the_report(tmp_path) -> None:
    """`fly --sim` end to end, through a little packet loss (`--sim-loss`; 30 % below and in test_faults)."""
    report = tmp_path / "rep"
    code = main(["fly", str(STATIC), "--sim", "--speedup", "20", "--sim-loss", "0.05", "--report", str(report), "-q",
                 *FAST])
    assert code == 0
    for name in ("PLAN.json", "mission.waypoints", "mission.plan", "mission.geojson", "events.jsonl",
                 "flight.json", "track.png"):
        assert (report / name).stat().st_size > 0, name
    fl = _flight(report)
    assert fl["completed"] is True
    assert fl["upload_s"] > 0 and fl["autopilot"] == "ardupilot"
    assert fl["min_clearance_m"] >= fl["d_coll_m"]  # the flown (truth) track kept clear
    n_wp = len(json.loads((report / "PLAN.json").read_text())["waypoints"])
    records = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    # every route waypoint after the start was flown: each became the current item (MISSION_CURRENT is streamed,
    # so a lost one is repeated; a lost MISSION_ITEM_REACHED is not, and at 5 % loss two of ten go missing about
    # one flight in twelve, which is why items_reached is not counted here)
    currents = {r["seq"] for r in records if r["event"] == "current"}
    loaded = mavwp.MAVWPLoader()
    assert loaded.load(str(report / "mission.waypoints")) == fl["mission_items"] + fl["room_items"]  # as stored
    route = {i for i in range(1, loaded.count()) if loaded.wp(i).command == mavutil.mavlink.MAV_CMD_NAV_WAYPOINT}
    assert len(route) >= n_wp - 1 and route <= currents | set(fl["items_reached"])
    assert len(fl["items_reached"]) >= (n_wp - 1) // 2
    assert records[0]["event"] == "scene" and len(records[0]["route"]) >= 10  # the status page's map, first
    assert records[1]["event"] == "sim_started" and records[1]["loss"] == 0.05
    events = [r["event"] for r in records]
    # the vehicle's limits read, then its position fix and the departure checked from it, all before the upload
    order = [events.index(e) for e in ("vehicle_limits", "connected", "ready", "vehicle_fix", "departure",
                                       "upload_verified", "mission", "armed", "mission_start", "position", "finished")]
    assert order == sorted(order)


@pytest.mark.slow(covered_by="companion/flight/test_faults.py::"
                           "test_full_flight_through_30_percent_drop_with_duplicates_and_reordering[plane-1]")
def test_fly_sim_with_30_percent_loss_still_completes(tmp_path) -> None:
    report = tmp_path / "lossy"
    code = main(["fly", str(STATIC), "--sim", "--speedup", "20", "--sim-loss", "0.3", "--report", str(report),
                 "-q", *FAST])
    assert code == 0
    assert _flight(report)["completed"] is True


@pytest.mark.slow(covered_by=(  # the same scenario, flown to its end on ArduCopter (armed in GUIDED, started in
    # AUTO), and the simulated copter's start sequence held to SITL's by the conformance tests
    "sitl/test_flights.py::test_copter_scenario_flies_on_arducopter",
    "conformance/test_flight.py::test_start_sequence_arms_and_takes_off[sim-copter]",
    "conformance/test_flight.py::test_every_waypoint_is_reached_in_order[sim-copter]"))
def test_fly_copter_scenario_on_sim(tmp_path) -> None:
    report = tmp_path / "copter"
    code = main(["fly", str(ROOT / "sitl_scenarios" / "mountain_rescue.toml"), "--sim", "--speedup", "30",
                 "--report", str(report), "-q", *FAST])
    assert code == 0
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    modes = [e["mode"] for e in events if e["event"] == "mode"]
    assert modes == ["GUIDED", "AUTO"]  # a copter will not arm in AUTO
    assert _flight(report)["completed"] is True


def test_fly_infeasible_plan_exits_3_without_flying(tmp_path, capsys) -> None:
    report = tmp_path / "no"
    # d_coll 90 m: the start itself is 80 m from a cylinder, so no route can be feasible
    code = main(["fly", str(STATIC), "--sim", "--report", str(report), "-q", "--set", "hazard.d_coll=90",
                 "--set", "hazard.d_safe=100", "--set", "planner.pso.n_pop=30", "--set", "planner.pso.max_iter=5",
                 "--algorithm", "spso"])
    assert code == 3
    assert (report / "PLAN.json").exists() and not (report / "flight.json").exists()


def test_fly_unreachable_autopilot_exits_4(tmp_path, capsys) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:  # a port nobody answers on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = main(["fly", str(STATIC), "--connect", f"udpout:127.0.0.1:{port}", "--report", str(tmp_path / "r"),
                 "--heartbeat-timeout", "2", "-q", *FAST])
    assert code == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("fuseplan: error:") and "within 2 s" in err[0], err


def test_fly_refused_item_exits_4_with_one_line_and_the_previous_mission_restored(tmp_path, capsys) -> None:
    """`fuseplan fly --connect` to an autopilot (our simulator, in its own thread) that refuses item 4 of the
    upload: exit 4, one line naming the item, the autopilot's answer and what the vehicle was left with."""
    import asyncio
    import threading

    from companion.sim import SimAutopilot
    from planner.world.scenario import load_scenario

    ready, stop, port, left = threading.Event(), threading.Event(), [0], []

    async def autopilot() -> None:
        async with SimAutopilot(load_scenario(STATIC), "udpin:127.0.0.1:0", speedup=20.0) as sim:
            sim.inject_item_refusal(4)
            port[0] = sim.port
            ready.set()
            while not stop.is_set():
                await asyncio.sleep(0.05)
            left.append((sim.mission, sim.refusals, sim.armed))

    thread = threading.Thread(target=asyncio.run, args=(autopilot(),), name="sim")
    thread.start()
    try:
        assert ready.wait(10.0)
        report = tmp_path / "r"
        code = main(["fly", str(STATIC), "--connect", f"udpout:127.0.0.1:{port[0]}", "--report", str(report),
                     "-q", *FAST])
    finally:
        stop.set()
        thread.join(10.0)
    mission, refusals, armed = left[0]
    assert code == 4
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("fuseplan: error: mission upload refused at item 4: MAV_MISSION_ERROR; ")
    assert "previous verified mission (1 item) was restored" in err[0]  # the simulator had home only
    assert [it.seq for it, _ in refusals] == [4] and len(refusals[0][1]) > 1  # items 1-3 had been written
    assert len(mission) == 1 and not armed  # back to the empty mission it had (home only), never started
    fl = _flight(report)
    assert fl["completed"] is False and "refused at item 4" in fl["reason"]
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert [e["which"] for e in events if e["event"] == "mission_restored"] == ["previous"]


def test_sim_command_serves_heartbeats(tmp_path) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", "sim", str(STATIC), "--listen",
                             f"udpin:127.0.0.1:{port}", "--speedup", "5"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=191)
    try:
        deadline = time.monotonic() + 20
        hb = None
        while hb is None and time.monotonic() < deadline:
            conn.mav.heartbeat_send(18, 8, 0, 0, 4)  # let the sim learn our address
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
        assert hb is not None and hb.type == mavutil.mavlink.MAV_TYPE_FIXED_WING
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    finally:
        conn.close()
        proc.terminate()
        proc.communicate(timeout=10)


@pytest.mark.parametrize("fmt,suffix", [("waypoints", ".waypoints"), ("plan", ".plan"), ("geojson", ".geojson")])
def test_export_command(tmp_path, fmt, suffix, capsys) -> None:
    out = tmp_path / f"m{suffix}"
    assert main(["export", str(STATIC), "--format", fmt, "-o", str(out), *FAST]) == 0
    assert out.stat().st_size > 0
    if fmt != "waypoints":
        json.loads(out.read_text())


def test_the_readme_demo_completes_clear_of_the_intruder_it_predicted(tmp_path, monkeypatch, capsys) -> None:
    """`fuseplan demo` (the README's first command): exit 0, the ADS-B intruder's crossing predicted, the flight
    completed with every threat (truth) outside d_coll, whether the companion replanned or waited it out."""
    monkeypatch.chdir(tmp_path)
    assert main(["demo"]) == 0
    out = capsys.readouterr().out
    assert "CONFLICT with adsb-c0ffee" in out
    flight = json.loads((tmp_path / "fuseplan-demo" / "flight.json").read_text())
    assert flight["completed"] and flight["replanning"] and flight["replan_attempts"] >= 1
    assert set(flight["min_separation_m"]) >= {"intruder-1", "loiter-1", "patrol-1"}
    assert min(flight["min_separation_m"].values()) > flight["d_coll_m"]
    assert all((tmp_path / "fuseplan-demo" / name).exists() for name in ("PLAN.json", "events.jsonl"))


def test_the_reports_mission_plan_fences_what_export_fences(tmp_path) -> None:
    """The flight report's mission.plan holds the fence by the rule the upload and `export` use: spheres are not
    fenced (the autopilots' fences are 2-D circles and polygons), nor zones the route may fly over."""
    from companion.flight.fly import _write_mission_files
    from companion.mission.builder import mission_from_plan_json, spec_from_plan_json
    from planner.world.scenario import load_scenario

    source = ROOT / "sitl_scenarios" / "crossing_traffic.toml"  # six cylinders and two spheres
    plan = tmp_path / "PLAN.json"
    assert main(["plan", str(source), "-o", str(plan), "-q", *FAST]) == 0
    assert main(["export", str(plan), "--format", "plan", "-o", str(tmp_path / "export.plan")]) == 0
    doc, scenario = json.loads(plan.read_text()), load_scenario(source)
    spec, items = spec_from_plan_json(doc, scenario, "ardupilot"), mission_from_plan_json(doc, scenario, "ardupilot")
    _write_mission_files(tmp_path, doc, scenario, items, spec, fence=[object()])
    flown, exported = (json.loads((tmp_path / n).read_text())["geoFence"] for n in ("mission.plan", "export.plan"))
    assert len(flown["circles"]) == len(scenario.environment.cylinders)  # the spheres left out
    assert flown == exported


def _polygon_toml(cx: float, cy: float, n: int, r: float = 30.0) -> str:
    import math

    xy = ", ".join(f"[{cx + r * math.cos(2 * math.pi * k / n):.2f}, {cy + r * math.sin(2 * math.pi * k / n):.2f}]"
                   for k in range(n))
    return f"\n[[prisms]]\nxy = [{xy}]\n"


def test_fly_with_a_fence_too_large_for_the_autopilot_exits_2_before_anything_is_sent(tmp_path, capsys) -> None:
    """Two polygons of 60 and 30 vertices besides the six cylinders make 96 fence items, more than ArduPlane's 84
    (the simulator imitates its storage): `fuseplan fly` says so in one line naming the zone to drop and exits 2;
    the vehicle's fence (a triangle a ground station put there) and its mission are as they were, nothing uploaded."""
    import asyncio
    import threading

    from pymavlink.dialects.v20 import common as mavlink

    from companion.mavlink.items import FENCE, FRAME_GLOBAL_INT, MissionItem
    from companion.mavlink.link import Link
    from companion.mavlink.protocol import MissionClient
    from companion.sim import SimAutopilot
    from planner.world.scenario import load_scenario

    zones = tmp_path / "zones.toml"
    zones.write_text(STATIC.read_text() + _polygon_toml(940.0, 60.0, 60) + _polygon_toml(60.0, 940.0, 30))
    triangle = [MissionItem(k, FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, param1=3.0,
                            x=-353600000 + 1000 * k, y=1491600000 + 500 * (k % 2), mission_type=FENCE)
                for k in range(3)]
    ready, stop, port, left = threading.Event(), threading.Event(), [0], []

    async def autopilot() -> None:
        async with SimAutopilot(load_scenario(STATIC), "tcp:127.0.0.1:0", speedup=20.0) as sim:
            async with Link(f"tcp:127.0.0.1:{sim.port}", source_system=255, open_timeout=5.0) as gcs:
                await gcs.wait_heartbeat(10.0)
                await MissionClient(gcs).upload_verified(triangle, FENCE)
            before = sim.fence
            port[0] = sim.port
            ready.set()
            while not stop.is_set():
                await asyncio.sleep(0.05)
            left.append((before, sim.fence, sim.mission))

    thread = threading.Thread(target=asyncio.run, args=(autopilot(),), name="sim")
    thread.start()
    try:
        assert ready.wait(20.0)
        report = tmp_path / "r"
        code = main(["fly", str(zones), "--connect", f"tcp:127.0.0.1:{port[0]}", "--report", str(report), "-q",
                     *FAST])
    finally:
        stop.set()
        thread.join(10.0)
    before, fence, mission = left[0]
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert err[0].startswith("fuseplan: error: the fence does not fit the autopilot: 96 fence items, ArduPlane "
                             "stores at most 84"), err
    assert "drop or simplify prisms[0] (60 items)," in err[0] and err[0].endswith("nothing was uploaded")
    assert len(before) == 3 and fence == before and len(mission) == 1  # the triangle, and home only
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert not [e for e in events if e["event"] in ("upload_start", "backup")]
    assert [e["fits"] for e in events if e["event"] == "fence_capacity"] == [False]
    refused = _flight(report)
    assert "does not fit" in refused["reason"] and refused["fuseplan_version"] == fuseplan_version()


def test_export_warns_when_the_plans_fence_will_not_fit_the_vehicle(tmp_path, capsys) -> None:
    """`fuseplan export --format plan` of a scenario whose fence (96 items, as above) is larger than ArduPlane's 84
    writes the file (a ground station may still fly the route without the fence) and warns in one line naming the
    zone to drop; with the polygons simplified away, no warning."""
    big = tmp_path / "zones.toml"
    big.write_text(STATIC.read_text() + _polygon_toml(940.0, 60.0, 60) + _polygon_toml(60.0, 940.0, 30))
    out = tmp_path / "big.plan"
    assert main(["export", str(big), "--format", "plan", "-o", str(out), *FAST]) == 0
    warning = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert out.stat().st_size > 0 and len(warning) == 1
    assert "96 fence items, ArduPlane stores at most 84" in warning[0] and "prisms[0] (60 items)" in warning[0]
    assert main(["export", str(STATIC), "--format", "plan", "-o", str(tmp_path / "ok.plan"), *FAST]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_flight_supervised_past_its_flight_timeout_is_reported_not_completed(tmp_path, capsys) -> None:
    """`--flight-timeout S`: the companion stops supervising after S wall seconds and says so (exit 5, the reason
    in flight.json). (A bad value: test_plan_file.py::test_every_fly_option_is_checked_before_planning.)"""
    report = tmp_path / "rep"
    assert main(["fly", str(STATIC), "--sim", "--speedup", "20", "--flight-timeout", "3", "--report", str(report),
                 "-q", *FAST]) == 5
    flight = _flight(report)
    assert flight["completed"] is False and flight["reason"] == "timeout after 3 s"
    assert "flight NOT completed: timeout after 3 s" in capsys.readouterr().err
