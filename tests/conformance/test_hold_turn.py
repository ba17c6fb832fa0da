"""The plane's path where the companion relies on it: a 90° turn at a waypoint (how far the path-follower carries
it past the new leg) and the holds it commands (LOITER around the entry point at WP_LOITER_RAD, and DO_REPOSITION's
circle of a centre and radius of ours). One flight per plane backend: real ArduPlane SITL is the judge, the built-in
simulator must fly the same within the tolerances stated (a difference is a simulator bug).

Mission: take-off to 60 m (north, SITL's runway heading), a waypoint 500 m north, a right turn of 90° there onto a
leg 700 m east. Then LOITER for 40 s of the autopilot's time, then DO_REPOSITION to a centre 250 m south-east of
where the vehicle is, radius 120 m, clockwise, for 60 s.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pymap3d
import pytest
import pytest_asyncio
from conformance.conftest import HOME, home_item, item, numbered, ready, takeoff, waypoint
from pymavlink.dialects.v20 import ardupilotmega as mavlink

pytestmark = pytest.mark.asyncio(loop_scope="module")

ALT = 60.0
SPEED = 20.0  # m/s airspeed (DO_CHANGE_SPEED, as fuseplan's missions set it)
TURN_AT, LEG_EAST = 500.0, 700.0
LOITER_S, CIRCLE_S = 40.0, 60.0
CIRCLE_RADIUS = 120.0
# SITL (plane.parm: WP_LOITER_RAD 80, NAVL1_PERIOD 15, ROLL_LIMIT_DEG 65), measured at 10×: see the assertions.


def change_speed(speed: float):
    return item(mavlink.MAV_CMD_DO_CHANGE_SPEED, located=False, frame=mavlink.MAV_FRAME_MISSION, param1=0.0,
                param2=speed, param3=-1.0)


def _enu(lat: float, lon: float) -> tuple[float, float]:
    e, n, _ = pymap3d.geodetic2enu(lat, lon, 0.0, HOME.lat, HOME.lon, 0.0)
    return float(e), float(n)


async def _track_until(v, sub, until_s: float, out: list) -> None:
    """Append (t, east, north, alt) from GLOBAL_POSITION_INT until the autopilot's clock passes ``until_s``."""
    deadline = time.monotonic() + 120.0
    while time.monotonic() < deadline:
        try:
            m = await sub.get(0.5)
        except TimeoutError:
            continue
        if m.get_type() != "GLOBAL_POSITION_INT":
            continue
        out.append((m.time_boot_ms / 1000.0, *_enu(m.lat / 1e7, m.lon / 1e7), m.relative_alt / 1000.0))
        if out[-1][0] >= until_s:
            return
    raise AssertionError("the autopilot's clock stopped")


async def track_until_east(v, sub, east_m: float, wall_s: float) -> list[tuple[float, float, float, float]]:
    """The track (t, east, north, alt) from now until the vehicle is more than ``east_m`` east of home, or
    ``wall_s`` wall seconds have passed (the caller asserts it got there)."""
    track: list[tuple[float, float, float, float]] = []
    deadline = time.monotonic() + wall_s
    while time.monotonic() < deadline and not (track and track[-1][1] > east_m):
        await _track_until(v, sub, (track[-1][0] if track else 0.0) + 0.5, track)
    return track


@pytest_asyncio.fixture(scope="module", loop_scope="module")
async def flown(backend: str, launch) -> dict[str, float]:
    """The flight, once per backend: what each test asserts on."""
    if not backend.endswith("plane"):
        pytest.skip("a plane's turn and holds (a copter turns on the spot and brakes)")
    async with launch() as v:
        await ready(v)
        items = numbered([home_item(), takeoff(ALT, pitch=10.0), change_speed(SPEED),
                          waypoint(TURN_AT, 0.0, ALT, param2=30.0),
                          waypoint(TURN_AT, LEG_EAST, ALT, param2=30.0),
                          waypoint(TURN_AT - 600.0, LEG_EAST, ALT, param2=30.0)])
        await v.client.upload_verified(items)
        await v.supervisor.wait_ready(60.0)
        with v.link.subscribe("GLOBAL_POSITION_INT", "MISSION_CURRENT") as sub:
            await v.supervisor.start(1)
            # fly until the second leg is current and 500 m east, then LOITER there
            track = await track_until_east(v, sub, 450.0, 120.0)
            assert track and track[-1][1] > 450.0, "never reached the second leg"
            turn = np.array([p for p in track if p[1] > 1.0 and p[2] > TURN_AT - 200.0])
            overshoot = float(turn[:, 2].max() - TURN_AT)  # north of the new leg's line
            settled = turn[turn[:, 1] > 350.0]
            cross = float(np.abs(settled[:, 2] - TURN_AT).max()) if len(settled) else math.nan
            # LOITER at the entry point
            t0, (e0, n0) = track[-1][0], track[-1][1:3]
            await v.supervisor.set_mode("LOITER")
            loiter: list = []
            await _track_until(v, sub, t0 + LOITER_S, loiter)
            late = np.array([p for p in loiter if p[0] >= t0 + 20.0])
            r_loiter = np.hypot(late[:, 1] - e0, late[:, 2] - n0)
            # DO_REPOSITION to a circle of ours
            e1, n1 = loiter[-1][1] + 250.0 * math.sqrt(0.5), loiter[-1][2] - 250.0 * math.sqrt(0.5)
            lat, lon, _ = pymap3d.enu2geodetic(e1, n1, 0.0, HOME.lat, HOME.lon, HOME.alt)
            t1 = loiter[-1][0]
            await v.client.command_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                       -1.0, 1.0, CIRCLE_RADIUS, 0.0, x=round(lat * 1e7), y=round(lon * 1e7), z=ALT)
            circle: list = []
            await _track_until(v, sub, t1 + CIRCLE_S, circle)
            late = np.array([p for p in circle if p[0] >= t1 + 30.0])
            r_circle = np.hypot(late[:, 1] - e1, late[:, 2] - n1)
            ang = np.unwrap(np.arctan2(late[:, 2] - n1, late[:, 1] - e1))
    return {"overshoot": overshoot, "cross": cross, "loiter": float(np.median(r_loiter)),
            "circle": float(np.median(r_circle)), "clockwise": float(ang[-1] < ang[0])}


# measured on ArduPlane SITL at 10× (three runs): 39.2 / 34.0 / 33.7 m past the new leg, back within 2.9 / 1.8 / 1.7 m
# of it; LOITER 96.7 / 96.6 / 97.0 m around its entry point (WP_LOITER_RAD 80: ArduPlane flies its circles wider);
# DO_REPOSITION 135.5 m for a radius of 120 m (all three), clockwise. The simulator (ArduPlane's L1 law, the turn
# SITL's plane achieves: docs/design.md): 37.7 m, back within 3.2 m; LOITER 96.7 m; DO_REPOSITION 132.2 m
async def test_holds_circle_as_arduplane(flown, measure) -> None:
    """LOITER circles where it was entered at WP_LOITER_RAD, DO_REPOSITION our centre at param3; both ~16 m wider."""
    measure(f"LOITER around its entry point: radius {flown['loiter']:.1f} m; DO_REPOSITION circle: radius "
            f"{flown['circle']:.1f} m, {'clockwise' if flown['clockwise'] else 'counter-clockwise'}")
    assert abs(flown["loiter"] - 96.8) <= 6.0
    assert abs(flown["circle"] - 135.5) <= 6.0 and flown["clockwise"]  # param3 + 16 m, clockwise (param4 0)


async def test_a_90_degree_turn_overshoots_as_arduplane(flown, measure) -> None:
    """The path-follower carries the plane past the new leg after a 90° turn at 20 m/s, then settles on it."""
    measure(f"90° turn: {flown['overshoot']:.1f} m past the new leg, back within {flown['cross']:.1f} m of it")
    assert abs(flown["overshoot"] - 35.6) <= 10.0 and flown["cross"] <= 8.0
