"""``fuseplan serve`` on the built-in simulator (one TCP port, shared by the companion and a ground-station script,
the simulator passing broadcast messages between them as ArduPilot routes them): an operator's upload is noticed,
planned round the vehicle's fence and replaced by the verified route with a STATUSTEXT saying so; a goal inside a
fence zone is refused and the operator's mission kept; an upload while armed is never replaced; a route refused
part-way by the autopilot leaves the operator's mission restored and verified, and the failure told."""

from __future__ import annotations

import asyncio
import contextlib
import json
from pathlib import Path

import gcs_world
from operator_course import CIRCLE, base_scenario, fence_items, goal_mission
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink
from readback import waypoints_file
from serve_gcs import GroundStation, two_item_mission, write_config

from companion.mavlink.items import MISSION, MissionItem
from companion.service import MAV_COMP_ID_PATHPLANNER, Service, load_config
from companion.service.serve import mission_key
from companion.sim import SimAutopilot
from planner.world.home import Home
from planner.world.scenario import load_scenario

HOME = Home(-35.363261, 149.165230, 584.0)


def _zones_file(path: Path) -> Path:
    """A configured zones file: a 50-m cylinder ("Tower") in the region, off the way to the goal."""
    lat, lon = (v / 1e7 for v in gcs_world.e7(HOME, north=850.0, east=150.0))
    path.write_text(json.dumps({"type": "FeatureCollection", "features": [{
        "type": "Feature", "properties": {"name": "Tower", "radius_m": 50},
        "geometry": {"type": "Point", "coordinates": [lon, lat]}}]}))
    return path


def test_serve_replaces_refuses_and_leaves_an_armed_vehicle_alone(tmp_path: Path) -> None:
    asyncio.run(_serve_on_the_simulator(tmp_path))  # its own loop: the planner's thread ends with it


async def _serve_on_the_simulator(tmp_path: Path) -> None:
    base = base_scenario(tmp_path / "base.toml", HOME, "plane", 18.0)
    async with SimAutopilot(load_scenario(base), "tcp:127.0.0.1:0", speedup=20.0, seed=1) as sim:
        url = f"tcp:127.0.0.1:{sim.port}"
        cfg = load_config(write_config(tmp_path / "serve.toml", url, base, tmp_path / "logs", poll_s=1.0, budget_s=3.0,
                                       zones=[_zones_file(tmp_path / "zones.geojson")]))
        service = Service(cfg)
        task = asyncio.create_task(service.run())
        try:
            async with GroundStation(url) as gcs:
                await gcs.link.wait_heartbeat(10.0)
                while service.seen is None:  # the service's first look at the vehicle: no request
                    await asyncio.sleep(0.05)
                # the companion is listed: its HEARTBEAT from the path planner's component, passed on by the autopilot
                beat = await gcs.link.wait_for("HEARTBEAT", any_source=True, timeout=5.0,
                                               predicate=lambda m: m.get_srcComponent() == MAV_COMP_ID_PATHPLANNER)
                assert beat.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER

                # 1. a fence, a via and a goal: the verified route replaces the mission, and the ground station is
                # told
                goal = goal_mission(HOME, home_item=True)
                via = gcs_world.goal_mission(HOME, north=100.0, east=500.0, alt=60.0, home_item=False)[0]
                operator = [it.with_seq(k) for k, it in enumerate([goal[0], via, goal[1]])]
                stored = await gcs.upload(operator, fence_items(HOME))
                t_line, text = await gcs.line(lambda s: "uploaded and verified" in s, stored, 15.0)
                _, said = await gcs.line(lambda s: "plan accepted" in s, stored, 1.0)
                while not service.handled[-1].verdict:
                    await asyncio.sleep(0.02)
                accepted = service.handled[-1]
                assert accepted.verdict == "accepted", accepted
                got = await gcs.client.download(MISSION)
                assert mission_key(got, True) != mission_key(operator, True) and len(got) > len(operator)
                assert got[-1].command == mavlink.MAV_CMD_NAV_WAYPOINT or len(got) > 3
                print(f"replaced {accepted.done_at - stored:.2f} s, told {t_line - stored:.2f} s after the upload: "
                      f"{said!r}, {text!r}")
                assert t_line - stored < 5.0
                request = (accepted.report / "request.scenario.toml").read_text()
                # the fence's zones and the configured zones file's cylinder (cylinders carry no names)
                assert "vehicle fence items 0-5" in request and request.count("[[cylinders]]") == 2
                plan = json.loads((accepted.report / "PLAN.json").read_text())
                assert plan["status"] in ("exact", "approximate")
                assert len(plan["vias"]) == 1, plan.get("vias")  # the operator's intermediate position
                events = [json.loads(x)["event"] for x in (accepted.report / "events.jsonl").read_text().split("\n")
                          if x]
                assert "plan_accepted" in events and "upload_verified" in events
                n = len(service.handled)
                await asyncio.sleep(2.5)  # its own upload, seen by its polls, is no new request
                assert len(service.handled) == n

                # 2. a goal inside the exclusion circle: refused, the operator's mission stays, the reason is told
                inside = goal_mission(HOME, home_item=True)
                x, y = gcs_world.e7(HOME, north=CIRCLE[1], east=CIRCLE[0])
                inside[-1] = inside[-1].__class__(**{**inside[-1].__dict__, "x": x, "y": y})
                stored = await gcs.upload(inside)
                _, why = await gcs.line(lambda s: "refused" in s, stored, 15.0)
                while not service.handled[-1].verdict:
                    await asyncio.sleep(0.02)
                assert service.handled[-1].verdict == "refused"
                got = await gcs.client.download(MISSION)
                assert mission_key(got, True) == mission_key(inside, True)
                print(f"refused: {why!r}")

                # 3. armed: an upload is never replaced
                await gcs.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
                while not sim.armed:
                    await asyncio.sleep(0.05)
                stored = await gcs.upload(operator)
                _, why = await gcs.line(lambda s: "armed" in s, stored, 15.0)
                got = await gcs.client.download(MISSION)
                assert mission_key(got, True) == mission_key(operator, True), "replaced while armed"
                await gcs.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0)
                while sim.armed:
                    await asyncio.sleep(0.05)

                # 4. the route's upload refused part-way (item 5, as ArduPilot refuses an item it cannot store): the
                # operator's mission is put back and verified, and the ground station hears of the failure
                sim.inject_item_refusal(5, mavlink.MAV_MISSION_NO_SPACE)
                operator = two_item_mission(HOME, True, 1000.0, 800.0)
                stored = await gcs.upload(operator)
                _, why = await gcs.line(lambda s: "failure" in s, stored, 15.0)
                while not service.handled[-1].verdict:
                    await asyncio.sleep(0.02)
                failed = service.handled[-1]
                assert failed.verdict == "failed" and sim.refusals, failed
                got = await gcs.client.download(MISSION)
                assert mission_key(got, True) == mission_key(operator, True), "the operator's mission not restored"
                events = [json.loads(x) for x in (failed.report / "events.jsonl").read_text().splitlines()]
                assert any(e["event"] == "mission_restored" and e["which"] == "previous" for e in events)
                print(f"failed: {why!r}")
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
    assert (cfg.log_folder / "service.jsonl").exists()
    # the service's telemetry log holds the route it uploaded, as pymavlink reads a MAVProxy .tlog
    log = mavutil.mavlink_connection(str(service.tlog))
    sent = set()
    while (m := log.recv_match(type="MISSION_ITEM_INT")) is not None:
        if m.get_srcComponent() == MAV_COMP_ID_PATHPLANNER and m.mission_type == MISSION:
            it = MissionItem.from_message(m)
            sent.add((it.seq, it.command, it.x, it.y))
    log.close()
    route = waypoints_file(accepted.report / "mission.waypoints")[1:]  # the first request's route (home aside)
    assert route and {(it.seq, it.command, it.x, it.y) for it in route} <= sent
