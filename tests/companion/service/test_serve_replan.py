"""``fuseplan serve`` supervising a flight that replans (rescue_dynamic on the built-in simulator, its intruder timed
to meet the route the vehicle starts with): the missions the live replanner verified on the vehicle are the
service's own, so once the flight is over the next readbacks are no new request (before the fix: "plan refused:
vehicle armed" while it loitered at the goal, then a plan from where it stood); the request's report holds the
missions as flown (mission.waypoints: the last one stored on the vehicle; flight.json's index of them, and the
service's telemetry log). A stop while a request is planned drops it; a stop during a replan waits for it."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink
from readback import same_mission, waypoints_file
from serve_gcs import GroundStation, two_item_mission, write_config

from companion.mavlink.items import MISSION
from companion.service import Service, load_config
from companion.service.serve import Handled
from companion.sim import SimAutopilot
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
DYNAMIC = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
QUICK_PLAN = ("planner.pso.n_pop=200", "planner.pso.max_iter=80")  # a feasible plan in ~2 s


def test_a_replanned_flight_is_no_new_request(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    asyncio.run(_replanned_flight(tmp_path))  # its own loop: the planner's threads end with it
    # the service's watch is closed while the flight (and the request) run: it does not fill up meanwhile
    assert not [r.message for r in caplog.records if "overflowing" in r.message]


def test_a_stop_during_a_replan_lets_the_vehicle_go_on_its_verified_mission(tmp_path: Path) -> None:
    asyncio.run(_stop_during_a_replan(tmp_path))


def test_a_stop_while_planning_drops_the_request_and_leaves_the_operators_mission(tmp_path: Path) -> None:
    asyncio.run(_stop_while_planning(tmp_path))


def _config(tmp_path: Path, url: str) -> Path:
    config = write_config(tmp_path / "serve.toml", url, DYNAMIC, tmp_path / "logs", poll_s=0.5, budget_s=3.0)
    config.write_text(config.read_text().replace("zones = []", f"zones = []\nset = {json.dumps(QUICK_PLAN)}"))
    return config


async def _fly_the_route(service: Service, gcs: GroundStation) -> tuple[Handled, float]:
    """The operator's upload of the scenario's goal, planned and verified; then the pilot's start."""
    sc = load_scenario(DYNAMIC)
    await gcs.link.wait_heartbeat(10.0)
    while service.seen is None:
        await asyncio.sleep(0.05)
    goal = sc.goal
    stored = await gcs.upload(two_item_mission(sc.home, True, float(goal[0]), float(goal[1]), float(goal[2])))
    await gcs.line(lambda s: "uploaded and verified" in s, stored, 30.0)
    request = service.handled[-1]
    assert request.verdict == "accepted", request
    await gcs.arm_and_start(30.0)
    return request, stored


async def _replanned_flight(tmp_path: Path) -> None:
    async with SimAutopilot(load_scenario(DYNAMIC), "tcp:127.0.0.1:0", speedup=20.0, seed=1) as sim:
        url = f"tcp:127.0.0.1:{sim.port}"
        service = Service(load_config(_config(tmp_path, url)))
        task = asyncio.create_task(service.run())
        try:
            async with GroundStation(url) as gcs:
                request, stored = await _fly_the_route(service, gcs)
                await gcs.line(lambda s: s.startswith("fuseplan: flight "), stored, 60.0)
                while request.flight is None:
                    await asyncio.sleep(0.05)
                flight = request.flight
                assert flight["replans"] >= 1, flight["replan_log"]
                # ArduPlane loiters at the goal, still armed: then the pilot lands and disarms
                await asyncio.sleep(2.0)  # four polls: the replanned mission on the vehicle is the service's own
                await gcs.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
                t0 = time.monotonic()
                while sim.armed and time.monotonic() - t0 < 5.0:
                    await asyncio.sleep(0.05)
                await asyncio.sleep(1.5)
                assert [h.number for h in service.handled] == [request.number], \
                    [(h.number, h.verdict, h.reason) for h in service.handled]
                flown = await gcs.client.download(MISSION)
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    # the report holds the missions as flown: the last one verified on the vehicle as mission.waypoints, every one
    # in missions/ and flight.json's index; its tlog is the service's (absolute: one per start of the service)
    assert same_mission(waypoints_file(request.report / "mission.waypoints"), flown)
    reasons = [m["reason"] for m in flight["missions"]]
    assert reasons[0] == "initial" and any(r.startswith("replan ") for r in reasons), reasons
    assert all((request.report / m["file"]).exists() for m in flight["missions"])
    assert flight["tlog"] == str(service.tlog) and service.tlog.exists()


async def _stop_during_a_replan(tmp_path: Path) -> None:
    """SIGTERM (the CLI's handler calls Service.stop) as the replan is planned: the vehicle is held for it and its
    upload follows; the stop waits for the verified replan and the resume, then lets go (AUTO, not GUIDED)."""
    async with SimAutopilot(load_scenario(DYNAMIC), "tcp:127.0.0.1:0", speedup=20.0, seed=1) as sim:
        url = f"tcp:127.0.0.1:{sim.port}"
        service = Service(load_config(_config(tmp_path, url)))
        task = asyncio.create_task(service.run())
        seen: list[str] = []

        def on_record(rec: dict) -> None:
            seen.append(rec["event"])
            if rec["event"] == "replan_planned" and not service._stopping:
                service.stop(task)  # synchronously, mid-replan: the hold is on, the upload next

        service.listeners.append(on_record)
        try:
            async with GroundStation(url) as gcs:
                await _fly_the_route(service, gcs)
                await asyncio.wait_for(asyncio.shield(task), 60.0)
        except asyncio.CancelledError:
            pass
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        assert "replan_planned" in seen, seen
        assert sim.armed and sim.mode == "AUTO", sim.mode  # flying its verified mission, not held
        after = seen[seen.index("replan_planned"):]
        assert "stop_deferred" in after and "replan_verified" in after and "resume" in after, after


async def _stop_while_planning(tmp_path: Path) -> None:
    """SIGTERM while a request is planned: nothing is on its way to the vehicle yet, so the service stops at once
    (its search ends at its next iteration), the request is dropped and the operator's mission stays."""
    sc = load_scenario(DYNAMIC)
    async with SimAutopilot(sc, "tcp:127.0.0.1:0", speedup=20.0, seed=1) as sim:
        url = f"tcp:127.0.0.1:{sim.port}"
        service = Service(load_config(_config(tmp_path, url)))
        task = asyncio.create_task(service.run())
        stopped: list[float] = []

        def on_record(rec: dict) -> None:
            if rec["event"] == "planning" and not stopped:
                stopped.append(time.monotonic())
                service.stop(task)

        service.listeners.append(on_record)
        try:
            async with GroundStation(url) as gcs:
                await gcs.link.wait_heartbeat(10.0)
                while service.seen is None:
                    await asyncio.sleep(0.05)
                goal = sc.goal
                operator = two_item_mission(sc.home, True, float(goal[0]), float(goal[1]), float(goal[2]))
                await gcs.upload(operator)
                with contextlib.suppress(asyncio.CancelledError):
                    await asyncio.wait_for(asyncio.shield(task), 30.0)
                took = time.monotonic() - stopped[0]
                assert same_mission(await gcs.client.download(MISSION), operator), "replaced after the stop"
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    request = service.handled[-1]
    assert request.verdict == "failed" and "stopped" in request.reason, request
    assert took < 2.0, took
