"""Kinematic flight model of the simulated autopilot, in local ENU metres from home (docs/method.md §1.1).

No aerodynamics: a point with a compass heading (0 = north, clockwise, radians), a horizontal speed and a
vertical rate. The limits come from :class:`planner.world.config.VehicleLimits`:

- plane: steered by ArduPlane's L1 guidance law (Park, Deyst and How 2004, as ArduPlane's L1 controller flies it:
  a lateral acceleration of 4ζ²·v²/L1·sin η towards a point L1 = ζ·P·v/π ahead on the track, or on a loiter
  circle a PD law on the radius error plus the centripetal term), with NAVL1_PERIOD P and damping ζ of SITL's
  plane.parm. The bank follows that demand (limited to the max bank) with a lag, and the plane turns at
  ARDUPLANE_TURN_EFFICIENCY of the rate g·tan(bank)/v: fitted to ArduPlane SITL, this one law gives its 90°
  turn (carried 34-39 m past the new leg) and its circles (80 m flown at 96.8 m, 120 m at 135.5 m;
  tests/conformance/test_hold_turn.py). Climb/descent ≤ v·tan(max climb), never hovers (it circles instead);
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

from companion.mavlink.vehicle_limits import ARDUPLANE_L1_DAMPING, ARDUPLANE_TURN_EFFICIENCY, l1_distance
from planner.world.config import G0, VehicleLimits

COPTER_CLIMB_RATE = 2.5  # m/s, WPNAV_SPEED_UP
COPTER_DESCENT_RATE = 1.5  # m/s, WPNAV_SPEED_DN / LAND_SPEED_HIGH
COPTER_LAND_RATE = 0.5  # m/s below 10 m, LAND_SPEED
COPTER_WP_DECEL = 2.5  # m/s², a copter's braking for a waypoint (ArduCopter WPNAV_ACCEL 250 cm/s²)
COPTER_CLIMB_ACCEL = 1.0  # m/s², vertical acceleration of a copter climb (SITL: 0 → 2.5 m/s in ~2.5 s)
COPTER_CLIMB_DECEL = 0.55  # m/s², the slow-down before the target altitude (SITL: 2.15 m/s 4 m below it)
COPTER_MIN_CLIMB = 0.3  # m/s, the slowest final approach of a climb
PLANE_LOITER_RADIUS = 80.0  # m, WP_LOITER_RAD of SITL's plane.parm (ArduPlane's own default is 60)
PLANE_L1_PERIOD_S = 15.0  # s, NAVL1_PERIOD of SITL's plane.parm (ArduPlane's own default is 17)
PLANE_ROLL_TCONST_S = 0.25  # s, RLL2SRV_TCONST of SITL's plane.parm: the bank follows its demand with this lag
# SITL's plane turns at ARDUPLANE_TURN_EFFICIENCY of the rate its bank implies (g·tan φ / v). Fitted: with 0.58 the
# L1 law above carries the plane 37 m past the new leg after a 90° turn at 20 m/s (SITL 34-39 m) and flies an 80 m
# loiter at 96.7 m and a 120 m one at 132 m (SITL 96.8 m and 135.5 m); at 1.0 it would be 17 m, 80 m and 120 m.
# NAVL1_DAMPING is ArduPlane's default (ARDUPLANE_L1_DAMPING) in SITL's plane.parm too.
L1_MAX_SINE_ETA1 = 0.7071  # the track's L1 point is at most 45° off the track (ArduPlane caps sin η1 there)
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
    turn_rate: float = 0.0  # rad/s, clockwise, of the last step
    bank: float = 0.0  # rad, right wing down positive (a plane's; a copter's stays 0)

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
        self.on_circle = False  # the last :meth:`circle` step flew the circle itself (not its capture)

    # --- limits ---------------------------------------------------------------------------------------------

    @property
    def airborne_speed(self) -> float:
        return max(self.target_speed, 1.0)

    def _max_vz(self) -> float:
        return max(self.airborne_speed * math.tan(self.vehicle.max_climb), 0.5)

    def _l1_distance(self) -> float:
        """L1 = ζ·P·v/π (m): how far ahead on the track the guidance aims."""
        return max(l1_distance(max(self.state.speed, 1.0), PLANE_L1_PERIOD_S, ARDUPLANE_L1_DAMPING), 1.0)

    def _towards(self, eta: float) -> float:
        """The L1 lateral acceleration (m/s², right positive) for a point ``eta`` rad off the velocity."""
        eta = max(-0.5 * math.pi, min(0.5 * math.pi, eta))
        return 4.0 * ARDUPLANE_L1_DAMPING**2 * self.state.speed**2 / self._l1_distance() * math.sin(eta)

    def _steer(self, lateral: float, dt: float) -> None:
        """Bank towards the demand ``lateral`` (m/s², right positive; limited to the max bank), with the roll
        lag, and turn at the rate that bank gives this plane."""
        s = self.state
        limit = self.vehicle.max_bank
        demand = max(-limit, min(limit, math.atan(lateral / G0)))
        s.bank += (demand - s.bank) * min(dt / PLANE_ROLL_TCONST_S, 1.0)
        s.turn_rate = ARDUPLANE_TURN_EFFICIENCY * G0 * math.tan(s.bank) / max(s.speed, 1.0)
        s.heading = wrap_pi(s.heading + s.turn_rate * dt)

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
            s.bank = 0.0
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
        """Towards ``target``: a plane follows the track origin→target by the L1 law (without an origin, or on a
        track shorter than a metre: it heads for the target); a copter points directly at it and stops there."""
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
                if length > 1.0:  # the L1 point: on the track, L1 from the vehicle, at most 45° off the track
                    ux, uy = lx / length, ly / length
                    along = (s.x - ox) * ux + (s.y - oy) * uy
                    l1 = self._l1_distance()
                    off = min(abs((s.x - ox) * uy - (s.y - oy) * ux), L1_MAX_SINE_ETA1 * l1)
                    ahead = along + math.sqrt(l1 * l1 - off * off)
                    aim_x, aim_y = ox + ux * ahead, oy + uy * ahead
            self._steer(self._towards(wrap_pi(bearing(aim_x - s.x, aim_y - s.y) - s.heading)), dt)
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
        """Plane: circle ``centre`` at ``radius`` by the L1 loiter law: from outside, the L1 capture of the centre
        until the circle's own demand (a PD law on the radius error and the radial speed, plus the centripetal
        term) turns harder; copter: hold over the centre. Sets :attr:`on_circle` (ArduPlane's "loiter target
        reached", which starts a loiter's timer)."""
        s = self.state
        if not self.is_plane:
            self.fly_to((centre[0], centre[1], z_target), None, dt)
            return
        self._cruise(dt)
        side = 1.0 if clockwise else -1.0
        cx, cy = centre
        rx, ry = s.x - cx, s.y - cy
        d = math.hypot(rx, ry)
        ux, uy = (rx / d, ry / d) if d > 0.1 else (-math.sin(s.heading), -math.cos(s.heading))
        omega = 2.0 * math.pi / PLANE_L1_PERIOD_S
        outward = s.vx * ux + s.vy * uy  # radial speed
        tangential = side * (s.vx * uy - s.vy * ux)  # along the circle, in its direction
        error = d - radius
        pd = error * omega**2 + outward * 2.0 * ARDUPLANE_L1_DAMPING * omega
        if outward > 0.0 and tangential < 0.0:  # flying out the wrong way round: never steer away from the centre
            pd = max(pd, 0.0)
        on_circle = side * (pd + tangential**2 / max(0.5 * radius, d))
        capture = self._towards(wrap_pi(bearing(-rx, -ry) - s.heading))
        self.on_circle = not (error > 0.0 and side * capture < side * on_circle)
        self._steer(on_circle if self.on_circle else capture, dt)
        self._hold_altitude(z_target, dt)
        self._advance(dt, turning=True)

    def touch_down(self) -> None:
        s = self.state
        s.z = 0.0
        s.vz = 0.0
        s.speed = 0.0
        s.on_ground = True
