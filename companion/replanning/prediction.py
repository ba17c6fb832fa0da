"""The replanner's traffic picture and its predictions (docs/design.md, "Live replanning"): ADS-B tracks and
scripted threats on mission time, the pace the vehicle actually flies its route at, and the conflicts and
separations of a route flown from now."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from companion.mavlink.link import Message, received_at
from companion.mission import picture
from companion.replanning.context import ReplanContext
from companion.replanning.threats import Conflict, TrackPicture, predict_conflicts, route_separations
from planner.world.environment import Threats

CONTACTS_EVERY_S = 0.25  # wall seconds between two ``contacts`` records (the status page's traffic picture)
CONTACT_PATH_S = 60.0  # vehicle seconds of each contact's predicted path in a ``contacts`` record
PACE_TAU_S = 8.0  # vehicle seconds over which the ground speed along the route is smoothed


class Prediction:
    """Tracks and predictions, fed by the vehicle state's messages. ``flying_route()``: whether the vehicle flies
    its route in AUTO now (only then is its ground speed its pace along the route)."""

    def __init__(self, ctx: ReplanContext, flying_route: Callable[[], bool]) -> None:
        self.ctx = ctx
        self.tracks = TrackPicture(ctx.scenario.home)
        self.pace: float | None = None  # smoothed ground speed along the route (m/s), once measured
        self._flying_route = flying_route
        self._pace_t: float | None = None  # vehicle time of the last ground speed
        self._announced: set[int] = set()
        self._contacts_at = -math.inf  # wall time of the last ``contacts`` record
        ctx.state.listen(self._observe)

    def _observe(self, msg: Message) -> None:
        kind = msg.get_type()
        state = self.ctx.state
        if kind == "GLOBAL_POSITION_INT":
            self._track_pace(state.groundspeed, msg.time_boot_ms / 1000.0)
        elif kind == "ADSB_VEHICLE" and state.mission_t0 is not None:
            heard = state.at(received_at(msg))
            if self.tracks.update(msg, heard) is not None and msg.ICAO_address not in self._announced:
                self._announced.add(msg.ICAO_address)
                self.ctx.events.log("track", id=f"adsb-{msg.ICAO_address:06x}", callsign=str(msg.callsign))

    def threats(self, now: float) -> Threats:
        """Scripted threats (mission-time laws) and live ADS-B tracks."""
        cfg = self.ctx.cfg
        for tid in self.tracks.expire(now, cfg.track_max_age_s):
            self.ctx.events.log("track_expired", id=tid)
        return self.tracks.threats(now, cfg.track_radius_m, cfg.track_growth_m_s, self.ctx.scenario.environment.threats)

    @property
    def speed(self) -> float:
        """Speed for ETAs along the route: the vehicle's own pace over the ground while it flies the route in
        AUTO (:meth:`_track_pace`), the commanded cruise speed until that is known. ArduPlane SITL asked for
        18 m/s airspeed flies 19.2 m/s over the ground: predicted at cruise speed, a conflict 20 s ahead
        was 25 m out, more than the margin (measured on crossing_traffic)."""
        return self.pace if self.pace is not None else self.ctx.scenario.vehicle.cruise_speed

    def _track_pace(self, groundspeed: float, t_vehicle: float) -> None:
        """Smooth the ground speed over :data:`PACE_TAU_S`, starting from cruise, while flying the route in AUTO
        (not in a hold or the climb-out); each sample kept within ±30 % of cruise."""
        cruise = self.ctx.scenario.vehicle.cruise_speed
        last, self._pace_t = self._pace_t, t_vehicle
        if last is None or t_vehicle <= last or not self._flying_route():
            return
        v = float(np.clip(groundspeed, 0.7 * cruise, 1.3 * cruise))
        keep = math.exp(-(t_vehicle - last) / PACE_TAU_S)
        # from cruise, not from the first sample: a plane joining its route is still levelling off and turning,
        # and a jump of the pace would move every predicted conflict (1 m/s over 30 s: 30 m) at once
        self.pace = keep * (cruise if self.pace is None else self.pace) + (1.0 - keep) * v

    def conflicts(self, route: np.ndarray, now: float, threats: Threats, delays: np.ndarray) -> list[Conflict]:
        """Conflicts on ``route`` flown from now, and from each of ``delays`` vehicle seconds later (a held vehicle
        may be back on its route any time up to then): the earliest first."""
        c = self.ctx.cfg
        found = [predict_conflicts(route, self.speed, 0.0, now + d, threats, c.horizon_s, self.ctx.d_coll,
                                   c.margin_m, c.sample_dt_s)
                 for d in delays]
        return sorted((x for f in found for x in f), key=lambda x: x.t)

    def closest(self, route: np.ndarray, t0: float, threats: Threats, delays: np.ndarray | None = None) \
            -> Conflict | None:
        """The threat that comes closest to ``route`` flown from mission time ``t0`` (and each of ``delays`` vehicle
        seconds later), or None when none is near it within the horizon."""
        c = self.ctx.cfg
        seps = [x for d in (np.zeros(1) if delays is None else delays)
                for x in route_separations(route, self.speed, 0.0, t0 + d, threats, c.horizon_s, c.sample_dt_s)]
        return min(seps, key=lambda x: x.separation, default=None)

    def log_contacts(self, now: float, threats: Threats) -> None:
        """A ``contacts`` record (every threat, where it is and where it is predicted to go), at most every
        :data:`CONTACTS_EVERY_S` wall seconds: the status page's picture of the traffic."""
        wall = time.monotonic()
        if wall - self._contacts_at < CONTACTS_EVERY_S:
            return
        self._contacts_at = wall
        self.ctx.events.log("contacts", t_mission=round(now, 2),
                            contacts=picture.contacts(threats, now, min(self.ctx.cfg.horizon_s, CONTACT_PATH_S)))
