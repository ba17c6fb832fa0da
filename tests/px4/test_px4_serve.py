"""Issue 36 on PX4 SITL (SIH quadrotor): ``fuseplan serve`` on the API/offboard link (in this process) beside a
ground-station script on PX4's GCS link. The script uploads a fence (issue 35's operator course; PX4 enforces it at
once) and a two-item mission (takeoff, goal); within 5 s the vehicle's mission is the verified safe route and the
script has the companion's STATUSTEXT saying so (PX4 forwards it: both links run with forwarding, -f). The script
arms and starts; the service supervises the flight to the goal. PX4 is then power-cycled (PX4 SITL denies the reboot
command; a fresh PX4 on the same ports); the service reconnects and handles a second upload (mission replaced,
STATUSTEXT). This covers tests/px4/test_px4_operator_world_flight.py's flight (the fence and goal read from the
vehicle, planned round, flown safe) and its track-by-zone check (the same independent check of the flown track
against each zone)."""

from __future__ import annotations

import asyncio
import contextlib
import time
from pathlib import Path

from operator_course import D_COLL, base_scenario, fence_items
from px4_harness import FAST
from serve_gcs import GroundStation, flown_round_the_zones, replaced, two_item_mission, write_config

from companion.service import Service, load_config
from planner.world.home import Home

HOME = Home(-35.363261, 149.165230, 584.0)
REPLACED_WITHIN_S = 5.0


async def _scenario(tmp_path: Path, px4: object) -> None:
    base = base_scenario(tmp_path / "base.toml", HOME, "copter", 10.0)
    cfg = load_config(write_config(tmp_path / "serve.toml", px4.companion_url, base, tmp_path / "logs"))
    service = Service(cfg)
    task = asyncio.create_task(service.run())
    try:
        async with GroundStation(f"udpout:127.0.0.1:{px4.gcs_port}") as gcs:
            await gcs.link.wait_heartbeat(30.0)
            while service.seen is None:
                await asyncio.sleep(0.05)
            first = await replaced(gcs, service, two_item_mission(HOME, False, 1180.0, 720.0),
                                   fence_items(HOME), False)
            assert first["replaced_s"] < REPLACED_WITHIN_S and first["told_s"] < REPLACED_WITHIN_S, first

            t0 = time.monotonic()
            await gcs.arm_and_start()
            handled = service.handled[-1]
            while handled.flight is None:
                assert time.monotonic() - t0 < 300.0, "the flight was not over within 300 s"
                await asyncio.sleep(0.2)
            flight = handled.flight
            print(f"flight {time.monotonic() - t0:.1f} s: completed {flight['completed']} ({flight['reason']}), "
                  f"clearance {flight['min_static_clearance_m']:.1f} m")
            assert flight["completed"] and flight["flown_safe"], flight
            assert flight["min_static_clearance_m"] >= D_COLL
            flown_round_the_zones(handled.report, 100.0)

            connections = service.connections
            t_restart = time.monotonic()
            up = await asyncio.to_thread(px4.restart)
            while service.connections == connections:
                assert time.monotonic() - t_restart < 90.0, "the service did not reconnect within 90 s"
                await asyncio.sleep(0.1)
            print(f"PX4 up again {up:.1f} s, the service reconnected {time.monotonic() - t_restart:.1f} s after the "
                  "restart began")
            assert await gcs.link.wait_back(30.0)
            second = await replaced(gcs, service, two_item_mission(HOME, False, 1000.0, 800.0),
                                   fence_items(HOME), False)
            assert second["replaced_s"] < REPLACED_WITHIN_S, second
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task


def test_serve_on_px4_replaces_flies_and_survives_a_restart(px4_factory_fn, tmp_path: Path) -> None:
    px4 = px4_factory_fn(HOME, speedup=FAST)
    asyncio.run(_scenario(tmp_path, px4))
