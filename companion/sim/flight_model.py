"""Kinematic flight model of the simulated autopilot, in local ENU metres from home (docs/method.md §1.1).

No aerodynamics: a point with a compass heading (0 = north, clockwise, radians), a horizontal speed and a
vertical rate. The limits come from :class:`planner.world.config.VehicleLimits`:

- plane: turn rate ≤ g·tan(max bank)/v, climb/descent ≤ v·tan(max climb), never hovers (it circles instead);
  speed changes at most 1.3 m/s² and vertical rate at most 3.7 m/s² (so it overshoots a level-off as ArduPlane
  does). Take-off as measured on ArduPlane SITL: a ground roll on the current heading, then a full-throttle
  climb straight ahead (see :meth:`FlightModel.takeoff_roll` and :meth:`FlightModel.climb_straight`);
- copter: points straight at its target, moves at most ``speed`` horizontally (braking at 2.5 m/s² for the
  waypoint ahead, so it reaches it within 1-2 m as ArduCopter does), climbs/descends at most
  v·tan(max climb) on legs and at fixed vertical rates (2.5 m/s up, 1.5 m/s down, 0.5 m/s for the last 10 m of
  a landing; ArduCopter's WPNAV/LAND defaults) on take-off and landing; a climb accelerates at 1 m/s² and slows
  down on the last metres (ArduCopter's position controller, measured on SITL).

Each guidance primitive advances the state by ``dt`` seconds of simulated time; the caller keeps ``dt`` small.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner.world.config import G0, VehicleLimits

COPTER_CLIMB_RATE = 2.5  # m/s, WPNAV_SPEED_UP
COPTER_DESCENT_RATE = 1.5  # m/s, WPNAV_SPEED_DN / LAND_SPEED_HIGH
COPTER_LAND_RATE = 0.5  # m/s below 10 m, LAND_SPEED
COPTER_WP_DECEL = 2.5  # m/s², a copter's braking for a waypoint (ArduCopter WPNAV_ACCEL 250 cm/s²)
COPTER_CLIMB_ACCEL = 1.0  # m/s², vertical acceleration of a copter climb (SITL: 0 → 2.5 m/s in ~2.5 s)
COPTER_CLIMB_DECEL = 0.55  # m/s², the slow-down before the target altitude (SITL: 2.15 m/s 4 m below it)
COPTER_MIN_CLIMB = 0.3  # m/s, the slowest final approach of a climb
PLANE_LOITER_RADIUS = 80.0  # m, WP_LOITER_RAD of SITL's plane.parm (ArduPlane's own default is 60)
# ArduPlane flies its loiter circles wider than asked: WP_LOITER_RAD 80 m was flown at 96.7 m and a DO_REPOSITION
# radius of 120 m at 135.5 m on SITL (test_hold_turn.py)
PLANE_CIRCLE_WIDENING_M = 16.0
ALT_GAIN = 0.5  # 1/s, altitude error → commanded vertical rate (then limited)
PLANE_SPEED_ACCEL = 2.0  # m/s², SITL: 27.4 → 21.0 m/s in 3.3 s, once over the top of the take-off overshoot
PLANE_CLIMBING_VZ = 1.0  # m/s: still climbing this fast after take-off, a plane does not slow down yet
PLANE_VERTICAL_ACCEL = 3.7  # m/s², SITL: +10 → 0 m/s in 2.7 s after take-off, peaking 13 m above its altitude
# ArduPlane SITL take-off (plane.parm, TKOFF_* defaults), measured flying fuseplan's rescue_static mission:
PLANE_ROLL_ACCEL = 6.9  # m/s², ground roll (0 → 20 m/s ground speed between 0.6 and 3.5 s after arming)
PLANE_ROTATE_SPEED = 20.0  # m/s ground speed at lift-off (~30 m down the runway)
PLANE_TAKEOFF_CLIMB_RATE = 10.0  # m/s, full-throttle climb (pitch ~17°, TKOFF level-off does not slow it)
PLANE_TAKEOFF_SPEED = 27.0  # m/s, ground speed reached in the take-off climb
PLANE_TAKEOFF_ACCEL = 2.0  # m/s², 20 → 27 m/s during the climb
PLANE_LIFTOFF_VERTICAL_ACCEL = 12.0  # m/s², rotation: full climb rate within ~1 s of lift-off


def wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _approach(value: float, target: float, step: float) -> float:
    """``value`` moved towards ``target`` by at most ``step``."""
    return value + max(-step, min(step, target - value))


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
        self._after_takeoff = False  # climbing on after a take-off: no slowing down yet

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
        vz = max(-limit, min(limit, ALT_GAIN * (z_target - s.z)))
        if abs(z_target - s.z) < abs(vz * dt):
            vz = (z_target - s.z) / dt
        s.vz = _approach(s.vz, vz, PLANE_VERTICAL_ACCEL * dt) if self.is_plane else vz

    def _cruise(self, dt: float) -> None:
        """Plane: speed towards the target airspeed at a limited rate (copters change speed at once). After the
        take-off climb it keeps its speed until over the top of the overshoot (SITL: 27-28 m/s held for ~2 s)."""
        s = self.state
        target = self.airborne_speed
        self._after_takeoff = self._after_takeoff and s.vz > PLANE_CLIMBING_VZ
        if s.speed <= 0.0:
            s.speed = target
        elif target > s.speed or not self._after_takeoff:
            s.speed = _approach(s.speed, target, PLANE_SPEED_ACCEL * dt)

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
        self._cruise(dt)
        self._hold_altitude(z_target, dt)
        self._advance(dt)

    def takeoff_roll(self, dt: float) -> None:
        """Plane take-off, on the runway: accelerate straight ahead on the current heading; airborne once at
        the rotation speed."""
        s = self.state
        s.vz = 0.0
        s.speed = min(s.speed + PLANE_ROLL_ACCEL * dt, PLANE_ROTATE_SPEED)
        self._advance(dt)
        if s.speed >= PLANE_ROTATE_SPEED:
            s.on_ground = False

    def climb_straight(self, dt: float) -> None:
        """Plane take-off, airborne: climb straight ahead on the current heading at full throttle (ArduPlane's
        take-off climb rate and speed, not the planner's limits), until the caller sees the altitude reached."""
        s = self.state
        s.on_ground = False
        s.speed = _approach(max(s.speed, PLANE_ROTATE_SPEED), PLANE_TAKEOFF_SPEED, PLANE_TAKEOFF_ACCEL * dt)
        s.vz = _approach(s.vz, PLANE_TAKEOFF_CLIMB_RATE, PLANE_LIFTOFF_VERTICAL_ACCEL * dt)
        self._after_takeoff = True
        self._advance(dt)

    def vertical(self, z_target: float, dt: float) -> None:
        """Copter: climb or descend in place to ``z_target``."""
        s = self.state
        s.speed = 0.0
        dz = z_target - s.z
        if dz > 0.0:
            s.on_ground = False
            rate = min(COPTER_CLIMB_RATE, max(COPTER_MIN_CLIMB, math.sqrt(2.0 * COPTER_CLIMB_DECEL * dz)))
            s.vz = min(_approach(max(s.vz, 0.0), rate, COPTER_CLIMB_ACCEL * dt), dz / dt)
        else:
            rate = COPTER_LAND_RATE if s.z < 10.0 else COPTER_DESCENT_RATE
            s.vz = max(-rate, dz / dt)
        self._advance(dt)

    def fly_to(self, target: tuple[float, float, float], origin: tuple[float, float] | None, dt: float) -> None:
        """Towards ``target``: a plane follows the track origin→target with a look-ahead point, turning at its
        bank-limited rate; a copter points directly at it and stops there."""
        s = self.state
        s.on_ground = False
        tx, ty, tz = target
        if self.is_plane:
            self._cruise(dt)
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
        # slowing for the waypoint as ArduCopter does (WPNAV_ACCEL): it reaches it at a walk, within 1-2 m
        step = min(self.airborne_speed * dt, math.sqrt(2.0 * COPTER_WP_DECEL * dist) * dt, dist)
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
        self._cruise(dt)
        radius = max(radius + PLANE_CIRCLE_WIDENING_M, self.vehicle.min_turn_radius)
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
