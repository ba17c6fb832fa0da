"""How this vehicle flies, for the replanner's checks (docs/design.md, "Live replanning"): its turn radii at the
speed it flies, how early it may take an item, and the paths its path-follower may fly along a route."""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from typing import TypedDict

import numpy as np

from companion.mavlink.vehicle_limits import ARDUPLANE_TURN_EFFICIENCY
from companion.replanning.context import ReplanContext
from companion.replanning.guard import GUARD_DT_S, predict_own_path
from planner.world.config import G0


class HeightResponse(TypedDict, total=False):
    """:func:`predict_own_path`'s height arguments (none: instant)."""

    climb_rate: float
    sink_rate: float
    height_lag_s: float

# how much wider than its path-follower's bound (AutopilotLimits.wide_turn_radius) a plane may turn (flown_paths,
# and onto a hold circle): resuming, ArduPlane SITL at 23.5 m/s turned back from a hold at 58 m against the L1
# law's 37 m, then flew straight at the item from there, 22.7 m into a cylinder the path predicted at 37 m cleared.
# SITL's plane turns at ARDUPLANE_TURN_EFFICIENCY (0.58) of the rate its bank implies, so up to 1/0.58 = 1.72 times
# wider; with 1.6, the simulator flying that came 6.5 m from a cylinder on resuming (crossing_traffic, 1 of 10)
WIDE_TURNS = 1.05 / ARDUPLANE_TURN_EFFICIENCY
# vehicle seconds a plane's height lags the height its TECS demands (first order, beside the climb and sink rate
# limits): fitted to 40 ArduPlane SITL flights at 10x (rescue_dynamic and crossing_traffic, with and without replans,
# holds left out), the flown height is matched with an rms of 3.1-3.3 m and at worst 8 m for 2-3 s, against 12-15 m
# at worst with no lag; replanned routes that climb at the limit were flown up to 25 m below the demand
TECS_LAG_S = 2.5


class VehicleMotion:
    """The vehicle's turns and paths, from its measured ground speed and its limits (read, else the scenario's)."""

    def __init__(self, ctx: ReplanContext) -> None:
        self.ctx = ctx

    @property
    def flying_speed(self) -> float:
        """The speed it flies turns and circles at: its ground speed, at least the cruise speed (a plane slowed
        by a climb, or a vehicle not yet up to speed, still turns as wide as at cruise)."""
        return max(self.ctx.state.groundspeed, self.ctx.scenario.vehicle.cruise_speed)

    def turn_radius(self) -> float:
        """The vehicle's tightest turn at its ground speed (its roll limit when read, else the scenario's bank)."""
        limits = self.ctx.limits
        bank = math.radians(limits.max_bank_deg if limits is not None else self.ctx.scenario.vehicle.max_bank_deg)
        return self.flying_speed ** 2 / (G0 * math.tan(bank))

    def wide_turn_radius(self, speed: float) -> float:
        """How wide a plane's path-follower turns onto a track far off its heading (AutopilotLimits.wide_turn_radius;
        twice the tightest turn without read limits), never less than the tightest turn."""
        limits = self.ctx.limits
        wide = limits.wide_turn_radius(speed) if limits is not None else 2.0 * self.turn_radius()
        return max(wide, self.turn_radius())

    def switch_m(self) -> float:
        """How far before a waypoint the vehicle may count it reached (ArduPlane switches early)."""
        return max(self.ctx.scenario.vehicle.acceptance_radius, self.ctx.profile.early_switch_m)

    def height_response(self) -> HeightResponse:
        """How a plane's height follows its demand (:func:`predict_own_path`'s ``climb_rate``, ``sink_rate`` and
        ``height_lag_s``): its TECS limits when read, else the scenario's climb angle at cruise, lagging by
        :data:`TECS_LAG_S`. A copter's is left instant."""
        if not self.ctx.profile.hold_circles:
            return {}
        limits, vehicle = self.ctx.limits, self.ctx.scenario.vehicle
        steady = vehicle.cruise_speed * math.sin(vehicle.max_climb)
        return {"climb_rate": limits.climb_rate if limits is not None else steady,
                "sink_rate": limits.sink_rate if limits is not None else steady, "height_lag_s": TECS_LAG_S}

    def flown_paths(self, position: np.ndarray, velocity: np.ndarray, origin: np.ndarray, targets: np.ndarray,
                    radius: float, horizon_s: float, dt: float = GUARD_DT_S, direct: bool = False,
                    behind: bool = False, climbing: float = 0.0) -> Iterator[np.ndarray]:
        """The paths the vehicle may fly along ``targets`` (:func:`predict_own_path`), one at a time (a check that
        finds a breach stops predicting). A plane's path-follower is not modelled closely enough for one: it may
        turn as wide as ``radius`` or WIDE_TURNS times it, take each item at its acceptance radius or as early as
        ArduPlane switches, and (``behind``: its item behind it) turn round either way; its height lags its demand
        (:meth:`height_response`; ``climbing``: its climb rate now, m/s). A copter (no circles) has one."""
        accept = self.ctx.scenario.vehicle.acceptance_radius
        plane = self.ctx.profile.hold_circles
        radii = (radius, WIDE_TURNS * radius) if plane else (radius,)
        accepts = tuple(dict.fromkeys((accept, self.switch_m()))) if plane else (accept,)
        senses = (-1, 1) if plane and behind else (0,)
        height = self.height_response()
        for r, a, sense in itertools.product(radii, accepts, senses):
            yield predict_own_path(position, velocity, origin, targets, r, a, horizon_s=horizon_s, dt=dt,
                                   direct=direct, sense=sense, climbing=climbing, **height)
