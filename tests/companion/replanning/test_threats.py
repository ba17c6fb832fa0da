"""companion.replanning.threats: closest approach by hand, 4D conflict prediction, ADS-B track picture."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.mission.geo import enu_to_geodetic
from companion.replanning.threats import (
    TrackPicture,
    closest_approach,
    merge_threats,
    predict_conflicts,
    route_distances,
    route_points,
)
from planner.world.environment import Threat, Threats
from planner.world.home import Home

HOME = Home(47.0, 8.0, 500.0)
ALL_VALID = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_HEADING
             | mavlink.ADSB_FLAGS_VALID_VELOCITY)

# A straight route along +x at 100 m, flown at 20 m/s from x = 0 at t = 0.
ROUTE = np.array([[0.0, 0.0, 100.0], [1000.0, 0.0, 100.0], [2000.0, 0.0, 100.0]])
SPEED = 20.0
D_COLL, MARGIN, DT = 100.0, 20.0, 0.5


def track(p0, v, radius=10.0, growth=0.0, t_ref=0.0, id_="intruder") -> Threat:
    return Threat(id=id_, kind="track", radius=radius, p0=tuple(p0), p1=tuple(v), t_ref=t_ref,
                  radius_growth=growth)


def predict(threats, s_now=0.0, t_now=0.0, horizon=200.0):
    return predict_conflicts(ROUTE, SPEED, s_now, t_now, Threats(items=tuple(threats)), horizon, D_COLL, MARGIN, DT)


# --- closest approach ------------------------------------------------------------------------------------------

def test_closest_approach_head_on():
    t, d = closest_approach([0, 0, 0], [10, 0, 0], [1000, 0, 0], [-10, 0, 0])
    assert t == pytest.approx(50.0) and d == pytest.approx(0.0, abs=1e-9)
    t, d = closest_approach([0, 0, 0], [10, 0, 0], [1000, 30, 0], [-10, 0, 0])
    assert t == pytest.approx(50.0) and d == pytest.approx(30.0)


def test_closest_approach_right_angles():
    # Δp = (100, −100), Δv = (−10, 10): t* = 2000 / 200 = 10, they meet.
    t, d = closest_approach([0, 0, 0], [10, 0, 0], [100, -100, 0], [0, 10, 0])
    assert t == pytest.approx(10.0) and d == pytest.approx(0.0, abs=1e-9)
    # Δp = (100, −200): t* = 3000 / 200 = 15, relative position then (−50, −50).
    t, d = closest_approach([0, 0, 0], [10, 0, 0], [100, -200, 0], [0, 10, 0])
    assert t == pytest.approx(15.0) and d == pytest.approx(50 * math.sqrt(2))


def test_closest_approach_parallel_is_now():
    t, d = closest_approach([0, 0, 0], [10, 5, 0], [30, 40, 0], [10, 5, 0])
    assert t == 0.0 and d == pytest.approx(50.0)


def test_closest_approach_diverging_is_now():
    t, d = closest_approach([0, 0, 0], [-5, 0, 0], [100, 0, 0], [10, 0, 0])
    assert t == 0.0 and d == pytest.approx(100.0)


def test_closest_approach_broadcasts():
    p2 = np.array([[1000, 0, 0], [100, -200, 0], [100, 0, 0]], dtype=float)
    v2 = np.array([[-10, 0, 0], [0, 10, 0], [20, 0, 0]], dtype=float)
    t, d = closest_approach(np.zeros(3), np.array([10.0, 0, 0]), p2, v2)
    np.testing.assert_allclose(t, [50.0, 15.0, 0.0])
    np.testing.assert_allclose(d, [0.0, 50 * math.sqrt(2), 100.0], atol=1e-9)


# --- conflict prediction ---------------------------------------------------------------------------------------

def test_route_points_follow_corners():
    route = np.array([[0.0, 0, 0], [100, 0, 0], [100, 100, 0]])
    np.testing.assert_allclose(route_distances(route), [0, 100, 200])
    pts, seg = route_points(route, np.array([0.0, 50, 150, 250]))
    np.testing.assert_allclose(pts, [[0, 0, 0], [50, 0, 0], [100, 50, 0], [100, 100, 0]])
    assert seg.tolist() == [0, 0, 1, 1]


@pytest.mark.parametrize("t_now", [0.0, 10.0])
def test_crossing_track_matches_closest_approach(t_now):
    # Crosses the route northbound at 15 m/s; closest approach by hand: t* = 46.4 s, d* = |(72, 96)| = 120 m.
    p0, v = np.array([1000.0, -600, 100]), np.array([0.0, 15, 0])
    t_star, d_star = closest_approach(ROUTE[0], [SPEED, 0, 0], p0, v)
    assert (t_star, d_star) == (pytest.approx(46.4), pytest.approx(120.0))
    # The vehicle is already t_now seconds into the route: same encounter, same clock.
    (c,) = predict([track(p0, v)], s_now=SPEED * t_now, t_now=t_now)
    assert c.threat_id == "intruder"
    assert c.t == pytest.approx(t_star, abs=DT)
    assert c.separation == pytest.approx(d_star - 10.0, abs=DT * SPEED)
    np.testing.assert_allclose(c.position, ROUTE[0] + [SPEED * t_star, 0, 0], atol=DT * SPEED)
    assert c.s == pytest.approx(c.position[0]) and c.segment == 0


def test_track_passing_behind_is_no_conflict():
    # Crosses the route at x = 200 at t = 40 s, when the vehicle is already at x = 800.
    behind = track([200.0, -600, 100], [0.0, 15, 0])
    assert predict([behind]) == []
    # The same path met 30 s earlier in its flight would be a conflict (the check is about time, not place).
    assert predict([track([200.0, -150, 100], [0.0, 15, 0])])


def test_horizon_respected():
    crossing = track([1000.0, -600, 100], [0.0, 15, 0])  # closest approach at 46.4 s
    assert predict([crossing], horizon=30.0) == []
    assert len(predict([crossing], horizon=60.0)) == 1


def test_route_end_bounds_the_check():
    # Arrives at x = 2000 at t = 100 s; a threat that reaches the route's end only at t = 150 s is no conflict.
    late = track([2000.0, -1500, 100], [0.0, 10, 0])
    assert predict([late], horizon=300.0) == []


def test_uncertainty_growth_turns_near_miss_into_conflict():
    # Head-on with 200 m lateral offset: closest approach at t = 50 s, separation 200 − 10 = 190 m ≥ 120 m.
    p0, v = [2000.0, 200, 100], [-20.0, 0, 0]
    assert predict([track(p0, v)]) == []
    # Radius grows 2 m/s of prediction: 10 + 100 at t = 50 s → separation 90 m.
    (c,) = predict([track(p0, v, growth=2.0)])
    assert c.separation < D_COLL + MARGIN
    assert c.separation == pytest.approx(90.0, abs=DT * SPEED)


def test_several_threats_sorted_by_time_and_scripted_kinds():
    loiter = Threat(id="orbit", kind="loiter", radius=50.0, p0=(1500.0, 0, 100), speed=10.0, circle_radius=200.0)
    crossing = track([1000.0, -600, 100], [0.0, 15, 0])
    far = track([0.0, 5000, 100], [0.0, 0, 0], id_="far")
    conflicts = predict([loiter, far, crossing])
    assert [c.threat_id for c in conflicts] == ["intruder", "orbit"]
    assert conflicts[1].segment == 1


# --- ADS-B track picture ---------------------------------------------------------------------------------------

def adsb(enu, heading_cdeg=9000, speed_cms=2500, ver_cms=100, tslc=0, flags=ALL_VALID, icao=0xABC123):
    lat, lon, _ = enu_to_geodetic(np.asarray(enu, dtype=float), HOME)
    return mavlink.MAVLink_adsb_vehicle_message(
        icao, round(float(lat) * 1e7), round(float(lon) * 1e7), mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC,
        round((HOME.alt + enu[2]) * 1000), heading_cdeg, speed_cms, ver_cms, b"INTRUDR1", mavlink.ADSB_EMITTER_TYPE_UAV,
        tslc, flags, 0)


def test_adsb_to_enu_position_and_velocity():
    picture = TrackPicture(HOME)
    t = picture.update(adsb([300.0, 400, 120], flags=ALL_VALID | mavlink.ADSB_FLAGS_VERTICAL_VELOCITY_VALID),
                       now=100.0)
    np.testing.assert_allclose(t.position, [300, 400, 120], atol=0.05)  # 1e-7 deg ≈ 1 cm
    np.testing.assert_allclose(t.velocity, [25, 0, 1], atol=1e-9)  # heading 90° = east, climbing 1 m/s
    # without the vertical-velocity flag the climb rate is not to be trusted (horizontal velocity still is)
    t2 = TrackPicture(HOME).update(adsb([300.0, 400, 120]), now=100.0)
    np.testing.assert_allclose(t2.velocity, [25, 0, 0], atol=1e-9)
    assert t.t_contact == 100.0 and t.callsign == "INTRUDR1" and t.id == "adsb-abc123"


@pytest.mark.parametrize("heading_cdeg, expected", [(0, (0, 25)), (18000, (0, -25)), (27000, (-25, 0)),
                                                     (22500, (-25 / math.sqrt(2), -25 / math.sqrt(2)))])
def test_adsb_heading_convention(heading_cdeg, expected):
    t = TrackPicture(HOME).update(adsb([0.0, 0, 50], heading_cdeg=heading_cdeg), now=0.0)
    np.testing.assert_allclose(t.velocity[:2], expected, atol=1e-9)


def test_adsb_tslc_and_invalid_reports():
    picture = TrackPicture(HOME)
    assert picture.update(adsb([0.0, 0, 50], tslc=3), now=10.0).t_contact == 7.0
    # No valid coordinates: ignored, the held track stays.
    kept = picture.update(adsb([900.0, 0, 50], flags=ALL_VALID & ~mavlink.ADSB_FLAGS_VALID_COORDS), now=11.0)
    assert kept.position[0] == pytest.approx(0.0, abs=0.05)
    # Older than the one held (out of order): ignored.
    assert picture.update(adsb([500.0, 0, 50], tslc=5), now=11.0).t_contact == 7.0
    # No velocity: a stationary track (the growth carries the uncertainty).
    t = picture.update(adsb([100.0, 0, 50], flags=ALL_VALID & ~mavlink.ADSB_FLAGS_VALID_VELOCITY), now=12.0)
    assert t.velocity == (0.0, 0.0, 0.0)
    assert TrackPicture(HOME).update(adsb([0.0, 0, 50], flags=mavlink.ADSB_FLAGS_VALID_COORDS), now=0.0) is None


def test_expiry_drops_stale_tracks():
    picture = TrackPicture(HOME)
    picture.update(adsb([0.0, 0, 50], icao=1), now=0.0)
    picture.update(adsb([0.0, 0, 50], icao=2), now=8.0)
    assert picture.expire(now=10.0, max_age=5.0) == ["adsb-000001"]
    assert list(picture.tracks) == [2]
    assert picture.expire(now=12.0, max_age=5.0) == []
    assert picture.expire(now=13.5, max_age=5.0) == ["adsb-000002"] and len(picture) == 0


def test_threats_from_tracks_merge_with_scripted():
    picture = TrackPicture(HOME)
    picture.update(adsb([300.0, 400, 120], tslc=2, flags=ALL_VALID | mavlink.ADSB_FLAGS_VERTICAL_VELOCITY_VALID),
                   now=100.0)  # last contact at 98 s
    scripted = Threats(items=(Threat(id="orbit", kind="loiter", radius=50.0, p0=(0.0, 0, 100), speed=10.0,
                                     circle_radius=200.0),))
    threats = picture.threats(now=100.0, base_radius=30.0, growth_per_s=1.5, scripted=scripted)
    assert [t.id for t in threats.items] == ["orbit", "adsb-abc123"]
    tr = threats.items[1]
    assert tr.kind == "track" and tr.t_ref == 98.0
    np.testing.assert_allclose(tr.p1, [25, 0, 1], atol=1e-9)
    # Radius now = base + growth × age (2 s); 10 s ahead it has grown for 12 s.
    np.testing.assert_allclose(threats.radii(np.array([100.0, 110.0]))[1], [33.0, 48.0])
    np.testing.assert_allclose(threats.positions(110.0)[1], np.array(tr.p0) + 12 * np.array([25, 0, 1]))
    assert len(merge_threats(scripted, picture.threat_items(30.0, 1.5), ())) == 2


def test_adsb_intruder_predicted_into_conflict():
    # End to end: an ADS-B report of the crossing intruder from the hand-worked case, heard at t = 0.
    picture = TrackPicture(HOME)
    picture.update(adsb([1000.0, -600, 100], heading_cdeg=0, speed_cms=1500, ver_cms=0), now=0.0)
    threats = picture.threats(now=0.0, base_radius=10.0, growth_per_s=0.0)
    (c,) = predict_conflicts(ROUTE, SPEED, 0.0, 0.0, threats, 120.0, D_COLL, MARGIN, DT)
    assert c.threat_id == "adsb-abc123" and c.t == pytest.approx(46.4, abs=DT)
