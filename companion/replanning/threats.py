"""Threat picture and 4D conflict prediction for live replanning (threat laws: docs/method.md §2.6; the
replanner: docs/design.md, "Live replanning").

Two parts, both free of I/O:

- :class:`TrackPicture` keeps the live ADS-B tracks (ADSB_VEHICLE → ENU position, ENU velocity, time of
  last contact) and turns them into ``track`` threats of :class:`planner.world.environment.Threats`, merged with
  the scenario's scripted ``loiter`` / ``patrol`` threats.
- :func:`predict_conflicts` samples the vehicle's remaining route at its ETAs and checks it against every
  threat's predicted position and radius at the same times, in one broadcast over threats × samples.

All positions are ENU metres with the origin at home; all times are seconds on the caller's clock (``now``),
which must be the clock the threats' laws use (scripted threats: mission time).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike
from pymavlink.dialects.v20 import common as mavlink

from companion.mission.geo import geodetic_to_enu
from planner.world.environment import Threat, Threats
from planner.world.home import Home

log = logging.getLogger(__name__)

_EPS = 1e-12  # m²/s², relative speeds below this count as "no relative motion"
_VERTICAL_VALID = mavlink.ADSB_FLAGS_VERTICAL_VELOCITY_VALID


# ---------------------------------------------------------------------------------------------------------------
# Closest approach of two constant-velocity tracks
# ---------------------------------------------------------------------------------------------------------------

def closest_approach(p1: ArrayLike, v1: ArrayLike, p2: ArrayLike,
                     v2: ArrayLike) -> tuple[np.ndarray | float, np.ndarray | float]:
    """Time and distance of closest approach of ``p1 + v1 t`` and ``p2 + v2 t`` for t ≥ 0.

    Inputs broadcast over leading axes: positions (..., 3) m, velocities (..., 3) m/s. Returns ``(t*, d*)``,
    each (...) (a float for single tracks): t* = −Δp·Δv / |Δv|² clipped at 0 (diverging or no relative
    motion → 0, i.e. now), d* = |Δp + Δv t*|.
    """
    dp = np.asarray(p2, dtype=float) - np.asarray(p1, dtype=float)
    dv = np.asarray(v2, dtype=float) - np.asarray(v1, dtype=float)
    dv2 = np.sum(dv * dv, axis=-1)
    moving = dv2 > _EPS
    t = np.where(moving, -np.sum(dp * dv, axis=-1) / np.where(moving, dv2, 1.0), 0.0)
    t = np.maximum(t, 0.0)
    d = np.linalg.norm(dp + dv * t[..., None], axis=-1)
    if t.ndim == 0:
        return float(t), float(d)
    return t, d


# ---------------------------------------------------------------------------------------------------------------
# Live tracks from ADSB_VEHICLE
# ---------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Track:
    """One ADS-B contact: ENU ``position`` (m) at ``t_contact`` (caller's clock, s), ENU ``velocity`` (m/s);
    ``t_heard``: when that same report was last received again (None: only once)."""

    icao: int
    callsign: str
    position: tuple[float, float, float]
    velocity: tuple[float, float, float]
    t_contact: float
    t_heard: float | None = None

    @property
    def last_heard(self) -> float:
        return self.t_contact if self.t_heard is None else max(self.t_contact, self.t_heard)

    @property
    def id(self) -> str:
        """Threat id: ``adsb-`` and the 24-bit ICAO address in hex."""
        return f"adsb-{self.icao:06x}"


def track_from_adsb(msg: mavlink.MAVLink_adsb_vehicle_message, now: float, home: Home,
                    previous: Track | None = None) -> Track | None:
    """An ADSB_VEHICLE message received at ``now`` → :class:`Track`, or None without valid coordinates.

    lat/lon 1e7 deg, altitude mm AMSL, heading cdeg from north clockwise (9000 = east), hor/ver_velocity cm/s
    (ver positive up), tslc s since the receiver last heard the aircraft (so contact was at ``now − tslc``).
    Missing altitude keeps ``previous``'s; missing heading or velocity gives zero horizontal velocity (the
    uncertainty growth then carries the prediction). The ENU axes at the aircraft are taken as parallel to
    home's (meridian convergence is negligible over a mission area).
    """
    flags = msg.flags
    if not flags & mavlink.ADSB_FLAGS_VALID_COORDS:
        return None
    if flags & mavlink.ADSB_FLAGS_VALID_ALTITUDE:
        alt = msg.altitude / 1000.0
    elif previous is not None:
        alt = home.alt + previous.position[2]
    else:
        return None
    e, n, u = geodetic_to_enu(msg.lat / 1e7, msg.lon / 1e7, alt, home)
    vx = vy = vz = 0.0
    if flags & mavlink.ADSB_FLAGS_VALID_HEADING and flags & mavlink.ADSB_FLAGS_VALID_VELOCITY:
        heading = np.radians(msg.heading / 100.0)
        speed = msg.hor_velocity / 100.0
        vx, vy = speed * np.sin(heading), speed * np.cos(heading)
    if flags & _VERTICAL_VALID:
        vz = msg.ver_velocity / 100.0
    callsign = msg.callsign
    if isinstance(callsign, bytes):
        callsign = callsign.decode("ascii", errors="replace")
    return Track(msg.ICAO_address, callsign.rstrip("\x00 "), (float(e), float(n), float(u)),
                 (float(vx), float(vy), float(vz)), now - float(msg.tslc))


class TrackPicture:
    """Live ADS-B tracks keyed by ICAO address, in the ENU frame of ``home``."""

    def __init__(self, home: Home) -> None:
        self.home = home
        self.tracks: dict[int, Track] = {}

    def __len__(self) -> int:
        return len(self.tracks)

    def update(self, msg: mavlink.MAVLink_adsb_vehicle_message, now: float) -> Track | None:
        """Fold in one ADSB_VEHICLE received at ``now``; returns the track kept, or None if the message was
        unusable. A report older than the track held (out-of-order delivery) is ignored.

        A moving aircraft reported again at exactly the same position and velocity is the same report again,
        not a new contact: ArduPilot re-sends every aircraft it knows once a second with the ``tslc`` it arrived
        with, and the same report can come both from an ADS-B receiver on the vehicle and relayed by the
        autopilot. The track keeps its first contact time (prediction and radius growth run from there) and
        only counts as heard now (:meth:`expire` keeps it). A report without velocity (a point obstacle, which
        ArduPilot's simulated ADS-B reports unchanged every second) is a fresh contact each time."""
        previous = self.tracks.get(msg.ICAO_address)
        track = track_from_adsb(msg, now, self.home, previous)
        if track is None:
            log.debug("ADSB_VEHICLE %06x without valid position ignored", msg.ICAO_address)
            return previous
        if previous is not None and any(track.velocity) \
                and (track.position, track.velocity) == (previous.position, previous.velocity):
            self.tracks[track.icao] = replace(previous, t_heard=max(now, previous.last_heard))
            return self.tracks[track.icao]
        if previous is not None and track.t_contact < previous.t_contact:
            return previous
        if previous is None:
            log.info("new track %s (%s)", track.id, track.callsign)
        self.tracks[track.icao] = track
        return track

    def expire(self, now: float, max_age: float) -> list[str]:
        """Drop tracks not heard from (:attr:`Track.last_heard`) for more than ``max_age`` s; returns the dropped
        threat ids."""
        stale = [icao for icao, t in self.tracks.items() if now - t.last_heard > max_age]
        for icao in stale:
            log.info("track %s expired", self.tracks[icao].id)
            del self.tracks[icao]
        return [f"adsb-{icao:06x}" for icao in stale]

    def threat_items(self, base_radius: float, growth_per_s: float) -> tuple[Threat, ...]:
        """Each track as a ``track`` :class:`Threat`: p0 = last ENU position, p1 = ENU velocity, t_ref = time
        of last contact, radius = ``base_radius``, radius_growth = ``growth_per_s``.

        ``Threats.radii(t)`` grows the radius from t_ref, so at ``now`` it is already base + growth × age and
        at ``now + τ`` base + growth × (age + τ): age and prediction time both count, once each.
        """
        return tuple(Threat(id=t.id, kind="track", radius=base_radius, p0=t.position, p1=t.velocity,
                            t_ref=t.t_contact, radius_growth=growth_per_s)
                     for t in sorted(self.tracks.values(), key=lambda t: t.icao))

    def threats(self, now: float, base_radius: float, growth_per_s: float,
                scripted: Threats | Iterable[Threat] = ()) -> Threats:
        """Live tracks (heard by ``now``) as :class:`Threats`, after the ``scripted`` threats if given."""
        tracks = tuple(t for t in self.threat_items(base_radius, growth_per_s) if t.t_ref <= now)
        return merge_threats(scripted, tracks)


def merge_threats(*groups: Threats | Iterable[Threat]) -> Threats:
    """One :class:`Threats` from several groups (scripted threats, live tracks), in order."""
    items: list[Threat] = []
    for g in groups:
        items.extend(g.items if isinstance(g, Threats) else g)
    return Threats(items=tuple(items))


# ---------------------------------------------------------------------------------------------------------------
# Conflict prediction
# ---------------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Conflict:
    """A predicted loss of separation with one threat, described at the closest approach.

    ``separation`` is distance to the threat centre minus its (grown) radius, in metres; ``t`` is on the
    caller's clock; ``segment`` is the route segment (route[segment] → route[segment + 1]) and ``s`` the
    along-route distance (m from route[0]) of the vehicle then.
    """

    threat_id: str
    t: float
    separation: float
    position: tuple[float, float, float]
    segment: int
    s: float


def route_distances(route: np.ndarray) -> np.ndarray:
    """Cumulative along-route distance of each vertex of ``route`` (N, 3) → (N,) m, starting at 0."""
    route = np.asarray(route, dtype=float)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=-1))])


def route_points(route: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points at along-route distances ``s`` (M,) m, clipped to the route → ((M, 3) m, (M,) segment index)."""
    route = np.asarray(route, dtype=float)
    cum = route_distances(route)
    s = np.clip(np.asarray(s, dtype=float), 0.0, cum[-1])
    seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(route) - 2)
    length = cum[seg + 1] - cum[seg]
    frac = np.where(length > 0, (s - cum[seg]) / np.where(length > 0, length, 1.0), 0.0)
    return route[seg] + (route[seg + 1] - route[seg]) * frac[:, None], seg


def route_separations(route: np.ndarray, speed: float, s_now: float, t_now: float, threats: Threats,
                      horizon_s: float, dt: float) -> list[Conflict]:
    """Closest predicted approach of the remaining route to every threat within ``horizon_s`` (one entry per
    threat, in ``threats`` order; separation inf when the route has ended or there is nothing to compare).

    The vehicle is at along-route distance ``s_now`` (m; for waypoint ``i`` use ``route_distances(route)[i]``)
    at ``t_now`` and flies ``route`` (N, 3) ENU m at ``speed`` m/s. Its positions are sampled every ``dt`` s
    from now until the horizon or the route's end (which is always sampled); each threat's centre (k, M, 3)
    and radius (k, M) come from ``threats`` at the same M times, in one broadcast. Separation = distance −
    radius (k, M). Sampling can miss an encounter shorter than a sample: keep
    ``dt · (speed + threats.max_speed) / 2`` well below the separation you test for.
    """
    if len(threats) == 0 or len(route) < 2:
        return [Conflict(t.id, t_now, float("inf"), (0.0, 0.0, 0.0), 0, s_now) for t in threats.items]
    route = np.asarray(route, dtype=float)
    remaining = max(route_distances(route)[-1] - s_now, 0.0)
    t_end = min(horizon_s, remaining / speed) if speed > 0 else horizon_s
    tau = np.arange(0.0, t_end, dt)
    if tau.size == 0 or tau[-1] < t_end:
        tau = np.append(tau, t_end)
    times = t_now + tau  # (M,)
    pos, seg = route_points(route, s_now + speed * tau)  # (M, 3), (M,)
    centres = threats.positions(times)  # (k, M, 3)
    sep = np.linalg.norm(centres - pos[None], axis=-1) - threats.radii(times)  # (k, M)
    j = np.argmin(sep, axis=1)  # (k,) sample of closest approach
    min_sep = sep[np.arange(len(threats)), j]
    return [Conflict(threats.items[i].id, float(times[j[i]]), float(min_sep[i]),
                     (float(pos[j[i], 0]), float(pos[j[i], 1]), float(pos[j[i], 2])), int(seg[j[i]]),
                     float(min(s_now + speed * tau[j[i]], s_now + remaining)))
            for i in range(len(threats))]


def predict_conflicts(route: np.ndarray, speed: float, s_now: float, t_now: float, threats: Threats,
                      horizon_s: float, d_coll: float, margin: float, dt: float) -> list[Conflict]:
    """Conflicts of the remaining route with every threat within ``horizon_s``, sorted by time: the threats
    whose closest approach (:func:`route_separations`, same arguments) is below ``d_coll + margin``."""
    conflicts = [c for c in route_separations(route, speed, s_now, t_now, threats, horizon_s, dt)
                 if c.separation < d_coll + margin]
    conflicts.sort(key=lambda c: c.t)
    for c in conflicts:
        log.info("conflict with %s at t=%.1f s: separation %.1f m", c.threat_id, c.t, c.separation)
    return conflicts
