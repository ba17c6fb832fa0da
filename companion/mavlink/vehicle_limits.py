"""The vehicle's own limits, read from the autopilot's parameters at connect (docs/autopilots.md, "Limits read from
the autopilot"), with the scenario's ``[vehicle]`` values as the fallback for anything the autopilot does not say.

The plan and every pattern the companion commands (climb-out, hold circles) are checked with these, not with what
the scenario file assumed: on ArduPlane SITL the scenario's 45° bank and 15° climb were neither what the autopilot
flew (65° roll limit, TECS climb 5 m/s) nor what its loiter circle was (WP_LOITER_RAD 80 m, not the scenario's).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from pymavlink.dialects.v20.common import MAV_AUTOPILOT_PX4 as PX4_AUTOPILOT

from companion.mavlink.profiles import mission_layout
from planner.world.config import G0, VehicleLimits

# name → (what it is, scale to SI). Only what the companion uses; the names are those of the firmware we fly
# (ArduPilot 4.7, PX4 1.17): parameters the autopilot does not answer simply keep the scenario's value.
ARDUPLANE = {
    "ROLL_LIMIT_DEG": ("max_bank_deg", 1.0),
    "AIRSPEED_CRUISE": ("cruise_speed", 1.0),
    "WP_RADIUS": ("acceptance_radius", 1.0),
    "WP_LOITER_RAD": ("loiter_radius", 1.0),
    "TECS_CLMB_MAX": ("climb_rate", 1.0),
    "TECS_SINK_MAX": ("sink_rate", 1.0),
    "NAVL1_PERIOD": ("l1_period_s", 1.0),
    "NAVL1_DAMPING": ("l1_damping", 1.0),
}
ARDUCOPTER = {
    "WPNAV_SPEED": ("cruise_speed", 0.01),  # cm/s
    "WPNAV_RADIUS": ("acceptance_radius", 0.01),  # cm
    "WPNAV_ACCEL": ("accel", 0.01),  # cm/s²
    "WPNAV_SPEED_UP": ("climb_rate", 0.01),
    "WPNAV_SPEED_DN": ("sink_rate", 0.01),
}
PX4_FIXED_WING = {
    "NAV_ACC_RAD": ("acceptance_radius", 1.0),
    "NAV_LOITER_RAD": ("loiter_radius", 1.0),
    "FW_R_LIM": ("max_bank_deg", 1.0),
    "FW_AIRSPD_TRIM": ("cruise_speed", 1.0),
    "FW_T_CLMB_MAX": ("climb_rate", 1.0),
    "FW_T_SINK_MAX": ("sink_rate", 1.0),
    "NPFG_PERIOD": ("npfg_period_s", 1.0),
}
PX4_MULTICOPTER = {
    "NAV_ACC_RAD": ("acceptance_radius", 1.0),
    "MPC_XY_CRUISE": ("cruise_speed", 1.0),
    "MPC_ACC_HOR": ("accel", 1.0),
    "MPC_Z_V_AUTO_UP": ("climb_rate", 1.0),
    "MPC_Z_V_AUTO_DN": ("sink_rate", 1.0),
}
ARDUPLANE_L1_PERIOD_S, ARDUPLANE_L1_DAMPING = 17.0, 0.75  # ArduPlane's defaults when they are not read
# How far ArduPlane swings past a new leg after a turn, per radian of turn and per metre of its L1 distance
# (ζ·P·v/π): measured on SITL at 18-20 m/s, 6.0 m after 21°, 10.4 m after 29°, 14.1 m after 45° and 34-39 m after
# 90° (0.25-0.35 of L1 per radian); the largest ratio is used (docs/design.md, "Turns flown wider than planned")
OVERSHOOT_PER_L1 = 0.35
# ArduPlane SITL's plane turns at this share of the rate its bank implies (g·tan φ / v): with it, the L1 law flies a
# 90° turn 34-39 m past the new leg and an 80 m loiter at 96.8 m, as SITL does (tests/conformance/test_hold_turn.py,
# docs/design.md "The simulator against SITL"). The simulator flies it; the companion's turn envelope covers it.
ARDUPLANE_TURN_EFFICIENCY = 0.58
PX4_NPFG_PERIOD_S = 10.0  # PX4's default NPFG_PERIOD when it is not read
# How far PX4's fixed-wing path-follower (NPFG) swings past a new leg after a turn, m per radian of turn, per second of
# NPFG_PERIOD and m/s of speed: measured on PX4 SITL's SIH standard VTOL at its 10 m/s trim airspeed (NPFG_PERIOD
# 10): 5.0 m/rad after 60°, 5.4 after 45°, 6.6 after 90° (10.4 m), 8.4 after 135° (19.8 m), i.e. 0.050-0.084 of
# period x speed; rounded up (docs/design.md, "Turns flown wider than planned"). One speed only: the airframe flies
# 7-12 m/s
NPFG_OVERSHOOT_PER_PERIOD_SPEED = 0.1
COPTER_ACCEL = 2.5  # m/s², a copter's braking when the autopilot does not say (WPNAV_ACCEL default)


def parameter_names(autopilot: str, vehicle_type: str) -> Mapping[str, tuple[str, float]]:
    """The parameters to read for an autopilot layout ("ardupilot", "px4", "px4-vtol") and vehicle type (a VTOL
    flies its route as a fixed-wing: "plane")."""
    if mission_layout(autopilot).qgc_firmware_type == PX4_AUTOPILOT:
        return PX4_FIXED_WING if vehicle_type == "plane" else PX4_MULTICOPTER
    return ARDUPLANE if vehicle_type == "plane" else ARDUCOPTER


@dataclass(frozen=True)
class AutopilotLimits:
    """What the vehicle will really do: speeds in m/s, angles in degrees, distances in metres."""

    vehicle_type: str
    cruise_speed: float
    max_bank_deg: float
    acceptance_radius: float
    loiter_radius: float
    climb_rate: float
    sink_rate: float
    accel: float
    l1_period_s: float
    l1_damping: float
    read: dict[str, float] = field(default_factory=dict)  # the parameters the autopilot answered, as it sent them
    vertical_takeoff: bool = False  # a VTOL: it climbs vertically where it stands, then transitions
    npfg_period_s: float = PX4_NPFG_PERIOD_S
    # who flies its turns: "l1" (ArduPlane: l1_period_s, l1_damping), "npfg" (a PX4 fixed-wing or VTOL in fixed-wing
    # flight: npfg_period_s), "" (a copter: it turns on the spot)
    path_follower: str = ""

    @property
    def turn_radius(self) -> float:
        """Tightest level turn at cruise speed, v²/(g tan φ_max) (docs/method.md §11.2)."""
        return self.cruise_speed**2 / (G0 * math.tan(math.radians(min(self.max_bank_deg, 85.0))))

    def wide_turn_radius(self, speed: float | None = None) -> float:
        """How wide a plane's path-follower turns onto a track far off its heading: ArduPlane's L1 law commands
        4·damping²·v²/L1 at most, a circle of L1/(4·damping²) with L1 = (1/π)·damping·period·v; never less than the
        tightest turn. A copter turns on the spot (0)."""
        if self.vehicle_type != "plane":
            return 0.0
        v = self.cruise_speed if speed is None else speed
        l1 = l1_distance(v, self.l1_period_s, self.l1_damping)
        return max(l1 / (4.0 * self.l1_damping**2), self.turn_radius)

    def turn_overshoot(self, speed: float | None = None) -> float:
        """How far its path-follower swings past a new leg after a turn, m per radian (VehicleLimits.turn_overshoot),
        at ``speed`` (the mission's; default cruise): :func:`l1_overshoot` for ArduPlane,
        :data:`NPFG_OVERSHOOT_PER_PERIOD_SPEED` of NPFG_PERIOD x speed for a PX4 fixed-wing, 0 for a copter."""
        v = self.cruise_speed if speed is None else speed
        if self.path_follower == "l1":
            return l1_overshoot(v, self.l1_period_s, self.l1_damping)
        return NPFG_OVERSHOOT_PER_PERIOD_SPEED * self.npfg_period_s * v if self.path_follower == "npfg" else 0.0

    @property
    def climb_angle_deg(self) -> float:
        """A plane's steady climb angle at cruise speed from its climb-rate limit."""
        return math.degrees(math.asin(min(self.climb_rate / max(self.cruise_speed, 1e-6), 1.0)))

    @property
    def stopping_distance(self) -> float:
        """A copter's braking distance from cruise speed, v²/(2a)."""
        return self.cruise_speed**2 / (2.0 * max(self.accel, 0.1))

    def summary(self) -> dict[str, float | str | dict[str, float]]:
        """flight.json's ``vehicle_limits``: what was used, and what was read."""
        d: dict[str, float | str | dict[str, float]] = {
            k: round(v, 3) for k, v in self.__dict__.items() if isinstance(v, float)}
        d["turn_radius_m"] = round(self.turn_radius, 1)
        d["turn_overshoot_m_per_rad"] = round(self.turn_overshoot(), 1)
        d["vehicle_type"] = self.vehicle_type
        d["vertical_takeoff"] = self.vertical_takeoff
        d["read"] = dict(self.read)
        return d


def l1_distance(speed: float, period_s: float = ARDUPLANE_L1_PERIOD_S, damping: float = ARDUPLANE_L1_DAMPING) -> float:
    """L1 = ζ·P·v/π (m): how far ahead on its track ArduPlane's L1 law aims."""
    return damping * period_s * speed / math.pi


def l1_overshoot(cruise_speed: float, period_s: float = ARDUPLANE_L1_PERIOD_S,
                 damping: float = ARDUPLANE_L1_DAMPING) -> float:
    """ArduPlane's swing past a new leg, m per radian of turn: :data:`OVERSHOOT_PER_L1` of :func:`l1_distance`."""
    return OVERSHOOT_PER_L1 * l1_distance(cruise_speed, period_s, damping)


def overshoot_override(swing: float) -> str:
    """The ``--set`` override that plans with ``swing`` m per radian, rounded up to 0.1 (never below it)."""
    return f"vehicle.turn_overshoot={math.ceil(swing * 10) / 10:g}"


def flight_overrides(vehicle: VehicleLimits) -> list[str]:
    """``--set`` overrides a plan to be flown needs beyond the scenario's: a plane's turns are flown by a path
    follower that swings past each new leg, so its plan allows at least ArduPlane's default swing at the plan's
    speed (an autopilot that swings wider is found at connect, and the plan made again)."""
    need = l1_overshoot(vehicle.cruise_speed) if vehicle.type == "plane" else 0.0
    return [overshoot_override(need)] if vehicle.turn_overshoot < need else []


def limits_from(params: Mapping[str, float], autopilot: str, vehicle: VehicleLimits,
                loiter_fallback: float) -> AutopilotLimits:
    """The vehicle's limits from the parameters read (``params``: name → value as the autopilot sent it), each
    missing one from the scenario's ``vehicle`` (``loiter_fallback``: the loiter radius when neither says)."""
    names = parameter_names(autopilot, vehicle.type)
    values: dict[str, float] = {
        "cruise_speed": vehicle.cruise_speed, "max_bank_deg": vehicle.max_bank_deg,
        "acceptance_radius": vehicle.acceptance_radius, "loiter_radius": loiter_fallback,
        "climb_rate": vehicle.cruise_speed * math.sin(vehicle.max_climb),
        "sink_rate": vehicle.cruise_speed * math.sin(vehicle.max_climb),
        "accel": COPTER_ACCEL, "l1_period_s": ARDUPLANE_L1_PERIOD_S, "l1_damping": ARDUPLANE_L1_DAMPING,
        "npfg_period_s": PX4_NPFG_PERIOD_S}
    read = {}
    for name, (key, scale) in names.items():
        v = params.get(name)
        if v is not None and math.isfinite(v) and v > 0:
            values[key] = float(v) * scale
            read[name] = float(v)
    return AutopilotLimits(vehicle.type, read=read, vertical_takeoff=mission_layout(autopilot).vtol,
                           path_follower="l1" if names is ARDUPLANE else "npfg" if names is PX4_FIXED_WING else "",
                           **values)
