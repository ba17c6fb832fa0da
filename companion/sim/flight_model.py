"""Kinematic flight model of the simulated autopilot, in local ENU metres from home (SPEC §1).

No aerodynamics: a point with a compass heading (0 = north, clockwise, radians), a horizontal speed and a
vertical rate. The limits come from :class:`planner.config.VehicleLimits`:

- plane: turn rate ≤ g·tan(max bank)/v, climb/descent ≤ v·tan(max climb), never hovers (it circles instead);
- copter: points straight at its target, moves at most ``speed`` horizontally, climbs/descends at most
  v·tan(max climb) on legs and at fixed vertical rates (2.5 m/s up, 1.5 m/s down, 0.5 m/s for the last 10 m of
  a landing; ArduCopter's WPNAV/LAND defaults) on take-off and landing.

Each guidance primitive advances the state by ``dt`` seconds of simulated time; the caller keeps ``dt`` small.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner.config import G0, VehicleLimits

COPTER_CLIMB_RATE = 2.5  # m/s, WPNAV_SPEED_UP
COPTER_DESCENT_RATE = 1.5  # m/s, WPNAV_SPEED_DN / LAND_SPEED_HIGH
COPTER_LAND_RATE = 0.5  # m/s below 10 m, LAND_SPEED
PLANE_LOITER_RADIUS = 60.0  # m, WP_LOITER_RAD default
ALT_GAIN = 0.5  # 1/s, altitude error → commanded vertical rate (then limited)


def wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def bearing(dx: float, dy: float) -> float:
    """Compass bearing (rad) of an ENU displacement."""
    return math.atan2(dx, dy)


@dataclass
class VehicleState:
    x: float = 0.0  # east, m
    y: float = 0.0  # north, m
    z: float = 0.0  # up, m above home
    heading: float = 0.0  # compass, rad
    speed: float = 0.0  # horizontal ground speed, m/s
    vz: float = 0.0  # up, m/s
    on_ground: bool = True
    turn_rate: float = 0.0  # rad/s, clockwise, of the last step (a plane's bank follows from it)

    @property
    def vx(self) -> float:
        return self.speed * math.sin(self.heading)

    @property
    def vy(self) -> float:
        return self.speed * math.cos(self.heading)


class FlightModel:
    """Moves one :class:`VehicleState` under simple guidance laws; ``target_speed`` is set by DO_CHANGE_SPEED."""

    def __init__(self, vehicle: VehicleLimits, heading: float = 0.0) -> None:
        self.vehicle = vehicle
        self.is_plane = vehicle.type == "plane"
        self.state = VehicleState(heading=heading)
        self.target_speed = vehicle.cruise_speed

    # --- limits ---------------------------------------------------------------------------------------------

    @property
    def airborne_speed(self) -> float:
        return max(self.target_speed, 1.0)

    def _max_vz(self) -> float:
        return max(self.airborne_speed * math.tan(self.vehicle.max_climb), 0.5)

    def _turn_towards(self, desired: float, dt: float) -> None:
        s = self.state
        rate = G0 * math.tan(self.vehicle.max_bank) / max(s.speed, 1.0)
        err = wrap_pi(desired - s.heading)
        turn = max(-rate * dt, min(rate * dt, err))
        s.heading = wrap_pi(s.heading + turn)
        s.turn_rate = turn / dt

    def _hold_altitude(self, z_target: float, dt: float) -> None:
        s = self.state
        limit = self._max_vz()
        s.vz = max(-limit, min(limit, ALT_GAIN * (z_target - s.z)))
        if abs(z_target - s.z) < abs(s.vz * dt):
            s.vz = (z_target - s.z) / dt

    def _advance(self, dt: float, turning: bool = False) -> None:
        s = self.state
        if not turning:
            s.turn_rate = 0.0
        s.x += s.vx * dt
        s.y += s.vy * dt
        s.z += s.vz * dt
        if s.z <= 0.0 and s.vz < 0.0:
            s.z = 0.0
            s.vz = 0.0

    # --- primitives -----------------------------------------------------------------------------------------

    def stay(self) -> None:
        """On the ground (or a copter hovering): no motion."""
        s = self.state
        s.speed = 0.0
        s.vz = 0.0
        s.turn_rate = 0.0

    def straight(self, z_target: float, dt: float) -> None:
        """Plane: fly on, wings level, holding ``z_target``; copter: hover."""
        if not self.is_plane:
            self.stay()
            return
        self.state.speed = self.airborne_speed
        self._hold_altitude(z_target, dt)
        self._advance(dt)

    def climb_straight(self, z_target: float, dt: float) -> None:
        """Plane take-off: straight ahead on the current heading at the maximum climb angle."""
        s = self.state
        s.on_ground = False
        s.speed = self.airborne_speed
        s.vz = min(s.speed * math.tan(self.vehicle.max_climb), max(0.0, (z_target - s.z) / dt))
        self._advance(dt)

    def vertical(self, z_target: float, dt: float) -> None:
        """Copter: climb or descend in place to ``z_target``."""
        s = self.state
        s.speed = 0.0
        if z_target > s.z:
            s.on_ground = False
            rate = COPTER_CLIMB_RATE
        else:
            rate = COPTER_LAND_RATE if s.z < 10.0 else COPTER_DESCENT_RATE
        s.vz = max(-rate, min(rate, (z_target - s.z) / dt))
        self._advance(dt)

    def fly_to(self, target: tuple[float, float, float], origin: tuple[float, float] | None, dt: float) -> None:
        """Towards ``target``: a plane follows the track origin→target with a look-ahead point, turning at its
        bank-limited rate; a copter points directly at it and stops there."""
        s = self.state
        s.on_ground = False
        tx, ty, tz = target
        if self.is_plane:
            s.speed = self.airborne_speed
            aim_x, aim_y = tx, ty
            if origin is not None:
                ox, oy = origin
                lx, ly = tx - ox, ty - oy
                length = math.hypot(lx, ly)
                if length > 1.0:
                    ux, uy = lx / length, ly / length
                    along = (s.x - ox) * ux + (s.y - oy) * uy
                    lookahead = max(2.0 * self.vehicle.cruise_speed**2 / (G0 * math.tan(self.vehicle.max_bank)),
                                    2.0 * s.speed)
                    ahead = min(max(along, 0.0) + lookahead, length)
                    aim_x, aim_y = ox + ux * ahead, oy + uy * ahead
            self._turn_towards(bearing(aim_x - s.x, aim_y - s.y), dt)
            self._hold_altitude(tz, dt)
            self._advance(dt, turning=True)
            return
        dx, dy = tx - s.x, ty - s.y
        dist = math.hypot(dx, dy)
        step = min(self.airborne_speed * dt, dist)
        if dist > 0.5:
            s.heading = bearing(dx, dy)
        s.speed = step / dt
        self._hold_altitude(tz, dt)
        self._advance(dt)

    def circle(self, centre: tuple[float, float], radius: float, z_target: float, clockwise: bool,
               dt: float) -> None:
        """Plane: circle ``centre`` at ``radius``; copter: hold over the centre."""
        s = self.state
        if not self.is_plane:
            self.fly_to((centre[0], centre[1], z_target), None, dt)
            return
        s.speed = self.airborne_speed
        radius = max(radius, self.vehicle.min_turn_radius)
        cx, cy = centre
        d = math.hypot(s.x - cx, s.y - cy)
        theta = bearing(s.x - cx, s.y - cy)  # where we are, seen from the centre
        correction = math.atan((d - radius) / max(0.5 * radius, 20.0))
        desired = theta + math.pi / 2 + correction if clockwise else theta - math.pi / 2 - correction
        self._turn_towards(desired, dt)
        self._hold_altitude(z_target, dt)
        self._advance(dt, turning=True)

    def touch_down(self) -> None:
        s = self.state
        s.z = 0.0
        s.vz = 0.0
        s.speed = 0.0
        s.on_ground = True
