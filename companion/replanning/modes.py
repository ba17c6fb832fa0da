"""The replanner's mode control (docs/design.md, "Checked holds", "Mode ownership"): hold the vehicle on a checked
pattern, keep that pattern clear of the traffic, resume AUTO, and never fight a mode somebody else chose."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import CommandError
from companion.mission.geo import enu_to_geodetic, to_int_e7
from companion.replanning.context import ReplanContext
from companion.replanning.holds import (
    FLOWN_WIDER_M,
    HOLD_MARGIN_M,
    CircleExit,
    HoldPattern,
    circle_exit,
    circle_traffic_separation,
    copter_hold,
    flown_ring,
    plane_hold,
    ring,
)
from companion.replanning.motion import WIDE_TURNS, VehicleMotion
from companion.replanning.prediction import Prediction
from planner.trajectory.checks import nearest_obstacle
from planner.world.environment import Threats

HOLD_CHECK_WALL_S = 0.5  # wall seconds between two looks for a hold pattern after none was found, and between
# two traffic checks of the circle being held (each takes CPU the planner needs: under load, 30 a second)
# vehicle seconds a plane may fly on straight after a hold is commanded before it turns onto the circle (ArduPlane
# SITL at 10x: ~2 s between the acknowledged DO_REPOSITION and the first change of heading, our latency included)
HOLD_TURN_LAG_S = 2.5
MIN_HOLD_RADIUS_TURNS = 2.0  # the smallest hold circle commanded, in tightest turns (ArduPlane flies it wider)
# the least time beyond planning and upload a plane circles before the exit of its hold circle that its new route
# starts at (docs/design.md, "Leaving a hold")
EXIT_MARGIN_S = 3.0
RESUME_ROLL_OUT_S = 3.0  # vehicle seconds a plane held on a circle may circle on after its resume is checked


@dataclass
class Leaving:
    """A plane's way off its hold circle: the ``exit`` its route is planned from, the mission time it is ``due``
    there and, once that route is live, the item after the exit (``seq``) and the arc still to circle at the last
    look (``left_m``)."""

    exit: CircleExit
    due: float
    seq: int | None = None
    left_m: float | None = None


class ModeControl:
    """Holds and resumes. ``holding``: why the vehicle is held (None: it flies its mission in AUTO)."""

    def __init__(self, ctx: ReplanContext, motion: VehicleMotion, prediction: Prediction) -> None:
        self.ctx, self.motion, self.prediction = ctx, motion, prediction
        self.holding: str | None = None
        self.held_in: str | None = None  # the mode it is held in (GUIDED for a plane's checked circle)
        self.pattern: HoldPattern | None = None  # the checked pattern it holds on
        self.held_since: float | None = None  # mission time the current hold began
        # a plane held on a circle leaves it where its new route starts: the exit being planned, then the one live
        self.planning_exit: Leaving | None = None
        self.exit: Leaving | None = None
        self._paused_in: int | None = None  # a mode we did not command, while replanning is paused
        self._hold_refused_at = -math.inf  # wall time no checked hold pattern was found
        self._route_kept_at = -math.inf  # wall time a late plan's hold was refused for the route being flown
        self._hold_checked_at = -math.inf  # wall time the hold circle was last checked against the traffic

    @property
    def hold_mode(self) -> str:
        return self.ctx.profile.hold_mode

    @property
    def loiter_radius(self) -> float:
        """The radius a plane's hold circles at: the vehicle's WP_LOITER_RAD when read, else the config's."""
        if self.pattern is not None and self.pattern.kind == "circle":
            return self.pattern.radius
        return self.ctx.limits.loiter_radius if self.ctx.limits is not None else self.ctx.cfg.plane_loiter_radius_m

    def in_control(self) -> bool:
        """The vehicle flies our mission in AUTO, or holds in the mode we put it in. Any other mode (the pilot
        took over, a failsafe's RTL) belongs to someone else: the replanner then only watches."""
        mode = self.ctx.state.custom_mode
        if mode is None:
            return True
        ours = self.ctx.mode_number(self.held_in or self.hold_mode) if self.holding is not None \
            else self.ctx.mode_number("AUTO")
        mine = mode == ours
        if not mine and self._paused_in != mode:
            self._paused_in = mode
            self.ctx.events.log("replanning_paused", mode=self.ctx.mode_name(mode))
        elif mine and self._paused_in is not None:
            self._paused_in = None
            self.ctx.events.log("replanning_resumed")
        return mine

    def in_auto(self) -> bool:
        """Not held, and in AUTO as far as the vehicle has said."""
        mode = self.ctx.state.custom_mode
        return self.holding is None and (mode is None or mode == self.ctx.mode_number("AUTO"))

    async def set_mode(self, name: str) -> None:
        custom = self.ctx.mode_number(name)
        await self.ctx.client.command_long(mavlink.MAV_CMD_DO_SET_MODE, *self.ctx.profile.set_mode_params(custom))
        self.ctx.state.custom_mode = custom  # accepted; the next HEARTBEAT will say so too

    # -- holding ------------------------------------------------------------------------------------
    async def hold(self, reason: str, route_separation: float | None = None) -> None:
        """Stop the vehicle advancing through its mission where it is (its profile's ``hold_mode``).
        ``route_separation``: what the route it flies keeps from the traffic (m, predicted; a plan that is only
        late): a circle keeping the traffic less far than that, and the route keeping d_coll, is no hold (on SITL,
        a plan 4 s from an intruder the route passed at 23.9 m: the circle predicted at 22.8 m was flown at 5.0 m)."""
        ctx = self.ctx
        if self.holding is not None:
            return
        mode = ctx.state.custom_mode
        if mode is not None and mode != ctx.mode_number("AUTO"):
            # not flying the mission (a failsafe, the pilot): it cannot step into a mixed item; leave it be
            ctx.events.log("not_holding", reason=reason, mode=ctx.mode_name(mode))
            return
        if time.monotonic() - self._hold_refused_at < HOLD_CHECK_WALL_S or (
                route_separation is not None and time.monotonic() - self._route_kept_at < HOLD_CHECK_WALL_S):
            return  # just refused: checking again takes the CPU the planner needs (under load, 30 checks a second)
        pattern = self.checked_hold()
        if pattern is not None and route_separation is not None and route_separation >= ctx.d_coll \
                and pattern.traffic_separation_m < route_separation:
            # only holds for a late plan wait for the next look: a swap's or the guard's hold is taken
            self._route_kept_at = time.monotonic()
            ctx.events.log("hold_refused", reason=reason, decision=(
                f"the route keeps the traffic further ({route_separation:.1f} m) than the best hold "
                f"({pattern.traffic_separation_m:.1f} m): the vehicle keeps flying it"))
            return
        if pattern is None:
            # no circle clear of the obstacles and the traffic: the leg it flies was cleared when it was planned
            self._hold_refused_at = time.monotonic()
            ctx.events.log("hold_refused", reason=reason, decision="no checked hold pattern: the vehicle keeps "
                           "flying its current, already-cleared leg")
            return
        if pattern.kind == "circle" and ctx.profile.hold_reposition:
            try:
                await self.circle(pattern)
                self.held_in = "GUIDED"
            except (CommandError, AttributeError) as e:  # refused, or a backend without COMMAND_INT
                ctx.events.log("hold_circle_refused", error=str(e), pattern=pattern.summary())
                loiter = self.loiter_here()
                if loiter is None:
                    ctx.events.log("hold_refused", reason=reason, decision="LOITER's own circle is not clear "
                                   "either: the vehicle keeps flying its current, already-cleared leg")
                    return
                pattern = loiter
                await self.set_mode(self.hold_mode)
                self.held_in = self.hold_mode
        else:
            await self.set_mode(self.hold_mode)
            self.held_in = self.hold_mode
        self.pattern = pattern
        self.holding = reason
        self.held_since = ctx.state.now()
        ctx.events.log("hold", mode=self.held_in, reason=reason, pattern=pattern.summary())

    async def recheck_hold(self, now: float, threats: Threats) -> None:
        """While circling a hold of ours: the traffic is checked against the circle again (at most every
        :data:`HOLD_CHECK_WALL_S` wall seconds); a circle that no longer keeps it at d_coll is replaced by a
        checked one that keeps it further (the traffic's prediction changes as it flies)."""
        pattern, position = self.pattern, self.ctx.state.position
        if (pattern is None or pattern.kind != "circle" or self.held_in != "GUIDED" or not len(threats)
                or position is None or time.monotonic() - self._hold_checked_at < HOLD_CHECK_WALL_S):
            return
        self._hold_checked_at = time.monotonic()
        sep = circle_traffic_separation(position, pattern.centre, pattern.radius, pattern.clockwise,
                                        self.motion.flying_speed, now, threats)
        if sep >= self.ctx.d_coll:
            return
        new = self.checked_hold()
        if new is None or new.kind != "circle" or new.traffic_separation_m <= sep:
            self.ctx.events.log("hold_unclear", separation_m=round(sep, 1), pattern=pattern.summary(),
                                note="no other checked circle keeps the traffic further")
            return
        try:
            await self.circle(new)
        except (CommandError, AttributeError) as e:
            self.ctx.events.log("hold_circle_refused", error=str(e), pattern=new.summary())
            return
        self.pattern = new
        self.exit = None  # on another circle: planned again from it
        self.ctx.events.log("hold_moved", separation_m=round(sep, 1), pattern=new.summary())

    def checked_hold(self) -> HoldPattern | None:
        """The hold pattern for where the vehicle is now, checked against the static world and the traffic
        (:mod:`companion.replanning.holds`): a plane on ArduPilot circles a centre and radius of ours, a PX4 VTOL its
        own loiter around where it is (profile ``hold_reposition``); any other vehicle stops (its stopping run
        checked, and flown whatever the verdict: stopping is a copter's safest move). None: no circle is clear (or,
        for a circling vehicle, no position to check one from)."""
        ctx, state, motion = self.ctx, self.ctx.state, self.motion
        if ctx.profile.hold_circles:
            if state.position is None:
                return None
            if not ctx.profile.hold_reposition:  # PX4 VTOL: its own loiter around where it is
                return self.loiter_here()
            now = state.now()
            speed = motion.flying_speed
            return plane_hold(state.position, state.velocity, self.loiter_radius, ctx.scenario.environment,
                              ctx.d_coll, speed, self.prediction.threats(now), now,
                              min_radius=MIN_HOLD_RADIUS_TURNS * motion.turn_radius(),
                              turn_radius=WIDE_TURNS * motion.wide_turn_radius(speed),
                              lag_m=HOLD_TURN_LAG_S * speed)
        if state.position is None:
            return HoldPattern("brake", np.zeros(3), 0.0, True, np.zeros((1, 3)), math.inf, None, math.inf)
        env = ctx.scenario.environment
        cruise = ctx.scenario.vehicle.cruise_speed
        stop = ctx.limits.stopping_distance if ctx.limits is not None else cruise ** 2 / 5.0
        speed_share = min(state.groundspeed / max(cruise, 0.1), 1.0) ** 2
        pattern = copter_hold(state.position, state.velocity, stop * speed_share, env, ctx.d_coll)
        if pattern.clearance_m < ctx.d_coll:
            ctx.events.log("hold_unclear", pattern=pattern.summary(),
                           note="the stopping run comes within d_coll; stopping is still the safest move")
        return pattern

    async def circle(self, pattern: HoldPattern) -> None:
        """ArduPlane: MAV_CMD_DO_REPOSITION (COMMAND_INT: ArduPlane answers it UNSUPPORTED as COMMAND_LONG) with
        MAV_DO_REPOSITION_FLAGS_CHANGE_MODE (GUIDED) at the pattern's centre, altitude above home, and radius
        (param3), clockwise unless param4 is set."""
        lat, lon, _ = enu_to_geodetic(np.array([pattern.centre[0], pattern.centre[1], 0.0]), self.ctx.scenario.home)
        await self.ctx.client.command_int(mavlink.MAV_CMD_DO_REPOSITION, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                          -1.0, 1.0, float(pattern.radius), 0.0 if pattern.clockwise else 1.0,
                                          x=to_int_e7(float(lat)), y=to_int_e7(float(lon)), z=float(pattern.centre[2]))
        self.ctx.state.custom_mode = self.ctx.mode_number("GUIDED")

    def loiter_here(self) -> HoldPattern | None:
        """The autopilot's own LOITER (a circle of the loiter radius around where the mode changes), when that
        circle is clear of the obstacles: the fallback when our circle cannot be commanded."""
        assert self.ctx.state.position is not None
        centre = self.ctx.state.position.copy()
        circle = np.vstack([ring(centre, self.loiter_radius, centre[2]),  # as asked, and as ArduPlane flies it
                            flown_ring(centre, self.loiter_radius, centre[2])])
        clearance, worst = nearest_obstacle(circle, self.ctx.scenario.environment)
        if clearance < self.ctx.d_coll + HOLD_MARGIN_M:
            return None
        return HoldPattern("circle", centre, self.loiter_radius, True, circle, clearance, worst, math.inf)

    async def resume(self) -> None:
        """Back to AUTO at the current item, unless someone else has changed the mode meanwhile. AUTO is not
        someone else's: an autopilot may acknowledge the hold before its HEARTBEAT shows it (PX4 does: a stale
        AUTO arrived between the hold and the resume and left the vehicle holding for good), and a pilot who put
        it back in AUTO wants the mission flown; AUTO is sent either way."""
        ctx, mode = self.ctx, self.ctx.state.custom_mode
        if mode is not None and mode not in (ctx.mode_number(self.held_in or self.hold_mode), ctx.mode_number("AUTO")):
            ctx.events.log("not_resuming", reason="the mode was changed by someone else", mode=ctx.mode_name(mode))
            self._released()
            return
        await self.set_mode("AUTO")
        ctx.events.log("resume", reason=self.holding, seq=ctx.state.current_seq)
        self._released()

    def _released(self) -> None:
        self.holding = self.held_in = self.pattern = self.exit = None

    # -- leaving a hold -----------------------------------------------------------------------------
    def rejoin_delays(self) -> np.ndarray:
        """Vehicle seconds a vehicle resumed now may take to be flying its route again: none when it is not
        held or stops dead (a copter in BRAKE); for a plane circling in LOITER, anything up to one circle,
        which is why a hold that merely delays a plane by a few seconds must not look like a cleared threat."""
        if self.holding is None or not self.ctx.profile.hold_circles:
            return np.zeros(1)
        step = self.ctx.cfg.rejoin_step_s
        circle = 2.0 * math.pi * self.loiter_radius / self.prediction.speed
        held = self.ctx.state.now() - self.held_since if self.held_since is not None else circle
        # having turned away for ``held`` seconds it needs about as long to turn back; never more than a circle
        longest = min(circle, 2.0 * held + step)
        return np.arange(0.0, longest + step, step)

    def rolling_out(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """Where a plane may start its turn back to the route from, with its velocity: where it is now, and, held on
        a circle, where it is after circling on for :data:`RESUME_ROLL_OUT_S` (the resume's latency and the roll
        out of the circle's bank; on the simulator flying ArduPlane's L1 law, a plane resumed at heading 340° from
        a counter-clockwise hold was still turning left at 316° when it rolled out, and its right turn back to the
        route, predicted 25-66 m clear of a cylinder from where the resume was checked, came 0.6 m from it)."""
        state = self.ctx.state
        assert state.position is not None
        here = [(state.position, state.velocity)]
        pattern = self.pattern
        speed = float(np.linalg.norm(state.velocity))
        if pattern is None or pattern.kind != "circle" or speed < 1.0:
            return here
        turn = (1.0 if pattern.clockwise else -1.0) * speed / (pattern.radius + FLOWN_WIDER_M)  # rad/s, right +
        pos, vel, dt = state.position.copy(), np.asarray(state.velocity, dtype=float).copy(), 0.25
        for _ in range(round(RESUME_ROLL_OUT_S / dt)):
            a = -turn * dt  # a right (clockwise) turn rotates the ENU velocity clockwise
            vel = np.array([vel[0] * math.cos(a) - vel[1] * math.sin(a), vel[0] * math.sin(a) + vel[1] * math.cos(a)])
            pos = pos + np.array([vel[0] * dt, vel[1] * dt, 0.0])
        return [*here, (pos, vel)]

    def hold_exit(self, budget_s: float, toward: np.ndarray, upload_wall_s: float) -> CircleExit | None:
        """Where a plane circling its hold will leave it for a route planned now within ``budget_s`` towards
        ``toward``: far enough round the circle it flies that the plan and its upload (``upload_wall_s`` each) are
        done first (:func:`circle_exit`). None when it is not circling a hold of ours (a copter, a hold not yet
        captured: it is planned from where it is)."""
        pattern, state = self.pattern, self.ctx.state
        position, velocity = state.position, state.velocity
        if pattern is None or pattern.kind != "circle" or not self.ctx.profile.hold_circles \
                or position is None or float(np.linalg.norm(velocity)) < 1.0:
            return None
        if abs(float(np.linalg.norm(position[:2] - pattern.centre[:2])) - pattern.radius) > 1.5 * FLOWN_WIDER_M:
            return None  # still joining its circle
        out = position[:2] - pattern.centre[:2]
        if (float(out[0] * velocity[1] - out[1] * velocity[0]) < 0.0) != pattern.clockwise:
            return None  # circling the other way than the pattern says (an autopilot's own loiter): not trusted
        wall = budget_s + 2.0 * (upload_wall_s + self.ctx.cfg.check_interval_wall_s)
        lead = (wall * state.clock.rate + EXIT_MARGIN_S) * self.motion.flying_speed
        return circle_exit(position, pattern.centre, pattern.clockwise, toward, lead)
