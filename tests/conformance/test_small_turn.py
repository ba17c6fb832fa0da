"""How far the plane is carried outside a 21° and a 45° right turn at 18 m/s (acceptance 20 m), on both plane
backends, against what a plan allows for it (VehicleLimits.turn_overshoot: 0.35 of ArduPlane's L1 distance per
radian, docs/design.md "Turns flown wider than planned"). Measured (4 December): ArduPlane SITL 6.0 m and 14.1 m
outside the new leg; the simulator (ArduPlane's L1 law, SITL's turn) 7.4 m and 16.4 m; allowed 8.3 m and 17.7 m."""
from __future__ import annotations

import math

import numpy as np
import pytest
from conformance.conftest import home_item, numbered, ready, takeoff, waypoint
from conformance.test_hold_turn import _track_until, change_speed

from companion.mavlink.vehicle_limits import l1_overshoot
from companion.sim.flight_model import PLANE_L1_PERIOD_S  # SITL's NAVL1_PERIOD (plane.parm), flown by both

pytestmark = pytest.mark.asyncio(loop_scope="module")
ALT = 60.0


@pytest.mark.parametrize("turn_deg", [21.0, 45.0])
async def test_a_small_turn_swings_outside_no_further_than_plans_allow(backend, launch, measure, turn_deg) -> None:
    """The plane crosses the new leg to the outside of the turn (a path-follower, not the Bézier), by less than the
    plan's allowance for that turn and by more than half of it (a simulator that turned onto the leg would fail)."""
    if not backend.endswith("plane"):
        pytest.skip("plane")
    a = math.radians(turn_deg)
    c = (500.0, 0.0)
    end = (c[0] + 700.0 * math.cos(a), c[1] + 700.0 * math.sin(a))  # north, east: turning right by turn_deg
    async with launch() as v:
        await ready(v)
        items = numbered([home_item(), takeoff(ALT, pitch=10.0), change_speed(18.0),
                          waypoint(c[0], c[1], ALT, param2=20.0), waypoint(end[0], end[1], ALT, param2=20.0),
                          waypoint(end[0] + 300, end[1], ALT, param2=20.0)])
        await v.client.upload_verified(items)
        await v.supervisor.wait_ready(60.0)
        with v.link.subscribe("GLOBAL_POSITION_INT", "MISSION_CURRENT") as sub:
            await v.supervisor.start(1)
            track: list = []
            t = 0.0
            while not (track and track[-1][2] > c[0] + 400.0 * math.cos(a)):
                await _track_until(v, sub, t + 0.5, track)
                t = track[-1][0]
    tr = np.array(track)  # t, east, north, alt
    ux, uy = math.sin(a), math.cos(a)  # leg 2 direction (east, north)
    rel_e, rel_n = tr[:, 1] - c[1], tr[:, 2] - c[0]
    along = rel_e * ux + rel_n * uy
    cross = rel_e * uy - rel_n * ux  # + = right of leg 2 (outside of a right turn is left: negative)
    after = (along > 0) & (along < 400)
    measure(f"{turn_deg:g} deg right turn at 18 m/s: cross-track after the corner min {cross[after].min():.1f} "
            f"max {cross[after].max():.1f} m (left/outside negative)")
    swing = -float(cross[after].min())
    allowed = l1_overshoot(18.0, PLANE_L1_PERIOD_S) * a
    measure(f"… allowed {allowed:.1f} m")
    assert 0.5 * allowed < swing <= allowed
