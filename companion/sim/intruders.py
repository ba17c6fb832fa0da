"""Scripted intruder aircraft (scenario ``[[intruders]]``), flown by the simulator and reported as ADSB_VEHICLE.

Each intruder flies its waypoints in order at constant speed, starting ``start_time`` seconds after *mission
start* (the simulated time at which the vehicle first began its mission, armed in AUTO). It is in the air, and
reported, only between leaving its first waypoint and reaching its last one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from planner.scenario import Intruder


@dataclass(frozen=True)
class IntruderSample:
    x: float
    y: float
    z: float
    vx: float  # east, m/s
    vy: float  # north
    vz: float  # up


class IntruderTrack:
    """Position of one intruder as a function of mission time."""

    def __init__(self, intruder: Intruder) -> None:
        self.intruder = intruder
        self._points = np.asarray(intruder.waypoints, dtype=float)  # (n, 3) ENU m
        legs = np.linalg.norm(np.diff(self._points, axis=0), axis=1)
        self._cumulative = np.concatenate([[0.0], np.cumsum(legs)])

    @property
    def duration(self) -> float:
        """Seconds from leaving the first waypoint to reaching the last."""
        return float(self._cumulative[-1]) / self.intruder.speed

    def sample(self, mission_time: float) -> IntruderSample | None:
        """Where it is ``mission_time`` s after mission start; None while not flying."""
        t = mission_time - self.intruder.start_time
        if t < 0.0 or t > self.duration:
            return None
        s = t * self.intruder.speed
        leg = min(int(np.searchsorted(self._cumulative, s, side="right")) - 1, len(self._points) - 2)
        a, b = self._points[leg], self._points[leg + 1]
        length = self._cumulative[leg + 1] - self._cumulative[leg]
        u = (b - a) / length if length > 0 else np.zeros(3)
        p = a + u * (s - self._cumulative[leg])
        v = u * self.intruder.speed
        return IntruderSample(*(float(c) for c in p), *(float(c) for c in v))


def heading_deg(sample: IntruderSample) -> float:
    return math.degrees(math.atan2(sample.vx, sample.vy)) % 360.0
