"""What the companion knows of the vehicle in flight, from one telemetry subscription (docs/design.md, "Vehicle state").

The supervisor reads the flight's one subscription (:func:`subscribe`) and hands every message to
:meth:`VehicleState.observe`; the replanner reads the same state. Position in the scenario's local frame (ENU from
home), the active item, the flight mode, the vehicle clock and mission time, and whether the link is up.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import numpy as np

from companion.mavlink.link import MAV_COMP_ID_ADSB, Link, Message, Subscription, received_at
from companion.mission.geo import geodetic_to_enu
from planner.world.home import Home

# the flight's telemetry: progress and completion (the supervisor), position, mode and traffic (both)
TELEMETRY = ("MISSION_ITEM_REACHED", "MISSION_CURRENT", "GLOBAL_POSITION_INT", "STATUSTEXT", "HEARTBEAT",
             "ADSB_VEHICLE")
# ADS-B reports come from the autopilot (its own receiver, forwarded) or from a receiver that is a MAVLink component
# of the same vehicle; that receiver's other messages (its HEARTBEAT) and every other system's are not ours
ADSB_SOURCES = {"ADSB_VEHICLE": (MAV_COMP_ID_ADSB,)}


def subscribe(link: Link) -> Subscription:
    """The flight's one subscription: :data:`TELEMETRY` from the target autopilot, and ADSB_VEHICLE also from an
    ADS-B receiver of the same vehicle (:data:`ADSB_SOURCES`)."""
    return link.subscribe(*TELEMETRY, extra_components=ADSB_SOURCES)


class VehicleClock:
    """Vehicle time in seconds from ``time_boot_ms`` (simulated time in SITL), extrapolated between messages.

    The rate (vehicle seconds per wall second) is given (our simulator's speed-up) or measured from the
    messages over at least one wall second; a reboot (time going backwards) restarts the measurement.
    """

    def __init__(self, rate: float | None = None) -> None:
        self._hint = rate
        self._first: tuple[float, float] | None = None
        self._last: tuple[float, float] | None = None

    def observe(self, boot_ms: int, wall: float) -> None:
        t = boot_ms / 1000.0
        if self._last is not None and t < self._last[0]:
            self._first = None
        if self._first is None:
            self._first = (t, wall)
        self._last = (t, wall)

    @property
    def rate(self) -> float:
        if self._hint is not None:
            return self._hint
        if self._first is None or self._last is None or self._last[1] - self._first[1] < 1.0:
            return 1.0
        return max((self._last[0] - self._first[0]) / (self._last[1] - self._first[1]), 1e-3)

    @property
    def synced(self) -> bool:
        return self._last is not None

    def now(self, wall: float) -> float:
        if self._last is None:
            return 0.0
        return self._last[0] + (wall - self._last[1]) * self.rate


class VehicleState:
    """The vehicle as last heard: one instance per flight, fed by :meth:`observe`, read by everyone.

    ``home``: the scenario's home (positions in its local frame; None: no position is kept); ``rate``: the vehicle's
    seconds per wall second where known (our simulator's speed-up), else measured.
    """

    def __init__(self, home: Home | None, rate: float | None = None) -> None:
        self.home = home
        self.clock = VehicleClock(rate)
        self.position: np.ndarray | None = None  # ENU m from home, z above home
        self.velocity = np.zeros(2)  # ENU m/s over the ground
        self.groundspeed = 0.0
        self.climb = 0.0  # m/s up
        self.current_seq = 0  # the active mission item (MISSION_CURRENT, or the item after the last one reached)
        self.custom_mode: int | None = None  # the flight mode, from HEARTBEAT (or as commanded and accepted)
        self.link_down = False  # between the supervisor finding the link lost and its re-sync of the mission
        self._fresh_since = 0.0  # monotonic: position and active item must be newer than this to act on
        # monotonic time of the latest position and (if the autopilot streams it) active item
        self._seen: dict[str, float] = {"GLOBAL_POSITION_INT": 0.0}
        self._mission_wall: float | None = None  # wall time of the mission start
        self._mission_t0: float | None = None  # vehicle time of the mission start, once the clock is synced
        self._listeners: list[Callable[[Message], None]] = []
        self._link_listeners: list[Callable[[bool], None]] = []

    def listen(self, callback: Callable[[Message], None]) -> None:
        """Have ``callback`` called with every message after the state has taken it in (the replanner's traffic)."""
        self._listeners.append(callback)

    def listen_link(self, callback: Callable[[bool], None]) -> None:
        """Have ``callback`` called with False when the link is found lost and True when it is back and re-synced."""
        self._link_listeners.append(callback)

    def observe(self, msg: Message) -> None:
        """Take in one message, timed by when the link received it (the supervisor may read a backlog: what came
        during the start sequence)."""
        kind = msg.get_type()
        wall = received_at(msg)
        if kind in ("GLOBAL_POSITION_INT", "MISSION_CURRENT"):
            self._seen[kind] = wall
        if kind == "GLOBAL_POSITION_INT":
            self.clock.observe(msg.time_boot_ms, wall)
            if self.home is not None:
                e, n, _u = geodetic_to_enu(msg.lat / 1e7, msg.lon / 1e7, self.home.alt + msg.relative_alt / 1000,
                                           self.home)
                self.position = np.array([e, n, msg.relative_alt / 1000.0])
            self.groundspeed = math.hypot(msg.vx, msg.vy) / 100.0
            self.velocity = np.array([msg.vy / 100.0, msg.vx / 100.0])  # NED north/east → ENU east/north
            self.climb = -msg.vz / 100.0
        elif kind == "HEARTBEAT":
            self.custom_mode = int(msg.custom_mode)
        elif kind == "MISSION_CURRENT":
            self.current_seq = int(msg.seq)
        elif kind == "MISSION_ITEM_REACHED":
            self.current_seq = max(self.current_seq, int(msg.seq) + 1)
        for callback in self._listeners:
            callback(msg)

    # -- mission time ------------------------------------------------------------------------------
    def mission_started(self, wall: float) -> None:
        """MISSION_START was accepted at ``wall`` (monotonic s): mission time (the scripted threats' clock) starts
        there."""
        self._mission_wall = wall

    @property
    def mission_t0(self) -> float | None:
        """Vehicle time of the mission start (None before it, or before any telemetry)."""
        if self._mission_t0 is None and self._mission_wall is not None and self.clock.synced:
            self._mission_t0 = self.clock.now(self._mission_wall)
        return self._mission_t0

    def now(self) -> float:
        """Mission time (vehicle s since the mission start; vehicle time before it)."""
        return self.at(time.monotonic())

    def at(self, wall: float) -> float:
        """Mission time at monotonic time ``wall``."""
        return self.clock.now(wall) - (self.mission_t0 or 0.0)

    # -- link --------------------------------------------------------------------------------------
    def link_lost(self) -> None:
        """The link was found lost: what is known is getting stale and nothing can be uploaded."""
        self.link_down = True
        for callback in self._link_listeners:
            callback(False)

    def link_restored(self) -> None:
        """The link is back and the mission re-synced: act again only on telemetry received from now on."""
        self.link_down = False
        self._fresh_since = time.monotonic()  # position and active item are from before the outage
        for callback in self._link_listeners:
            callback(True)

    @property
    def fresh(self) -> bool:
        """The link is up and position and active item have been heard since it last came back."""
        return not self.link_down and min(self._seen.values()) >= self._fresh_since
