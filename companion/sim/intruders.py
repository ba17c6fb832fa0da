"""Scripted intruder aircraft (scenario ``[[intruders]]``), flown by the simulator (or fed to a real autopilot's
link by :mod:`companion.sim.traffic`) and reported as ADSB_VEHICLE.

Each intruder flies its waypoints in order at constant speed, starting ``start_time`` seconds after *mission
start* (the vehicle's time at which it first began its mission, armed in AUTO). An intruder with a ``meet`` point
is timed by the vehicle's real progress instead (:class:`IntruderTrack`): it takes off, at the speed that brings
it to ``meet`` when the vehicle, flying the planned route at its measured pace from where it is, reaches the
route point nearest ``meet``. So a scenario's conflict means the same on any autopilot, whatever its
takeoff and climb-out take. An intruder is in
the air, and reported, only between leaving its first waypoint and reaching its last one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mission.geo import enu_to_geodetic
from planner.world.home import Home
from planner.world.scenario import Intruder

ADSB_FLAGS = (mavlink.ADSB_FLAGS_VALID_COORDS | mavlink.ADSB_FLAGS_VALID_ALTITUDE | mavlink.ADSB_FLAGS_VALID_HEADING
              | mavlink.ADSB_FLAGS_VALID_VELOCITY | mavlink.ADSB_FLAGS_VALID_CALLSIGN)


@dataclass(frozen=True)
class IntruderSample:
    x: float
    y: float
    z: float
    vx: float  # east, m/s
    vy: float  # north
    vz: float  # up


def _arc_length_at(points: np.ndarray, cumulative: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """Arc length along the polyline ``points`` (n, 3) of its point nearest ``p``, and the distance to it."""
    a, b = points[:-1], points[1:]
    ab = b - a
    length2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    u = np.clip(np.einsum("ij,ij->i", p - a, ab) / length2, 0.0, 1.0)
    d = np.linalg.norm(a + u[:, None] * ab - p, axis=1)
    k = int(np.argmin(d))
    return float(cumulative[k] + u[k] * math.sqrt(length2[k])), float(d[k])


def _cumulative(points: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


SPEED_RANGE = (0.6, 2.0)  # a meet intruder that must take off at once flies this much slower or faster than nominal
JOIN_M = 30.0  # the vehicle is on its route while it is this close to it
SETTLE_S = 4.0  # ... and settled on it this long after joining it (turning onto it, speeding up)
PACE_WINDOW_S = 4.0  # ... and its pace along the route is measured over the last this long
SLOWED = 0.5  # its pace over the last RECENT_S below this share of its best: slowing to hold, the estimate stands
RECENT_S = 1.0


class IntruderTrack:
    """Position of one intruder as a function of mission time. With a ``meet`` point, pass the vehicle's planned
    route (ENU (K, 3), from the route's start) and call :meth:`follow` with the vehicle's positions in
    mission-time order. The vehicle's takeoff and climb-out differ from one autopilot to the next (ArduPlane
    overshoots the route start and turns back; a copter climbs, then accelerates), so nothing is decided until it
    has flown :data:`SETTLE_S` + :data:`PACE_WINDOW_S` on its route: its arrival at the meeting point is then
    estimated from its pace over the last :data:`PACE_WINDOW_S`, and the intruder takes off at the time that brings it
    to ``meet`` at its nominal speed;
    if that time has passed already, it takes off at once at the speed that keeps the appointment (within
    :data:`SPEED_RANGE`). A vehicle that leaves the route after that (it replanned) keeps the appointment as last
    estimated, and so does one that slows below half its best pace on the route (a copter braking to hold). From its
    take-off on it flies its script at a constant speed, whatever the vehicle does."""

    def __init__(self, intruder: Intruder, route: np.ndarray | None = None) -> None:
        self.intruder = intruder
        self._points = np.asarray(intruder.waypoints, dtype=float)  # (n, 3) ENU m
        self._cumulative = _cumulative(self._points)
        self.start_time: float | None = intruder.start_time  # None: not scheduled yet (a meet intruder)
        self.speed = intruder.speed  # m/s
        if intruder.meet is not None:
            if route is None or len(route) < 2:
                raise ValueError(f"intruder {intruder.id} meets the vehicle: the vehicle's route is needed")
            self.start_time = None
            self._route = np.asarray(route, dtype=float)
            self._route_cumulative = _cumulative(self._route)
            self._pace: list[tuple[float, float]] = []  # (mission s, m along the route) while on the route
            self._eta: float | None = None  # the vehicle's last estimated arrival at the meeting point
            self._pace_max = 0.0  # m/s, its best pace along the route so far
            self._slowed = False  # slowing down on the route: the appointment stands
            meet = np.asarray(intruder.meet, dtype=float)
            self._meet_on_route, _ = _arc_length_at(self._route, self._route_cumulative, meet)
            self._meet_on_path = _arc_length_at(self._points, self._cumulative, meet)[0]

    @property
    def waiting(self) -> bool:
        """A meet intruder that has not taken off yet."""
        return self.intruder.meet is not None and self.start_time is None

    def follow(self, mission_time: float, position: np.ndarray) -> None:
        """Renew a waiting meet intruder's estimate from the vehicle at ``position`` (ENU m) at ``mission_time``,
        and make it take off when it is time."""
        if not self.waiting:
            return
        t = mission_time
        along, off = _arc_length_at(self._route, self._route_cumulative, np.asarray(position, dtype=float))
        if off > JOIN_M:
            if self._eta is None:
                self._pace.clear()  # not on the route yet (or overshooting its start): measure again once it is
                return
            eta = self._eta  # it left the route (it replanned): the appointment stands as last estimated
        else:
            self._pace.append((t, max(along, self._pace[-1][1] if self._pace else along)))
            if t - self._pace[0][0] < SETTLE_S + PACE_WINDOW_S:
                return  # no pace yet: the first seconds on the route it is still turning onto it and speeding up
            t0, s0 = next(p for p in reversed(self._pace) if t - p[0] >= PACE_WINDOW_S)
            pace = (self._pace[-1][1] - s0) / (t - t0)
            left = self._meet_on_route - self._pace[-1][1]
            if left <= 0:
                return
            t1, s1 = next(p for p in reversed(self._pace) if t - p[0] >= RECENT_S)
            recent = (self._pace[-1][1] - s1) / (t - t1)
            if self._eta is None or recent >= SLOWED * self._pace_max:
                if pace <= 0:
                    return
                self._pace_max = max(self._pace_max, pace)
                self._eta = t + left / pace
                self._slowed = False
            elif not self._slowed:
                # slowing down on the route (a copter braking to hold): the appointment is where it would have been
                # flying on at its best pace, and stands, as when it leaves the route (before this, the copters'
                # crossing_traffic holds pushed ga-right's take-off past the end of the flight)
                self._slowed = True
                self._eta = t + left / self._pace_max
            eta = self._eta
        if t < eta - self._meet_on_path / self.intruder.speed:
            return
        lo, hi = SPEED_RANGE
        self.speed = float(np.clip(self._meet_on_path / max(eta - t, 1e-3), lo * self.intruder.speed,
                                   hi * self.intruder.speed))
        self.start_time = t

    @property
    def duration(self) -> float:
        """Seconds from leaving the first waypoint to reaching the last, at the nominal speed."""
        return float(self._cumulative[-1]) / self.intruder.speed

    def sample(self, mission_time: float) -> IntruderSample | None:
        """Where it is ``mission_time`` s after mission start; None while not flying."""
        if self.start_time is None or mission_time < self.start_time:
            return None
        s = self.speed * (mission_time - self.start_time)
        if s > self._cumulative[-1]:
            return None
        leg = min(int(np.searchsorted(self._cumulative, s, side="right")) - 1, len(self._points) - 2)
        a, b = self._points[leg], self._points[leg + 1]
        length = self._cumulative[leg + 1] - self._cumulative[leg]
        u = (b - a) / length if length > 0 else np.zeros(3)
        p = a + u * (s - self._cumulative[leg])
        v = u * self.speed
        return IntruderSample(*(float(c) for c in p), *(float(c) for c in v))


def heading_deg(sample: IntruderSample) -> float:
    return math.degrees(math.atan2(sample.vx, sample.vy)) % 360.0


def adsb_report(intruder: Intruder, sample: IntruderSample, home: Home) -> mavlink.MAVLink_adsb_vehicle_message:
    """The ADSB_VEHICLE an ADS-B receiver would report for ``intruder`` at ``sample`` (altitude AMSL, geometric)."""
    lat, lon, _ = enu_to_geodetic(np.array([[sample.x, sample.y, 0.0]]), home)
    return mavlink.MAVLink_adsb_vehicle_message(
        intruder.icao, round(float(lat[0]) * 1e7), round(float(lon[0]) * 1e7), mavlink.ADSB_ALTITUDE_TYPE_GEOMETRIC,
        round((home.alt + sample.z) * 1000), round(heading_deg(sample) * 100) % 36000,
        round(math.hypot(sample.vx, sample.vy) * 100), round(sample.vz * 100), intruder.id[:9].encode(),
        mavlink.ADSB_EMITTER_TYPE_UAV, 0, ADSB_FLAGS, 0)
