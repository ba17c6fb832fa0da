"""How far PX4's fixed-wing path-follower (NPFG) carries the SIH standard VTOL past a new leg after a turn, against
what the companion assumes of it (AutopilotLimits.turn_overshoot, from NPFG_PERIOD as read).

Mission: VTOL take-off, a leg 600 m north, then turns of 90° (right), 45° (left), 135° (right) and 60° (left), each
new leg 500 m, at the airframe's 10 m/s trim airspeed, fixed-wing; VTOL landing.
"""

from __future__ import annotations

import asyncio
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from px4_harness import FAST

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.link import Link
from companion.mavlink.params import read_params
from companion.mavlink.protocol import MissionClient
from companion.mavlink.vehicle_limits import limits_from, parameter_names
from companion.mission.builder import MissionSpec, build_mission
from companion.mission.events import EventLog
from companion.mission.geo import geodetic_to_enu
from planner.world.scenario import load_scenario

SC = load_scenario(Path(__file__).resolve().parents[2] / "sitl_scenarios" / "rescue_static.toml")
VTOL_MODEL = "sihsim_standard_vtol"  # airframe 10043
TURNS_DEG = (90.0, 45.0, 135.0, 60.0)  # right, left, right, left
ALT, FIRST_LEG, LEG = 80.0, 600.0, 500.0


def _route() -> np.ndarray:
    pts, h = [np.array([0.0, 0.0, ALT]), np.array([0.0, FIRST_LEG, ALT])], 0.0
    for k, turn in enumerate(TURNS_DEG):
        h += math.radians(turn) * (1 if k % 2 == 0 else -1)
        pts.append(pts[-1] + LEG * np.array([math.sin(h), math.cos(h), 0.0]))
    return np.array(pts)


def swings(route: np.ndarray, xy: np.ndarray) -> list[tuple[float, float]]:
    """(turn in rad, metres flown past the new leg on the outside of the turn) at each corner of ``route``, from the
    track ``xy`` between the legs' midpoints."""
    out = []
    for k in range(1, len(route) - 1):
        a, b, c = route[k - 1, :2], route[k, :2], route[k + 1, :2]
        inn, u = (b - a) / np.linalg.norm(b - a), (c - b) / np.linalg.norm(c - b)
        left = inn[0] * u[1] - inn[1] * u[0] > 0
        outside = np.array([u[1], -u[0]]) if left else np.array([-u[1], u[0]])
        i0 = int(np.argmin(np.linalg.norm(xy - (a + b) / 2, axis=1)))
        i1 = int(np.argmin(np.linalg.norm(xy - (b + c) / 2, axis=1)))
        seg = xy[i0:i1 + 1]
        after = seg[(seg - b) @ u > 0]
        out.append((math.acos(float(np.clip(np.dot(inn, u), -1.0, 1.0))), float(((after - b) @ outside).max())))
    return out


async def _fly(url: str) -> tuple[np.ndarray, dict[str, float]]:
    vehicle = replace(SC.vehicle, cruise_speed=10.0, end_action="land")
    items = build_mission(_route(), MissionSpec("px4-vtol", vehicle, SC.home))
    async with Link(url) as link:
        await link.wait_heartbeat(30.0)
        params = await read_params(link, parameter_names("px4-vtol", "plane"))
        out = await FlightSupervisor(link, MissionClient(link), EventLog(), arm=True, home=SC.home).fly(
            items, ready_timeout=90.0, flight_timeout=300.0)
    assert out.completed, out.reason
    home = SC.home
    xy = np.array([geodetic_to_enu(lat, lon, home.alt + alt, home)[:2] for _t, lat, lon, alt in out.track])
    return xy, params


def test_px4_swings_past_a_new_leg_no_further_than_the_companion_assumes(px4_factory_fn) -> None:
    px4 = px4_factory_fn(SC.home, speedup=FAST, model=VTOL_MODEL)
    xy, params = asyncio.run(_fly(px4.companion_url))
    limits = limits_from(params, "px4-vtol", replace(SC.vehicle, cruise_speed=10.0), 80.0)
    assume = limits.turn_overshoot(10.0)  # m per radian at the mission's speed
    measured = swings(_route(), xy)
    print(f"NPFG_PERIOD {limits.npfg_period_s:g} s: assumed {assume:.1f} m/rad; flown "
          + ", ".join(f"{math.degrees(t):.0f}° {s:.1f} m ({s / t:.1f} m/rad)" for t, s in measured))
    assert "NPFG_PERIOD" in limits.read
    for turn, swing in measured:
        assert swing <= assume * turn, (math.degrees(turn), swing, assume)
    # and the assumption is not loose beyond use: the widest swing per radian is at least half of it
    assert max(s / t for t, s in measured) >= 0.5 * assume
