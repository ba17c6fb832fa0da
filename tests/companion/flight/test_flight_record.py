"""The flight record (issue 36) over real UDP on 127.0.0.1: the report's telemetry log, read back by pymavlink and
its ``mavlogdump.py``, holds what the companion uploaded and heard; the report's mission files are the missions the
vehicle held, the last one equal item by item to what the vehicle gives back after the flight."""

from __future__ import annotations

import asyncio
import contextlib
import json
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil
from readback import first_difference, same_item, vehicle_mission, waypoints_file

from companion.cli import main
from companion.mavlink.items import MISSION, MissionItem
from companion.mavlink.link import MAV_COMP_ID_ONBOARD_COMPUTER
from companion.sim import SimAutopilot
from planner.distribution import fuseplan_version
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
DYNAMIC = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
FAST = ["--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"]
RETRIES = 1  # flights flown again when no replan was made live


def _tlog(path: Path) -> list:
    """Every message of a .tlog, read by pymavlink as MAVProxy's logs are."""
    log = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append(msg)
    log.close()
    return out


def _mavlogdump() -> list[str]:
    script = shutil.which("mavlogdump.py")
    if script is None:
        pytest.skip("mavlogdump.py (installed with pymavlink) is not on PATH")
    return [sys.executable, script]


def test_the_report_holds_a_tlog_of_the_link(tmp_path: Path) -> None:
    """`fly --sim`: flight.tlog holds every message of the companion's link. pymavlink reads it back with times that
    never go backwards, HEARTBEATs both ways (ours from the onboard computer's component, link 3 as MAVProxy marks
    what it sends), and the mission upload: mavlogdump.py lists the MISSION_ITEM_INTs sent, the same items (seq,
    command, coordinates) as the report's mission file."""
    report = tmp_path / "rep"
    assert main(["fly", str(STATIC), "--sim", "--speedup", "20", "--report", str(report), "-q", *FAST]) == 0
    flight = json.loads((report / "flight.json").read_text())
    assert flight["tlog"] == "flight.tlog" and flight["fuseplan_version"] == fuseplan_version() != "unknown"
    assert [m["reason"] for m in flight["missions"]] == ["initial"]  # nothing moves in this scenario
    mission = waypoints_file(report / "mission.waypoints")
    assert mission == waypoints_file(report / flight["missions"][0]["file"])
    assert len(mission) == flight["mission_items"] + flight["room_items"] == flight["missions"][0]["items"]

    msgs = _tlog(report / "flight.tlog")
    times = [m._timestamp for m in msgs]
    assert len(msgs) > 500 and times == sorted(times) and times[-1] - times[0] > 2.0
    ours = (1, MAV_COMP_ID_ONBOARD_COMPUTER)
    beats = [((m.get_srcSystem(), m.get_srcComponent()), m._link) for m in msgs if m.get_type() == "HEARTBEAT"]
    assert (ours, 3) in beats and ((1, 1), 0) in beats  # ours, sent; the autopilot's, received
    sent = [m for m in msgs if m.get_type() == "MISSION_ITEM_INT" and m.mission_type == MISSION
            and (m.get_srcSystem(), m.get_srcComponent()) == ours]
    uploaded = {m.seq: MissionItem.from_message(m) for m in sent}  # an item asked for twice is sent twice
    assert sorted(uploaded) == list(range(len(mission)))
    assert all(same_item(uploaded[it.seq], it) for it in mission[1:])  # item 0 is home in the file too

    dump = subprocess.run([*_mavlogdump(), "--format", "json", "--types", "MISSION_ITEM_INT",
                           str(report / "flight.tlog")], capture_output=True, text=True, timeout=60, check=True)
    rows = [json.loads(line) for line in dump.stdout.splitlines() if line.startswith("{")]
    # ours go to the autopilot (component 1); the vehicle's (its readback) come to us
    to_vehicle = {r["data"]["seq"]: r["data"] for r in rows
                  if r["data"]["target_component"] == 1 and r["data"]["mission_type"] == MISSION}
    assert sorted(to_vehicle) == list(range(len(mission)))
    for it in mission:
        row = to_vehicle[it.seq]
        assert (row["command"], row["x"], row["y"]) == (it.command, it.x, it.y), (it, row)
        assert abs(row["z"] - it.z) < 1e-3
    stamps = [r["meta"]["timestamp"] for r in rows]
    assert stamps == sorted(stamps)


@contextlib.contextmanager
def _simulator(scenario: Path, speedup: float) -> Iterator[int]:
    """The simulated autopilot served from a thread of its own, so that it outlives a `fly` run (yields its UDP
    port)."""
    ready, stop, port, errors = threading.Event(), threading.Event(), [0], []

    async def serve() -> None:
        async with SimAutopilot(load_scenario(scenario), "udpin:127.0.0.1:0", speedup=speedup, seed=1) as sim:
            port[0] = sim.port
            ready.set()
            while not stop.is_set():
                await asyncio.sleep(0.05)

    def run() -> None:
        try:
            asyncio.run(serve())
        except BaseException as e:  # surfaced below
            errors.append(e)
            ready.set()

    thread = threading.Thread(target=run, name="record-sim")
    thread.start()
    try:
        assert ready.wait(20.0) and not errors, errors
        yield port[0]
    finally:
        stop.set()
        thread.join(20.0)
    if errors:
        raise errors[0]


# ArduPlane SITL's crossing-traffic flight checks the same (its readback after live replans equals mission.waypoints,
# the missions' reasons): this one is for machines without SITL and for --with-covered
@pytest.mark.slow(covered_by="sitl/test_flights.py::test_crossing_traffic_on_serial1_with_adsb_from_a_receiver[replan]")
def test_the_reports_mission_is_the_one_the_vehicle_holds_after_a_replan(tmp_path: Path) -> None:
    """A flight with live replanning (the dynamic rescue's intruder; a 0.5 s replan budget, in which the planner
    finds a detour) against the simulator run apart from `fly`: after the flight, the vehicle's mission read back
    with the mission protocol is the report's mission.waypoints, item for item, and the last of missions/; the first
    of missions/ is the planned mission uploaded before the take-off. On a loaded machine the planner may find no
    detour in its budget and hold the vehicle instead, uploading nothing: then one more flight."""
    for attempt in range(1, RETRIES + 2):
        report = tmp_path / f"rep{attempt}"
        with _simulator(DYNAMIC, speedup=10.0) as port:
            url = f"udpout:127.0.0.1:{port}"
            code = main(["fly", str(DYNAMIC), "--connect", url, "--arm", "--replan-budget", "0.5", "--report",
                         str(report), "-q"])
            got = asyncio.run(vehicle_mission(url))
        flight = json.loads((report / "flight.json").read_text())
        events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
        assert code == 0 and flight["completed"], (flight.get("reason"), [e["event"] for e in events][-30:])
        replans = [e for e in events if e["event"] == "replan_verified"]
        if replans:
            break
    assert replans, "no replan was uploaded: nothing to tell the first mission from the last"
    missions = flight["missions"]
    assert [m["reason"] for m in missions] == ["initial", *(f"replan {e['n']}" for e in replans)]
    assert [m["t"] for m in missions] == sorted(m["t"] for m in missions)
    assert [m["t"] for m in missions[1:]] == [e["t"] for e in replans]
    last = waypoints_file(report / "mission.waypoints")
    assert first_difference(last, got) is None  # item 0 aside: the autopilot's home
    assert last == waypoints_file(report / missions[-1]["file"]) and len(last) == missions[-1]["items"]
    first = waypoints_file(report / missions[0]["file"])
    assert first != last  # the replan changed the route
    plan = json.loads((report / "mission.plan").read_text())
    assert len(plan["mission"]["items"]) == len(last) - 1  # QGC keeps home out of its items
    assert plan["geoFence"]["circles"]  # the fence the upload used, as before
