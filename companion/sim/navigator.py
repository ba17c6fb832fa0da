"""Mission execution of the simulated autopilot: ArduPilot's ``AP_Mission`` in miniature.

One NAV command is active at a time, as a :class:`NavTask` built from a *copy* of the stored item, so a mission
re-uploaded in flight does not change it: the vehicle keeps flying the old target until the task ends (then the
next NAV command is taken from the stored mission as it is now) or until :meth:`Navigator.start` restarts an
item (MAV_CMD_DO_SET_MISSION_CURRENT, MISSION_SET_CURRENT or re-entering AUTO). DO_JUMP repeats param2 times
(-1: for ever) when the search for the next NAV command passes it.

As ArduPilot 4.7 does (SITL, plane and copter, a mission TAKEOFF, DO, WP, DO, WP, DO, DO, WP):

- DO commands run (instantly here) when the search for the next NAV command passes them: those between two NAV
  commands run when the first one *completes*, not while it is flown (a DO_CHANGE_SPEED after the TAKEOFF does
  not change the take-off; "Mission: 2 ChangeSpeed" comes with "Takeoff complete");
- each command started is announced with STATUSTEXT "Mission: <seq> <name>";
- MISSION_ITEM_REACHED is one pending slot per link, written by each completed command: a NAV command followed
  by DO commands is not reported (the first DO, completed in the same loop, replaces it); each DO is.

The tasks are also used by the flight modes (RTL, LOITER, LAND, TAKEOFF).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.items import MissionItem
from companion.sim.flight_model import PLANE_LOITER_RADIUS, FlightModel
from companion.sim.mission_server import is_nav

logger = logging.getLogger(__name__)

Point = tuple[float, float, float]
MAX_ACCEPTANCE = 255.0  # m, ArduPlane caps the per-item acceptance radius
PLANE_RTL_ALT = 100.0  # m, ALT_HOLD_RTL default
COPTER_RTL_ALT = 15.0  # m, RTL_ALT default
COPTER_WP_RADIUS = 2.0  # m, WPNAV_RADIUS: ArduCopter does not store a waypoint's own radius (param2)
PLANE_TAKEOFF_DELAY_S = 0.6  # s from arming to the ground roll (TKOFF_THR_DELAY 0.2 s, then throttle up)
COPTER_SPOOL_S = 1.0  # s from the start of a take-off to lift-off (motor spool-up), ArduCopter SITL
COPTER_TAKEOFF_DONE_M = 0.3  # m below the take-off altitude at which ArduCopter counts it reached
GLIDE_SLOPE_MIN_ALT_M = 20.0  # m above home: ArduPlane glides between waypoint altitudes above it (or descending)
# AP_Mission's short names for the STATUSTEXT "Mission: <seq> <name>" (WP, Takeoff, ChangeSpeed seen on SITL)
COMMAND_NAMES = {
    mavlink.MAV_CMD_NAV_WAYPOINT: "WP", mavlink.MAV_CMD_NAV_TAKEOFF: "Takeoff",
    mavlink.MAV_CMD_DO_CHANGE_SPEED: "ChangeSpeed", mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: "RTL",
    mavlink.MAV_CMD_NAV_LAND: "Land", mavlink.MAV_CMD_NAV_LOITER_UNLIM: "LoitUnlim",
    mavlink.MAV_CMD_NAV_LOITER_TIME: "LoitTime", mavlink.MAV_CMD_NAV_LOITER_TURNS: "LoitTurns",
    mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT: "SplineWP", mavlink.MAV_CMD_DO_JUMP: "Jump",
    mavlink.MAV_CMD_DO_SET_SERVO: "SetServo", mavlink.MAV_CMD_DO_SET_RELAY: "SetRelay",
    mavlink.MAV_CMD_CONDITION_DELAY: "CondDelay", mavlink.MAV_CMD_DO_SET_HOME: "SetHome",
}


class NavTask:
    """One navigation activity; :meth:`step` advances the model and returns True when the task is complete."""

    note: str | None = None  # STATUSTEXT to send on completion

    def step(self, model: FlightModel, dt: float) -> bool:
        raise NotImplementedError


class Takeoff(NavTask):
    """Plane: a ground roll and a climb straight ahead on the current heading, done at the altitude ("Takeoff
    complete at 50.43m"); copter: spool up, then climb vertically."""

    def __init__(self, z: float) -> None:
        self.z = z
        self._t = 0.0

    def step(self, model: FlightModel, dt: float) -> bool:
        s = model.state
        if model.is_plane:
            if s.z >= self.z and not s.on_ground:
                self.note = f"Takeoff complete at {s.z:.2f}m"
                return True
            self._t += dt
            if s.on_ground:
                if self._t < PLANE_TAKEOFF_DELAY_S:
                    model.stay()
                else:
                    model.takeoff_roll(dt)
            else:
                model.climb_straight(dt)
            return False
        if s.z >= self.z - COPTER_TAKEOFF_DONE_M:
            return True
        self._t += dt
        if s.on_ground and self._t < COPTER_SPOOL_S:
            model.stay()
        else:
            model.vertical(self.z, dt)
        return False


class Waypoint(NavTask):
    """Fly to a point; done within ``radius`` (plane: horizontal distance, or past the finish line through the
    waypoint at right angles to the track; copter: 3-D distance, then ``hold`` seconds)."""

    def __init__(self, seq: int, target: Point, origin: tuple[float, float], radius: float, hold: float = 0.0,
                 origin_z: float | None = None) -> None:
        self.seq, self.target, self.origin, self.radius, self.hold = seq, target, origin, radius, hold
        self.origin_z = origin_z  # the leg's starting altitude (the previous target's, or where it was)
        self._glide: bool | None = None
        self._held = 0.0

    def _glide_z(self, model: FlightModel) -> float:
        """ArduPlane's altitude target in AUTO (setup_glide_slope): above 20 m, or when descending, it is
        interpolated along the leg from the origin's altitude to the target's, not the target's at once (a
        descent flown as fast as the sink limit allows came 6 m from a sphere that the leg itself clears by
        15 m)."""
        s = model.state
        tx, ty, tz = self.target
        if self._glide is None:
            self._glide = self.origin_z is not None and (s.z > GLIDE_SLOPE_MIN_ALT_M or tz < s.z)
        if not self._glide or self.origin_z is None:
            return tz
        ox, oy = self.origin
        lx, ly = tx - ox, ty - oy
        length2 = lx * lx + ly * ly
        if length2 <= 1.0:
            return tz
        share = min(max(((s.x - ox) * lx + (s.y - oy) * ly) / length2, 0.0), 1.0)
        return self.origin_z + (tz - self.origin_z) * share

    def step(self, model: FlightModel, dt: float) -> bool:
        s = model.state
        tx, ty, tz = self.target
        if model.is_plane:
            model.fly_to((tx, ty, self._glide_z(model)), self.origin, dt)
            dist = math.hypot(tx - s.x, ty - s.y)
            if dist <= self.radius:
                self.note = f"Reached waypoint #{self.seq} dist {dist:.0f}m"
                return True
            ox, oy = self.origin
            lx, ly = tx - ox, ty - oy
            if lx * lx + ly * ly > 1.0 and (s.x - tx) * lx + (s.y - ty) * ly > 0.0:
                self.note = f"Passed waypoint #{self.seq} dist {dist:.0f}m"
                return True
            return False
        if self._held > 0.0 or math.dist((s.x, s.y, s.z), self.target) <= self.radius:
            model.stay()
            self._held += dt
            if self._held >= self.hold:
                self.note = f"Reached command #{self.seq}"
                return True
            return False
        model.fly_to(self.target, None, dt)
        return False


class Loiter(NavTask):
    """Circle (plane) or hover (copter) at a point; ``duration`` None = unlimited."""

    def __init__(self, centre: Point, radius: float, clockwise: bool = True, duration: float | None = None) -> None:
        self.centre, self.radius, self.clockwise, self.duration = centre, radius, clockwise, duration
        self._elapsed: float | None = None

    def step(self, model: FlightModel, dt: float) -> bool:
        s = model.state
        cx, cy, cz = self.centre
        model.circle((cx, cy), self.radius, cz, self.clockwise, dt)
        arrived = model.on_circle if model.is_plane else math.hypot(s.x - cx, s.y - cy) <= 2.0
        if self._elapsed is None and arrived:
            self._elapsed = 0.0
        if self._elapsed is not None:
            self._elapsed += dt
        return self.duration is not None and self._elapsed is not None and self._elapsed >= self.duration


class Land(NavTask):
    """Plane: glide at the climb-angle limit towards the point and touch down; copter: fly there, descend."""

    def __init__(self, target: tuple[float, float], origin: tuple[float, float]) -> None:
        self.target, self.origin = target, origin
        self._passed = False

    def step(self, model: FlightModel, dt: float) -> bool:
        s = model.state
        tx, ty = self.target
        dist = math.hypot(tx - s.x, ty - s.y)
        if model.is_plane:
            glide_z = 0.9 * dist * math.tan(model.vehicle.max_climb)
            ox, oy = self.origin
            self._passed = self._passed or (s.x - tx) * (tx - ox) + (s.y - ty) * (ty - oy) > 0.0
            if self._passed:
                model.straight(-1.0, dt)
            else:
                model.fly_to((tx, ty, min(s.z, glide_z) - 0.5), self.origin, dt)
        elif dist > 1.0:
            model.fly_to((tx, ty, s.z), None, dt)
        else:
            model.vertical(0.0, dt)
        if s.z <= 0.05:
            model.touch_down()
            self.note = "Land complete"
            return True
        return False


class ReturnHome(NavTask):
    """Fly home at the RTL altitude. Plane: done on arrival (mission) or circles home for ever (mode);
    copter: done on arrival (mission item) or lands there (mode and mission item both land, as ArduCopter)."""

    def __init__(self, origin: tuple[float, float], radius: float, z: float, for_ever: bool,
                 home: tuple[float, float] = (0.0, 0.0)) -> None:
        self.origin, self.radius, self.z, self.for_ever, self.home = origin, radius, z, for_ever, home
        self._phase: NavTask | None = None

    def step(self, model: FlightModel, dt: float) -> bool:
        s = model.state
        hx, hy = self.home
        off = math.hypot(s.x - hx, s.y - hy)
        if self._phase is not None:
            return self._phase.step(model, dt) and not self.for_ever
        if model.is_plane:
            model.fly_to((hx, hy, self.z), self.origin, dt)
            if off <= max(self.radius, PLANE_LOITER_RADIUS):
                self.note = "Reached RTL location"
                if not self.for_ever:
                    return True
                self._phase = Loiter((hx, hy, self.z), PLANE_LOITER_RADIUS)
            return False
        if s.z < self.z - 0.5 and off > 2.0:
            model.vertical(self.z, dt)
        elif off > 1.0:
            model.fly_to((hx, hy, max(s.z, self.z)), None, dt)
        else:
            self._phase = Land((hx, hy), (s.x, s.y))
            self.for_ever = False
        return False


def rtl_altitude(model: FlightModel) -> float:
    return max(model.state.z, PLANE_RTL_ALT if model.is_plane else COPTER_RTL_ALT)


class NavigatorEvents(Protocol):
    def reached(self, seq: int, report: bool = True) -> None: ...
    def text(self, severity: int, text: str) -> None: ...
    def current_changed(self, seq: int) -> None: ...
    def mission_complete(self) -> None: ...
    def landed(self) -> None: ...


class Navigator:
    """Runs the stored mission (item 0 = home is never flown)."""

    def __init__(self, model: FlightModel, to_enu: Callable[[MissionItem], Point], events: NavigatorEvents,
                 home: tuple[float, float] = (0.0, 0.0)) -> None:
        self.model = model
        self.home = home  # where RTL returns to, m in the frame
        self._to_enu = to_enu
        self._events = events
        self.current_seq = 0
        self.running = False
        self.task: NavTask | None = None
        self.active: MissionItem | None = None  # the copy being flown
        self._jumps: dict[int, int] = {}
        self._last_target: tuple[float, float, float] | None = None

    # --- control --------------------------------------------------------------------------------------------

    def start(self, mission: list[MissionItem], seq: int | None = None) -> None:
        """Start (or restart) at ``seq``, default the current item (≥ 1); the leg starts where the vehicle is."""
        first = max(1, self.current_seq if seq is None else seq)
        if first >= len(mission):
            first = 1
        if first == 1:
            self._jumps.clear()
        self.running = True
        self._last_target = None
        self._begin(mission, first)

    def stop(self) -> None:
        """Leave AUTO: the active task is dropped; :meth:`start` resumes at the current item."""
        self.running = False
        self.task = None
        self.active = None

    def step(self, mission: list[MissionItem], dt: float) -> None:
        if not self.running or self.task is None or self.active is None:
            return
        if not self.task.step(self.model, dt):
            return
        done, task = self.active, self.task
        if task.note:
            self._events.text(mavlink.MAV_SEVERITY_INFO, task.note)
        following = mission[done.seq + 1] if done.seq + 1 < len(mission) else None
        do_follows = following is not None and not is_nav(following.command) \
            and following.command != mavlink.MAV_CMD_DO_JUMP
        self._events.reached(done.seq, report=not do_follows)  # else the DO's REACHED replaces it
        if isinstance(task, (Land, ReturnHome)) and self.model.state.on_ground:
            self.running = False
            self.task = None
            self._events.landed()
            return
        if isinstance(task, Waypoint):
            self._last_target = (task.target[0], task.target[1], task.target[2])
        self._begin(mission, done.seq + 1)

    # --- internals ------------------------------------------------------------------------------------------

    def _begin(self, mission: list[MissionItem], seq: int) -> None:
        """Find the next NAV command from ``seq`` (following DO_JUMPs), running the DO commands on the way, and
        start it."""
        for _ in range(10 * len(mission) + 10):
            if seq >= len(mission):
                self._complete()
                return
            item = mission[seq]
            if item.command == mavlink.MAV_CMD_DO_JUMP:
                left = self._jumps.setdefault(seq, int(item.param2))
                if left != 0 and 1 <= int(item.param1) < len(mission):
                    if left > 0:
                        self._jumps[seq] = left - 1
                    seq = int(item.param1)
                else:
                    seq += 1
                continue
            if is_nav(item.command):
                break
            self._do(item)
            seq += 1
        else:
            self._complete()
            return
        self._announce(item)
        self.active = item
        self.task = self._task_for(item)
        self.current_seq = seq
        self._events.current_changed(seq)

    def _announce(self, item: MissionItem) -> None:
        name = COMMAND_NAMES.get(item.command) or mavlink.enums["MAV_CMD"][item.command].name.split("_")[-1].title()
        self._events.text(mavlink.MAV_SEVERITY_INFO, f"Mission: {item.seq} {name}")

    def _complete(self) -> None:
        self.running = False
        self.task = None
        self.active = None
        self._jumps.clear()
        self._events.mission_complete()

    def _do(self, item: MissionItem) -> None:
        self._announce(item)
        if item.command == mavlink.MAV_CMD_DO_CHANGE_SPEED and item.param2 > 0.0:
            self.model.target_speed = float(item.param2)
            self._events.text(mavlink.MAV_SEVERITY_INFO, f"Set airspeed {item.param2:g} m/s" if item.param1 == 0
                              else f"Set groundspeed {item.param2:g}")
        self._events.reached(item.seq)

    def _task_for(self, item: MissionItem) -> NavTask:
        s = self.model.state
        here = (s.x, s.y)
        origin = self._last_target[:2] if self._last_target is not None else here
        origin_z = self._last_target[2] if self._last_target is not None else s.z
        x, y, z = self._to_enu(item)
        if self.model.is_plane:  # the item's own radius (whole metres, ≤ 255), else WP_RADIUS
            radius = item.param2 if item.param2 > 0.0 else self.model.vehicle.acceptance_radius
            radius = min(radius, MAX_ACCEPTANCE)
        else:
            radius = COPTER_WP_RADIUS
        cmd = item.command
        if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
            return Takeoff(z)
        if cmd in (mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT):
            return Waypoint(item.seq, (x, y, z), origin, radius, hold=max(item.param1, 0.0), origin_z=origin_z)
        if cmd in (mavlink.MAV_CMD_NAV_LOITER_UNLIM, mavlink.MAV_CMD_NAV_LOITER_TIME,
                   mavlink.MAV_CMD_NAV_LOITER_TURNS):
            loiter_radius = abs(item.param3) if item.param3 else PLANE_LOITER_RADIUS
            duration = None
            if cmd == mavlink.MAV_CMD_NAV_LOITER_TIME:
                duration = max(item.param1, 0.0)
            elif cmd == mavlink.MAV_CMD_NAV_LOITER_TURNS:
                duration = max(item.param1, 0.0) * 2 * math.pi * loiter_radius / self.model.airborne_speed
            return Loiter((x, y, z), loiter_radius, clockwise=item.param3 >= 0.0, duration=duration)
        if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            return ReturnHome(here, self.model.vehicle.acceptance_radius, rtl_altitude(self.model),
                              for_ever=False, home=self.home)
        if cmd == mavlink.MAV_CMD_NAV_LAND:
            return Land((x, y), origin)
        return Waypoint(item.seq, (x, y, z), origin, radius, origin_z=origin_z)
