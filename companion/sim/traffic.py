"""A scenario's scripted intruders flown against a real autopilot: an ADS-B receiver on its MAVLink link.

Real SITL does not fly our scripted traffic, so :class:`TrafficFeed` does: it connects to a spare port of the
autopilot (e.g. ArduPilot SITL's SERIAL2) as component 156 (MAV_COMP_ID_ADSB) of the vehicle's own system, and
sends each intruder's ADSB_VEHICLE at ``report_hz`` of the vehicle's time. ArduPilot forwards these broadcast
messages to its other ports, so the companion receives them as it would from an ADS-B receiver wired to the
autopilot (its link must have sent something first: ArduPilot forwards only to ports with a known MAVLink peer).

Time is the vehicle's own (GLOBAL_POSITION_INT ``time_boot_ms``), so SITL's speed-up changes nothing; mission time
starts at the first position after a HEARTBEAT that says armed in AUTO, as in the simulator. Intruders with a
``meet`` point are timed from the vehicle's real progress along ``route`` (:class:`IntruderTrack.follow`). The
vehicle's positions and the intruders' reported positions are kept as truth, for :meth:`separations` (the same
measure as the simulator's flight.json).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.link import MAV_COMP_ID_ADSB, Link, Message
from companion.mavlink.modes import mode_number
from companion.mavlink.telemetry import Rate, TelemetryRates
from companion.mission.geo import geodetic_to_enu
from companion.replanning.separation import Separation, min_separations
from companion.sim.intruders import IntruderTrack, adsb_report
from planner.world.scenario import Scenario

log = logging.getLogger(__name__)

REPORT_HZ = 2.0  # ADS-B reports per second of vehicle time (a receiver hears each aircraft about once a second)
FEED_RATES = (Rate("GLOBAL_POSITION_INT", 10.0, mavlink.MAV_DATA_STREAM_POSITION, "vehicle clock and truth"),)


class TrafficFeed:
    """Feeds ``scenario``'s intruders to the autopilot at ``url`` while entered (async context manager).
    ``route``: the planned route's ENU points (K, 3), needed for intruders timed by a ``meet`` point."""

    def __init__(self, url: str, scenario: Scenario, route: Sequence[Sequence[float]] | None = None, *,
                 system: int = 1, component: int = MAV_COMP_ID_ADSB, report_hz: float = REPORT_HZ) -> None:
        self.scenario = scenario
        self.tracks = [IntruderTrack(i, None if route is None else np.asarray(route, float))
                       for i in scenario.intruders]
        self.link = Link(url, source_system=system, source_component=component, open_timeout=10.0)
        self.report_hz = report_hz
        self.vehicle: list[tuple[float, float, float, float]] = []  # (t vehicle s, x, y, z) ENU m
        self.intruders: dict[str, list[tuple[float, float, float, float]]] = {i.id: [] for i in scenario.intruders}
        self.mission_t0: float | None = None  # vehicle time of the mission start
        self.reports = 0
        self._in_auto = False
        self._last_report = -np.inf
        self._task: asyncio.Task | None = None
        self._rates: TelemetryRates | None = None

    async def __aenter__(self) -> TrafficFeed:
        await self.link.open()
        self._rates = TelemetryRates(self.link, FEED_RATES).start()
        self._task = asyncio.create_task(self._run(), name="traffic-feed")
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        if self._rates is not None:
            self._rates.stop()
            await self._rates.wait()
        await self.link.close()

    async def _run(self) -> None:
        with self.link.subscribe("GLOBAL_POSITION_INT", "HEARTBEAT") as sub:
            async for msg in sub:
                if msg.get_type() == "HEARTBEAT":
                    self._in_auto = bool(msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED) and \
                        msg.custom_mode == mode_number(msg.autopilot, msg.type, "AUTO")
                else:
                    self._position(msg)

    def _position(self, msg: Message) -> None:
        t = msg.time_boot_ms / 1000.0
        home = self.scenario.home
        p = geodetic_to_enu(msg.lat / 1e7, msg.lon / 1e7, home.alt + msg.relative_alt / 1000.0, home)
        p = np.array([p[0], p[1], msg.relative_alt / 1000.0])
        self.vehicle.append((t, *map(float, p)))
        if self.mission_t0 is None:
            if not self._in_auto:
                return
            self.mission_t0 = t
            log.info("traffic: mission started at vehicle time %.2f s", t)
        t_mission = t - self.mission_t0
        report = t - self._last_report >= 1.0 / self.report_hz
        if report:
            self._last_report = t
        for track in self.tracks:
            track.follow(t_mission, p)
            sample = track.sample(t_mission)
            if sample is None:
                continue
            self.intruders[track.intruder.id].append((t, sample.x, sample.y, sample.z))
            if report:
                self.link.send(adsb_report(track.intruder, sample, home))
                self.reports += 1

    def separations(self) -> dict[str, Separation]:
        """Per intruder: the closest the vehicle came (its GLOBAL_POSITION_INT track against the intruder's
        scripted track), separation = distance − the intruder's protected radius."""
        vehicle = np.asarray(self.vehicle, dtype=float).reshape(-1, 4)
        radius = {i.id: i.radius for i in self.scenario.intruders}
        tracks = {k: (np.asarray(v, dtype=float).reshape(-1, 4), radius[k]) for k, v in self.intruders.items()}
        return min_separations(vehicle, tracks)
