"""The flight record (issue 36) over real UDP on 127.0.0.1: the report's telemetry log, read back by pymavlink and
its ``mavlogdump.py``, holds what the companion uploaded and heard; the report's mission files are the missions the
vehicle held, the last one equal item by item to what the vehicle gives back after the flight."""

from __future__ import annotations

import asyncio
import contextlib
import json
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from readback import assert_the_tlog_holds_the_flight, first_difference, vehicle_mission, waypoints_file

from companion.cli import main
from companion.sim import SimAutopilot
from planner.distribution import fuseplan_version
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
DYNAMIC = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
FAST = ["--set", "planner.pso.n_pop=200", "--set", "planner.pso.max_iter=80"]
RETRIES = 1  # flights flown again when no replan was made live


# test_announce's replanning flight checks its tlog with the same helper (a replanned mission: the last items sent)
@pytest.mark.slow(covered_by="companion/flight/test_announce.py::test_a_replanning_flight_on_the_simulator_says_what_it_decides")
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

    assert_the_tlog_holds_the_flight(report)


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
