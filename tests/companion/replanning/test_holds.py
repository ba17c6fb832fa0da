"""Hold patterns checked like routes: a plane's circle of our choosing clear of the obstacles and the traffic, where
ArduPlane's LOITER around its entry point would not be."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.replanning.holds import (
    EXIT_TURN_DEG,
    FLOWN_WIDER_M,
    HOLD_MARGIN_M,
    TIGHT_HOLD_MARGIN_M,
    arc_to,
    circle_exit,
    circle_traffic_separation,
    copter_hold,
    plane_hold,
)
from planner.trajectory.checks import obstacle_distances
from planner.world.environment import Cylinders, Environment, Threat, Threats
from planner.world.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
SC = load_scenario(ROOT / "sitl_scenarios" / "rescue_dynamic.toml")
ENV, D_COLL = SC.environment, SC.hazard.d_coll


def _ring(centre, radius) -> np.ndarray:
    a = np.linspace(0, 2 * math.pi, 361)
    return np.stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a), np.full(a.size, 60.0)], axis=1)


def _clearance(points) -> float:
    return min(float(v.min()) for v in obstacle_distances(points, ENV).values())


def test_where_loiter_at_the_entry_point_runs_into_a_cylinder_the_chosen_circle_clears_it() -> None:
    """The SITL flight: the plane 60 m from cylinders[3], flying north; LOITER's 80 m circle around it breaks in."""
    here = np.array([252.0, 202.0, 60.0])
    assert _clearance(_ring(here, 80.0)) < 0  # ArduPlane's LOITER: the circle runs into the cylinder
    hold = plane_hold(here, np.array([0.0, 20.0]), 80.0, ENV, D_COLL, 20.0)
    assert hold is not None and hold.kind == "circle" and hold.radius == 80.0
    assert hold.clearance_m >= D_COLL + HOLD_MARGIN_M
    # the whole circle, independently, as asked and as ArduPlane flies it (wider)
    assert _clearance(_ring(hold.centre, 80.0)) >= D_COLL + HOLD_MARGIN_M
    assert _clearance(_ring(hold.centre, 80.0 + FLOWN_WIDER_M)) >= D_COLL + HOLD_MARGIN_M
    assert np.allclose(hold.path[0], here)  # the approach from the vehicle is part of what was checked
    # tangent to its track (here or further along it): the vehicle turns straight onto it, never back across
    assert abs(abs(hold.centre[0] - here[0]) - 80.0) < 1e-6 and hold.centre[1] >= here[1]


def test_a_circle_that_traffic_will_cross_is_not_chosen() -> None:
    here = np.array([200.0, 500.0, 100.0])
    free = plane_hold(here, np.array([0.0, 20.0]), 80.0, ENV, D_COLL, 20.0)
    assert free is not None
    # an intruder parked on that circle, half way round, for the next minute
    spot = tuple(float(v) for v in free.path[-len(free.path) // 2])
    parked = Threats((Threat("parked", "track", 40.0, spot, (0.0, 0.0, 0.0)),))
    other = plane_hold(here, np.array([0.0, 20.0]), 80.0, ENV, D_COLL, 20.0, parked, 0.0)
    assert other is None or (np.linalg.norm(other.centre - free.centre) > 1.0 and
                             other.traffic_separation_m >= D_COLL)


def test_traffic_is_checked_on_the_circle_as_flown_and_kept_beyond_the_margin_where_a_circle_allows() -> None:
    """An intruder parked just outside the circle asked (by d_coll + 5 m) is inside the ring ArduPlane flies
    (16-20 m wider): that circle is not taken while another keeps the margin."""
    here = np.array([200.0, 500.0, 100.0])
    free = plane_hold(here, np.array([0.0, 20.0]), 80.0, ENV, D_COLL, 20.0)
    assert free is not None
    outward = free.path[-len(free.path) // 2] - free.centre
    outward[2] = 0.0
    spot = free.centre + outward / np.linalg.norm(outward) * (80.0 + 40.0 + D_COLL + 5.0)
    parked = Threats((Threat("parked", "track", 40.0, tuple(float(v) for v in spot), (0.0, 0.0, 0.0)),))
    on_asked = float(np.min(np.linalg.norm(_ring(free.centre, 80.0)[:, :2] - spot[:2], axis=1))) - 40.0
    assert on_asked >= D_COLL  # the circle asked alone would pass
    sep = circle_traffic_separation(here, free.centre, 80.0, free.clockwise, 20.0, 0.0, parked)
    assert sep < D_COLL  # the ring flown does not
    other = plane_hold(here, np.array([0.0, 20.0]), 80.0, ENV, D_COLL, 20.0, parked, 0.0)
    assert other is not None and np.linalg.norm(other.centre - free.centre) > 1.0
    assert other.traffic_separation_m >= D_COLL + HOLD_MARGIN_M
    # recomputed independently on both rings of the circle chosen
    for r in (80.0, 80.0 + FLOWN_WIDER_M):
        assert float(np.min(np.linalg.norm(_ring(other.centre, r)[:, :2] - spot[:2], axis=1))) - 40.0 >= D_COLL


def test_no_room_anywhere_gives_no_circle() -> None:
    """Between cylinders[4] and [5] (a 56 m gap) no 80 m circle fits: the caller keeps the cleared leg."""
    here = np.array([680.0, 652.0, 150.0])
    assert plane_hold(here, np.array([0.0, 1.0]), 400.0, ENV, D_COLL, 20.0) is None


def test_a_copters_stopping_run_is_checked() -> None:
    at = np.array([260.0, 200.0, 60.0])  # 20 m west of cylinders[3], flying east at 10 m/s
    stop = copter_hold(at, np.array([10.0, 0.0]), 20.0, ENV, D_COLL)
    assert stop.kind == "brake" and np.allclose(stop.centre, (280.0, 200.0, 60.0))
    assert stop.clearance_m == 0.0 and stop.nearest_obstacle == "cylinders[3]"


def test_the_guard_predicts_a_breach_ahead_and_not_on_a_clear_turn() -> None:
    from companion.replanning.guard import first_breach, predict_own_path

    # flying east at 20 m/s at y = 200 towards cylinders[3] (x 350, r 70), its next item inside the cylinder
    path = predict_own_path(np.array([200.0, 200.0, 60.0]), np.array([20.0, 0.0]), np.array([150.0, 200.0, 60.0]),
                            np.array([[350.0, 200.0, 60.0]]), 33.0, 20.0)
    assert abs(path[-1, 1] - 320.0) < 1.0 and np.allclose(path[:, 3], 60.0)  # 6 s at 20 m/s along the leg
    breach = first_breach(path, ENV, D_COLL)
    assert breach is not None and breach.obstacle == "cylinders[3]" and 0 < breach.in_s < 6.0
    # the same vehicle turning north at (200, 200) towards (200, 400): west of every cylinder, no breach
    turn = predict_own_path(np.array([180.0, 200.0, 60.0]), np.array([20.0, 0.0]), np.array([100.0, 200.0, 60.0]),
                            np.array([[200.0, 200.0, 60.0], [200.0, 400.0, 60.0]]), 33.0, 20.0)
    assert first_breach(turn, ENV, D_COLL) is None
    assert turn[-1, 2] > 250.0 and turn[:, 1].max() < 200.0 + 2 * 33.0  # round the corner, no wider than a turn


def test_a_plane_resumed_with_its_item_behind_flies_at_it_from_where_its_turn_ends() -> None:
    """ArduPlane SITL resumed from a hold at (398, 954) heading 288° at 23.5 m/s, its item (800, 800) behind it: it
    turned round to the left at 58 m and flew straight at the item from there, 22.7 m into cylinders[5] of
    rescue_dynamic (x 650, y 750, r 80). The check that let it go held to the line from where it was, at the L1
    bound's 37 m: 20.3 m clear. Flown straight at the item from where the turn ends (``direct``), that turn
    breaches; the other way round it would have cleared."""
    from companion.replanning.guard import predict_own_path

    pos = np.array([398.3, 953.7, 116.2])
    h = math.radians(288.0)
    vel = 23.5 * np.array([math.sin(h), math.cos(h)])
    item = np.array([[800.0, 800.0, 150.0]])

    def clearance(path: np.ndarray) -> float:
        return float((np.hypot(path[:, 1] - 650.0, path[:, 2] - 750.0) - 80.0).min())

    held_to_line = predict_own_path(pos, vel, pos, item, 37.4, 50.0, horizon_s=30.0)
    assert clearance(held_to_line) > D_COLL + 10.0  # what passed the old check
    left = predict_own_path(pos, vel, pos, item, 1.6 * 37.4, 50.0, horizon_s=30.0, direct=True, sense=-1)
    assert clearance(left) < 0.0  # as SITL flew it (-22.7 m)
    assert clearance(predict_own_path(pos, vel, pos, item, 37.4, 50.0, horizon_s=30.0, direct=True)) < D_COLL
    right = predict_own_path(pos, vel, pos, item, 1.6 * 37.4, 50.0, horizon_s=30.0, direct=True, sense=1)
    assert clearance(right) > D_COLL + 10.0 and right[1:40, 1].max() > pos[0]  # round to the right: north, clear
    assert np.hypot(right[:, 1] - 800.0, right[:, 2] - 800.0).min() < 10.0  # and on to the item


def test_a_resume_takes_its_item_as_early_as_arduplane_does() -> None:
    """ArduPlane SITL resumed 101 m from its item (401, 353) heading 50° at 23 m/s counted it reached early and cut
    to the next leg 6.5 m from cylinders[0] of crossing_traffic (x 480, y 480, r 90). Predicted taking the item at
    the scenario's 20 m, the path cleared by 20.3 m; at ArduPlane's early switch (65 m) and the wider turn it
    comes 9.5 m, inside d_coll + the hold margin."""
    from companion.mavlink.profiles import PLANE_EARLY_SWITCH_M
    from companion.replanning.guard import predict_own_path

    route = np.array([[401.5, 353.1, 119.2], [542.3, 380.0, 127.6], [612.7, 418.2, 129.8], [729.7, 489.2, 134.9]])
    pos = np.array([316.6, 407.3, 104.6])
    h = math.radians(49.9)
    vel = 23.0 * np.array([math.sin(h), math.cos(h)])

    def clearance(accept: float, radius: float) -> float:
        path = predict_own_path(pos, vel, pos, route, radius, accept, horizon_s=20.0, direct=True)
        return float((np.hypot(path[:, 1] - 480.0, path[:, 2] - 480.0) - 90.0).min())

    assert clearance(20.0, 36.6) > 20.0 and clearance(20.0, 1.6 * 36.6) > 20.0  # what let it go
    assert clearance(PLANE_EARLY_SWITCH_M, 1.6 * 36.6) < 10.0  # what it flew: 6.5 m


def test_a_planes_height_lags_its_demand_as_arduplane_sitl_flew_it() -> None:
    """ArduPlane SITL (rescue_dynamic, without replanning, the same in 10 of 10 flights) flew the leg from item 6
    (283, 498, 84.1) to item 7 (396, 660, 108.9) from (280, 501, 80.9) at 19.2 m/s, climbing 1.4 m/s, and switched
    to item 8 9.5 s later at 98.0-101.3 m (this flight: 99.3 m). Reaching each item's altitude on arrival at once,
    the path is 106.4 m there; with TECS's lag and climb limit (TECS_LAG_S, TECS_CLMB_MAX 5 m/s) 101.5 m."""
    from companion.replanning.guard import predict_own_path
    from companion.replanning.motion import TECS_LAG_S

    pos, vel = np.array([280.2, 501.1, 80.9]), np.array([9.04, 16.94])
    items = np.array([[396.0, 660.4, 108.9], [490.8, 759.9, 126.2]])
    origin = np.array([283.2, 497.5, 84.1])

    def height_at_switch(**height: float) -> float:
        path = predict_own_path(pos, vel, origin, items, 40.0, 50.0, horizon_s=10.0, dt=0.25, **height)
        return float(path[round(9.49 / 0.25), 3])

    flown = 99.3
    assert height_at_switch() - flown > 5.0  # what the checks predicted: 7 m too high
    lagged = height_at_switch(climb_rate=5.0, sink_rate=5.0, height_lag_s=TECS_LAG_S, climbing=1.39)
    assert abs(lagged - flown) < 3.0, lagged
    # the limit alone: a climb of 2.5 m/s demanded never reaches 5 m/s, so it is the lag that matters
    assert height_at_switch(climb_rate=5.0, sink_rate=5.0) - flown > 5.0


def test_a_hold_circle_is_checked_with_the_turn_onto_it_begun_late_and_wide() -> None:
    """ArduPlane SITL at (594, 837) heading 93.5° at 23.8 m/s was held on the 50 m circle tangent to its track on
    the right (centre (591, 787), clear of crossing_traffic's cylinders[3] by 27.9 m): it flew on straight ~2 s,
    turned at ~60 m and came 3.0 m from that cylinder. With the late, wide turn onto it checked, that circle is
    refused."""
    sc = load_scenario(ROOT / "sitl_scenarios" / "crossing_traffic.toml")
    env = sc.environment
    p = np.array([594.1, 836.7, 154.4])
    h = math.radians(93.5)
    v = 23.8 * np.array([math.sin(h), math.cos(h)])
    asked = plane_hold(p, v, 50.0, env, sc.hazard.d_coll, 23.8)
    assert asked is not None and asked.clockwise and np.allclose(asked.centre[:2], [591.0, 786.8], atol=0.5)
    checked = plane_hold(p, v, 50.0, env, sc.hazard.d_coll, 23.8, turn_radius=60.6, lag_m=2.5 * 23.8)
    assert checked is None or not np.allclose(checked.centre[:2], asked.centre[:2], atol=1.0)


def test_a_turn_flown_wide_with_its_item_taken_late_is_one_of_the_paths_checked() -> None:
    """A replan from ArduPlane SITL's plane at the commit point (684, 882), flying 64.5° at 23.3 m/s, turned right
    onto (745, 829) and on east along y ~ 825; the plane overshot the turn and flew 5.0 m into crossing_traffic's
    cylinders[3] (x 780, y 700, r 110). The path at the L1 bound (36.6 m) cleared it by 14.4 m and was let through;
    turning 1.6 times as wide with the item taken at its 20 m, it breaches, as flown."""
    from companion.replanning.guard import predict_own_path

    route = np.array([[684.1, 881.6, 83.0], [745.2, 828.8, 87.7], [834.2, 822.4, 87.4], [902.8, 801.5, 90.1],
                      [995.1, 803.4, 102.4]])
    h = math.radians(64.5)
    vel = 23.3 * np.array([math.sin(h), math.cos(h)])

    def clearance(radius: float, accept: float) -> float:
        path = predict_own_path(route[0], vel, route[0], route[1:], radius, accept, horizon_s=20.0)
        return float((np.hypot(path[:, 1] - 780.0, path[:, 2] - 700.0) - 110.0).min())

    assert clearance(36.6, 20.0) > 10.0
    assert clearance(1.6 * 36.6, 20.0) < 10.0


def _walls(gap: float) -> Environment:
    """Two rows of 30 m cylinders either side of a plane flying north up x = 500: its 80 m circles, flown 20 m
    wider, clear them by ``gap``."""
    ys = np.arange(0.0, 1001.0, 40.0)
    xs = [500.0 + s * (80.0 + FLOWN_WIDER_M + 80.0 + gap + 30.0) for s in (-1.0, 1.0)]
    x = np.concatenate([np.full(ys.size, xs[0]), np.full(ys.size, xs[1])])
    y = np.concatenate([ys, ys])
    n = x.size
    return Environment(1000.0, 1000.0, 50.0, 300.0, cylinders=Cylinders(x, y, np.full(n, 30.0), np.full(n, np.inf),
                                                                     np.zeros(n)))


def test_with_no_circle_clear_by_the_whole_margin_the_clearest_one_clear_by_the_tight_margin_is_held() -> None:
    """A plane flying on into a conflict is worse than a circle 3 m short of the hold margin: the clearest circle
    that keeps d_coll + TIGHT_HOLD_MARGIN_M is held; with none that does, there is no hold."""
    here, v = np.array([500.0, 200.0, 100.0]), np.array([0.0, 20.0])
    gap = D_COLL + HOLD_MARGIN_M - 3.0  # between the tight margin and the whole one
    hold = plane_hold(here, v, 80.0, _walls(gap), D_COLL, 20.0)
    assert hold is not None and D_COLL + TIGHT_HOLD_MARGIN_M <= hold.clearance_m < D_COLL + HOLD_MARGIN_M
    assert abs(hold.clearance_m - gap) < 1.0
    assert plane_hold(here, v, 80.0, _walls(D_COLL + TIGHT_HOLD_MARGIN_M - 2.0), D_COLL, 20.0) is None


def test_a_circle_is_left_where_its_tangent_points_at_the_goal_after_the_time_to_plan() -> None:
    """The exit from a hold circle: on the circle flown (the vehicle's own distance from the centre), at least the
    planning lead round it in the circling direction, flying the tangent there, which points at the goal within the
    exit tolerance; of exits that good, the nearest."""
    centre, here, goal = np.zeros(3), np.array([97.0, 0.0, 80.0]), np.array([0.0, 2000.0, 0.0])
    for clockwise in (True, False):
        for lead in (50.0, 200.0, 500.0):
            ex = circle_exit(here, centre, clockwise, goal, lead)
            assert abs(float(np.linalg.norm(ex.point[:2])) - 97.0) < 1e-6
            assert ex.point[2] == here[2]
            # the arc it reports is the arc to the point, in the circling direction, never less than the lead
            assert ex.arc_m >= lead - 1e-6
            left = arc_to(here, centre, clockwise, ex.point) * 97.0
            lap = 2 * math.pi * 97.0
            assert min((ex.arc_m - left) % lap, lap - (ex.arc_m - left) % lap) < 1e-6
            # the tangent, in the circling direction: perpendicular to the radius, turning the way it circles
            radial = ex.point[:2] / np.linalg.norm(ex.point[:2])
            assert abs(float(np.dot(ex.heading[:2], radial))) < 1e-9
            assert (np.cross(radial, ex.heading[:2]) < 0) == clockwise
            to_goal = goal[:2] - ex.point[:2]
            off = math.degrees(math.acos(float(np.dot(ex.heading[:2], to_goal) / np.linalg.norm(to_goal))))
            assert off <= EXIT_TURN_DEG + 5.0  # the best exit on a circle points at a far goal; a worse one sooner
    # counter-clockwise from the east point, the tangent already points north: with a short lead it leaves soon,
    # not a whole circle later
    assert circle_exit(here, centre, False, goal, 20.0).arc_m < 150.0
    # clockwise, it leaves on the west side, where its tangent turns north
    assert circle_exit(here, centre, True, goal, 50.0).point[0] < 0.0
