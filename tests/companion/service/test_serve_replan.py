"""``fuseplan serve`` supervising a flight that replans (rescue_dynamic on the built-in simulator, its intruder timed
to meet the route the vehicle starts with): the missions the live replanner verified on the vehicle are the
service's own, so once the flight is over the next readbacks are no new request (before the fix: "plan refused:
vehicle armed" while it loitered at the goal, then a plan from where it stood)."""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink
from serve_gcs import GroundStation, two_item_mission, write_config

from companion.service import Service, load_config
from companion.sim import SimAutopilot
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
DYNAMIC = ROOT / "sitl_scenarios" / "rescue_dynamic.toml"
QUICK_PLAN = ("planner.pso.n_pop=200", "planner.pso.max_iter=80")  # a feasible plan in ~2 s


def test_a_replanned_flight_is_no_new_request(tmp_path: Path) -> None:
    asyncio.run(_replanned_flight(tmp_path))  # its own loop: the planner's threads end with it


async def _replanned_flight(tmp_path: Path) -> None:
    sc = load_scenario(DYNAMIC)
    async with SimAutopilot(sc, "tcp:127.0.0.1:0", speedup=20.0, seed=1) as sim:
        url = f"tcp:127.0.0.1:{sim.port}"
        config = write_config(tmp_path / "serve.toml", url, DYNAMIC, tmp_path / "logs", poll_s=0.5, budget_s=3.0)
        config.write_text(config.read_text().replace("zones = []", f"zones = []\nset = {json.dumps(QUICK_PLAN)}"))
        service = Service(load_config(config))
        task = asyncio.create_task(service.run())
        try:
            async with GroundStation(url) as gcs:
                await gcs.link.wait_heartbeat(10.0)
                while service.seen is None:
                    await asyncio.sleep(0.05)
                goal = sc.goal
                stored = await gcs.upload(two_item_mission(sc.home, True, float(goal[0]), float(goal[1]),
                                                           float(goal[2])))
                await gcs.line(lambda s: "uploaded and verified" in s, stored, 30.0)
                request = service.handled[-1]
                assert request.verdict == "accepted", request
                await gcs.arm_and_start(30.0)
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
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
