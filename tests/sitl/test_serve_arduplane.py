"""Issue 36 on ArduPlane SITL: ``fuseplan serve`` on SERIAL1 (in this process) beside a ground-station script on
SERIAL2. The script uploads a fence (issue 35's operator course) and a two-item mission (takeoff, goal); within 5 s
the vehicle's mission is the verified safe route and the script has the companion's STATUSTEXT saying so (ArduPilot
routes the companion's broadcast STATUSTEXT to the other port). The script arms and starts; the service supervises
the flight to the goal (its flight.json: completed, flown safe). The autopilot then reboots (force-disarmed, then
MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: SITL starts itself again on the same ports); the service reconnects and handles a
second upload (mission replaced, STATUSTEXT). This covers tests/sitl/test_operator_world_flight.py's flight (the
fence and goal read from the vehicle, planned round, flown safe) and its track-by-zone check (the same independent
check of the flown track against each zone)."""

from __future__ import annotations

import asyncio
import contextlib
import time
from pathlib import Path

from operator_course import D_COLL, base_scenario, fence_items
from pymavlink.dialects.v20 import common as mavlink
from serve_gcs import GroundStation, flown_round_the_zones, replaced, two_item_mission, write_config

from companion.service import Service, load_config
from planner.world.home import Home

HOME = Home(-35.363261, 149.165230, 584.0)
FAST = 20.0
REPLACED_WITHIN_S = 5.0


async def _scenario(tmp_path: Path, sitl: object) -> None:
    base = base_scenario(tmp_path / "base.toml", HOME, "plane", 18.0)
    cfg = load_config(write_config(tmp_path / "serve.toml", sitl.serial1_url, base, tmp_path / "logs"))
    service = Service(cfg)
    task = asyncio.create_task(service.run())
    try:
        async with GroundStation(sitl.serial2_url) as gcs:
            await gcs.link.wait_heartbeat(30.0)
            while service.seen is None:
                await asyncio.sleep(0.05)
            first = await replaced(gcs, service, two_item_mission(HOME, True, 1180.0, 720.0),
                                   fence_items(HOME), True)
            assert first["replaced_s"] < REPLACED_WITHIN_S and first["told_s"] < REPLACED_WITHIN_S, first

            t0 = time.monotonic()
            await gcs.arm_and_start()
            handled = service.handled[-1]
            while handled.flight is None:
                assert time.monotonic() - t0 < 240.0, "the flight was not over within 240 s"
                await asyncio.sleep(0.2)
            flight = handled.flight
            print(f"flight {time.monotonic() - t0:.1f} s: completed {flight['completed']} ({flight['reason']}), "
                  f"clearance {flight['min_static_clearance_m']:.1f} m")
            assert flight["completed"] and flight["flown_safe"], flight
            assert flight["min_static_clearance_m"] >= D_COLL
            flown_round_the_zones(handled.report, 200.0)
            await gcs.line(lambda s: "flight complete" in s, t0, 10.0)

            # the autopilot restarts: disarmed by force (it is flying its RTL), then rebooted
            await gcs.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196)
            connections = service.connections
            t_reboot = time.monotonic()
            with contextlib.suppress(Exception):  # it may go before it answers
                await gcs.client.command_long(mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1, retries=0)
            await asyncio.sleep(1.0)
            await asyncio.to_thread(sitl.hold_serial0)  # SITL waits for SERIAL0's client again
            while service.connections == connections:
                assert time.monotonic() - t_reboot < 90.0, "the service did not reconnect within 90 s"
                await asyncio.sleep(0.1)
            print(f"reconnected {time.monotonic() - t_reboot:.1f} s after the reboot command")
            assert await gcs.link.wait_back(30.0)
            second = await replaced(gcs, service, two_item_mission(HOME, True, 1000.0, 800.0),
                                   None, True)
            assert second["replaced_s"] < REPLACED_WITHIN_S, second
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def test_serve_on_arduplane_replaces_flies_and_survives_a_reboot(sitl_factory_fn, tmp_path: Path) -> None:
    sitl = sitl_factory_fn("plane", HOME, speedup=FAST)
    sitl.hold_serial0()
    asyncio.run(_scenario(tmp_path, sitl))
