"""Scripted intruders timed by the vehicle's real progress (``meet``), and their ADS-B reports."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from companion.sim.intruders import JOIN_M, PACE_WINDOW_S, SETTLE_S, SPEED_RANGE, IntruderTrack, adsb_report
from planner.errors import ScenarioError
from planner.world.home import Home
from planner.world.scenario import Intruder, load_scenario

ROUTE = np.array([[0.0, 0.0, 100.0], [1000.0, 0.0, 100.0]])  # due east along y = 0
# crosses the route at (600, 0) heading north: 300 m from its first waypoint
CROSSER = Intruder("x", 0xABCDEF, ((600.0, -300.0, 100.0), (600.0, 300.0, 100.0)), 15.0, meet=(600.0, 0.0, 100.0))


def _fly(track: IntruderTrack, start_x: float, speed: float, t_end: float, off_y: float = 0.0,
         dt: float = 0.1) -> list[tuple[float, np.ndarray]]:
    """A vehicle along the route from ``start_x`` at ``speed``, ``off_y`` off it; feeds the track."""
    flown = []
    for t in np.arange(0.0, t_end, dt):
        p = np.array([start_x + speed * t, off_y, 100.0])
        track.follow(float(t), p)
        flown.append((float(t), p))
    return flown


def _miss(track: IntruderTrack, flown) -> float:
    """Closest distance between the vehicle and the intruder."""
    d = [np.linalg.norm(p - [s.x, s.y, s.z]) for t, p in flown if (s := track.sample(t)) is not None]
    return float(min(d))


@pytest.mark.parametrize("pace", [10.0, 16.0, 20.0, 24.0], ids=["copter", "slower", "cruise", "faster"])
def test_a_meet_intruder_arrives_with_the_vehicle_whatever_its_pace(pace: float) -> None:
    track = IntruderTrack(CROSSER, ROUTE)
    flown = _fly(track, 0.0, pace, 60.0)
    arrival = 600.0 / pace
    assert track.start_time is not None
    # it takes off at the vehicle's arrival minus its own flight time at the speed it chose (nominal if it could)
    assert track.start_time + 300.0 / track.speed == pytest.approx(arrival, abs=0.2)
    assert _miss(track, flown) < 5.0  # it really meets the vehicle


def test_a_fixed_start_intruder_ignores_the_vehicle() -> None:
    fixed = Intruder("f", 1, ((600.0, -300.0, 100.0), (600.0, 300.0, 100.0)), 15.0, start_time=3.0)
    track = IntruderTrack(fixed)
    _fly(track, 0.0, 24.0, 10.0)
    assert track.start_time == 3.0 and track.speed == 15.0
    s = track.sample(3.0 + 10.0)
    assert (s.x, s.y) == pytest.approx((600.0, -150.0)) and s.vy == pytest.approx(15.0)


def test_it_waits_until_the_vehicle_has_joined_the_route() -> None:
    """During the climb-out (off the route) nothing is scheduled: the arrival estimate would be a guess."""
    track = IntruderTrack(CROSSER, ROUTE)
    _fly(track, 0.0, 20.0, 5.0, off_y=JOIN_M + 50.0)
    assert track.waiting and track.sample(4.9) is None


def test_late_join_speeds_it_up_within_its_range_and_then_it_flies_straight_on() -> None:
    """Joining 300 m before the meeting point at 20 m/s: once its pace is known (8 s, 160 m on) 7 s are left, and
    300 m in 7 s needs 43 m/s, capped at twice its 15 m/s."""
    track = IntruderTrack(CROSSER, ROUTE)
    _fly(track, 300.0, 20.0, 9.0)
    assert track.start_time == pytest.approx(SETTLE_S + PACE_WINDOW_S)
    assert track.speed == pytest.approx(SPEED_RANGE[1] * 15.0)
    speed = track.speed
    _fly(track, 0.0, 5.0, 30.0)  # whatever the vehicle does next, the intruder keeps its speed
    assert track.speed == speed


def test_leaving_the_route_starts_the_pace_again() -> None:
    """A plane overshooting the route start and turning back: its pace counts only once it is back on it."""
    track = IntruderTrack(CROSSER, ROUTE)
    _fly(track, 0.0, 20.0, 5.0)  # on the route, not long enough
    _fly(track, 0.0, 20.0, 2.0, off_y=JOIN_M + 10.0)  # off it
    assert track.waiting and not track._pace


@pytest.mark.parametrize("decel", [math.inf, 2.5], ids=["stops", "brakes"])
def test_a_vehicle_that_stops_on_the_route_keeps_its_appointment(decel: float) -> None:
    """A copter braking to hold on its route (at once, or at ArduCopter's 2.5 m/s²): the intruder still takes off
    when the vehicle, flying on at its pace, would have met it (the copters' crossing_traffic flights never saw
    their second intruder)."""
    track = IntruderTrack(CROSSER, ROUTE)
    x, v, dt = 0.0, 20.0, 0.1
    for t in np.arange(0.0, 40.0, dt):  # just settled on the route at 9 s, 180 m along, then hovering
        if t >= 9.0:
            v = max(v - decel * dt, 0.0)
        x += v * dt
        track.follow(float(t), np.array([x, 0.0, 100.0]))
    assert track.start_time is not None  # it took off while the vehicle held
    assert track.start_time + 300.0 / track.speed == pytest.approx(600.0 / 20.0, abs=1.5)


def test_meet_needs_the_route() -> None:
    with pytest.raises(ValueError, match="route"):
        IntruderTrack(CROSSER)


def test_adsb_report_carries_position_velocity_and_identity() -> None:
    home = Home(-35.363261, 149.165230, 584.0)
    track = IntruderTrack(Intruder("abc", 0xC0FFEE, ((0.0, 0.0, 120.0), (0.0, 1000.0, 120.0)), 15.0))
    msg = adsb_report(track.intruder, track.sample(10.0), home)
    assert msg.ICAO_address == 0xC0FFEE and msg.callsign.rstrip("\x00") == "abc"
    assert msg.altitude == round((584.0 + 120.0) * 1000) and msg.hor_velocity == 1500 and msg.heading == 0
    assert msg.lat / 1e7 == pytest.approx(home.lat + 150.0 / 111_000, abs=2e-5)  # 150 m north
    assert math.isclose(msg.lon / 1e7, home.lon, abs_tol=1e-6)


SCENARIO = Path(__file__).resolve().parents[3] / "sitl_scenarios" / "rescue_dynamic.toml"


def _without_start_time(tmp_path: Path, meet: str) -> Path:
    text = re.sub(r"^start_time = .*$", "", SCENARIO.read_text(), count=1, flags=re.M)
    path = tmp_path / "case.toml"
    text = re.sub(r"^meet = .*$", "", text, flags=re.M)
    path.write_text(text.replace("[[intruders]]", f"[[intruders]]\nmeet = {meet}", 1))
    return path


def test_scenario_meet_must_lie_on_the_path(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"intruders\[0\]\.meet.*must lie on the intruder's path"):
        load_scenario(_without_start_time(tmp_path, "[500.0, 500.0, 999.0]"))
    (intruder,) = load_scenario(_without_start_time(tmp_path, "[600.0, 600.0, 120.0]")).intruders
    assert intruder.meet == (600.0, 600.0, 120.0)


def test_scenario_meet_and_start_time_exclude_each_other() -> None:
    with pytest.raises(ScenarioError, match=r"intruders\[0\]\.start_time.*not both"):
        load_scenario(SCENARIO, ["intruders[0].meet=[600.0, 600.0, 120.0]", "intruders[0].start_time=5.0"])
