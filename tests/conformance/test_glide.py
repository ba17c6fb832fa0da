"""A plane's altitude along its legs, and what happens to its active item when the mission is rewritten under it:
both decide whether a replanned route is flown where it was checked. One flight per plane backend; real ArduPlane
SITL is the judge, the built-in simulator must fly the same within the tolerances stated.

Mission: take-off to 60 m (north), a waypoint 300 m north at 60 m, one 1300 m north at 160 m (a 100 m climb over
1 km), one 2300 m north at 60 m (the same descent), one 800 m east of it. While that last leg is flown, item 6 is
rewritten to a point 600 m further south; 5 s later DO_SET_MISSION_CURRENT 6.
"""

from __future__ import annotations

import numpy as np
import pytest
import pytest_asyncio
from conformance.conftest import home_item, numbered, ready, takeoff, waypoint
from conformance.test_hold_turn import _track_until, change_speed, track_until_east

pytestmark = pytest.mark.asyncio(loop_scope="module")

ALT, HIGH = 60.0, 160.0
SPEED = 20.0
START, TOP, BOTTOM, EAST = 300.0, 1300.0, 2300.0, 800.0
MOVED_SOUTH = 600.0  # item 6 rewritten this far south of where it was
KEEP_S = 5.0  # autopilot seconds flown after the rewrite before the item is restarted


def _mission(last_north: float) -> list:
    return numbered([home_item(), takeoff(ALT, pitch=10.0), change_speed(SPEED),
                     waypoint(START, 0.0, ALT, param2=30.0), waypoint(TOP, 0.0, HIGH, param2=30.0),
                     waypoint(BOTTOM, 0.0, ALT, param2=30.0), waypoint(last_north, EAST, ALT, param2=30.0)])


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def flown(backend: str, launch) -> dict[str, float]:
    if not backend.endswith("plane"):
        pytest.skip("a plane's glide slope and its copy of the active item (ArduCopter re-reads a changed item)")
    async with launch() as v:
        await ready(v)
        await v.client.upload_verified(_mission(BOTTOM))
        await v.supervisor.wait_ready(60.0)
        with v.link.subscribe("GLOBAL_POSITION_INT", "MISSION_CURRENT") as sub:
            await v.supervisor.start(1)
            track = await track_until_east(v, sub, 200.0, 180.0)  # on the last leg
            assert track and track[-1][1] > 200.0, "never reached the last leg"
            legs = np.array(track)

            def alt_at(north: float) -> float:
                up = legs[(legs[:, 1] < 100.0) & (np.abs(legs[:, 2] - north) < 30.0)]
                return float(np.median(up[:, 3]))

            # rewrite the active item (6: the leg east), keep flying, then restart it
            t0, north0 = track[-1][0], track[-1][2]
            await v.client.upload_verified(_mission(BOTTOM - MOVED_SOUTH))
            kept: list = []
            await _track_until(v, sub, t0 + KEEP_S, kept)
            await v.client.set_current(6)
            restarted: list = []
            await _track_until(v, sub, kept[-1][0] + 15.0, restarted)
    return {"climb_mid": alt_at(0.5 * (START + TOP)), "descent_mid": alt_at(0.5 * (TOP + BOTTOM)),
            "kept_south": north0 - min(p[2] for p in kept), "restarted_south": kept[-1][2] - restarted[-1][2]}


async def test_a_plane_glides_between_waypoint_altitudes(flown, measure) -> None:
    """ArduPlane above 20 m interpolates its altitude target along the leg (its glide slope) instead of climbing or
    sinking to the next waypoint's altitude at once: the leg as planned, not a steeper path under or over it."""
    measure(f"mid-leg altitude: climbing 60->160 m {flown['climb_mid']:.1f} m, descending 160->60 m "
            f"{flown['descent_mid']:.1f} m (on the leg: 110 m)")
    mid = 0.5 * (ALT + HIGH)
    assert abs(flown["climb_mid"] - mid) <= 15.0
    assert abs(flown["descent_mid"] - mid) <= 15.0


async def test_a_rewritten_active_item_is_flown_from_its_old_copy_until_restarted(flown, measure) -> None:
    """An upload that replaces the item being flown changes nothing until that item is restarted (the replanner
    restarts it with DO_SET_MISSION_CURRENT of the same item): then the vehicle turns for the new one."""
    measure(f"rewritten item 6 ({MOVED_SOUTH:g} m south): {flown['kept_south']:.1f} m south in {KEEP_S:g} s before "
            f"the restart, {flown['restarted_south']:.1f} m south in 15 s after it")
    assert flown["kept_south"] <= 15.0
    assert flown["restarted_south"] >= 60.0
