"""The operator's world as the vehicle holds it: its fence, rally points and mission, downloaded and read as the
geographic values of planner/world/geo_inputs.py, which the scenario builder turns into local metres (issue 35).

What each list holds (docs/autopilots.md §5.1, §5.4):

* Fence: a polygon is as many consecutive MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION/…_EXCLUSION items as its vertex
  count (param1, the same on each), a circle one MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION/…_EXCLUSION (radius in param1),
  and at most one MAV_CMD_NAV_FENCE_RETURN_POINT (kept in ``extras["fence_return_point"]``). Fences are 2-D: zones
  come without floor or ceiling.
* Rally: MAV_CMD_NAV_RALLY_POINT items, each a point with its altitude.
* Mission: on ArduPilot item 0 is home (AMSL); the goal is the last navigation item with a position, the vias the
  ones before it. Takeoffs are neither (ArduPlane climbs straight ahead, whatever their position), nor is an item
  at latitude and longitude 0 (ArduPilot's "where the vehicle is", e.g. a LAND in place). PX4 has no home item:
  ``home`` and ``start`` stay None there (its home comes in HOME_POSITION).

Altitudes take their reference from the item's frame: relative → "home", global → "amsl", terrain → "ground".
Content that cannot be read so raises :class:`~companion.mavlink.errors.VehicleContentError` naming the item.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path

from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import VehicleContentError
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, normalise_frame
from companion.mavlink.protocol import MissionClient, command_name
from planner.world.geo_inputs import Altitude, AltitudeRef, GeoPoint, OperatorMission, Zone

logger = logging.getLogger(__name__)

POLYGON_VERTEX = {  # command → inclusion
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: True,
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: False,
}
CIRCLE = {mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: True, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: False}
MIN_VERTICES = 3
# navigation commands whose position is a place the vehicle goes to (the goal and the vias)
PLACES = frozenset({
    mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM, mavlink.MAV_CMD_NAV_LOITER_TURNS,
    mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_LOITER_TO_ALT,
    mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT, mavlink.MAV_CMD_NAV_VTOL_LAND, mavlink.MAV_CMD_NAV_PAYLOAD_PLACE,
})
ALTITUDE_REFS: dict[int, AltitudeRef] = {  # normalised frame → what its altitude is measured from
    mavlink.MAV_FRAME_GLOBAL: "amsl",
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT: "home",
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT: "ground",
}
_LAT_MAX_E7, _LON_MAX_E7 = 900_000_000, 1_800_000_000


async def download_world(client: MissionClient, source: Path | str | None = None) -> OperatorMission:
    """The vehicle's fence, rally points and mission (downloaded in that order with ``client``) as an
    :class:`OperatorMission`; ``source`` (default: the link's URL) names where it came from. Raises what
    :meth:`MissionClient.download` raises, and :class:`VehicleContentError` for content that cannot be read."""
    fence = await client.download(FENCE)
    rally = await client.download(RALLY)
    mission = await client.download(MISSION)
    logger.info("vehicle world: %d fence, %d rally and %d mission items", len(fence), len(rally), len(mission))
    return operator_world(fence, rally, mission, home_at_zero=client.home_at_zero(MISSION),
                          source=Path(source if source is not None else client.link.url))


def operator_world(fence: Sequence[MissionItem], rally: Sequence[MissionItem], mission: Sequence[MissionItem], *,
                   home_at_zero: bool, source: Path) -> OperatorMission:
    """The three downloaded lists as an :class:`OperatorMission`; ``home_at_zero``: mission item 0 is the home
    (ArduPilot)."""
    zones, return_point = fence_zones(fence)
    home, vias, goal = mission_places(mission, home_at_zero)
    extras: dict[str, object] = {"fence_return_point": return_point} if return_point is not None else {}
    return OperatorMission(source, home=home, start=home, goal=goal, vias=vias, zones=zones,
                           rally=rally_points(rally), extras=extras)


def fence_zones(items: Sequence[MissionItem]) -> tuple[tuple[Zone, ...], GeoPoint | None]:
    """The fence's zones in item order, and its return point (or None)."""
    zones: list[Zone] = []
    return_point: tuple[int, GeoPoint] | None = None
    i = 0
    while i < len(items):
        item = items[i]
        _check_position(item, "fence")
        if item.command in POLYGON_VERTEX:
            vertices = _polygon(items, i)
            last = vertices[-1].seq
            zones.append(Zone(f"vehicle fence items {item.seq}-{last}", inclusion=POLYGON_VERTEX[item.command],
                              polygon=tuple((v.lat, v.lon) for v in vertices)))
            i += len(vertices)
            continue
        if item.command in CIRCLE:
            if not (math.isfinite(item.param1) and item.param1 > 0):
                raise VehicleContentError("fence", item.seq, f"circle radius {item.param1!r} is not a positive number")
            zones.append(Zone(f"vehicle fence item {item.seq}", inclusion=CIRCLE[item.command],
                              centre=(item.lat, item.lon), radius_m=float(item.param1)))
        elif item.command == mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT:
            if return_point is not None:
                raise VehicleContentError("fence", item.seq,
                                          f"a second return point (the first is item {return_point[0]})")
            return_point = item.seq, GeoPoint(item.lat, item.lon)
        else:
            raise VehicleContentError("fence", item.seq, f"unsupported fence command {command_name(item.command)}")
        i += 1
    return tuple(zones), (return_point[1] if return_point is not None else None)


def _polygon(items: Sequence[MissionItem], first: int) -> Sequence[MissionItem]:
    """The vertex items of the polygon that begins at ``items[first]``: as many as its vertex count, each of the
    same command and count."""
    head = items[first]
    count = head.param1
    if not (math.isfinite(count) and count == int(count)):
        raise VehicleContentError("fence", head.seq, f"polygon vertex count {count!r} is not a whole number")
    n = int(count)
    if n < MIN_VERTICES:
        raise VehicleContentError("fence", head.seq, f"a polygon of {n} vertices (at least {MIN_VERTICES} needed)")
    vertices = items[first:first + n]
    if len(vertices) < n:
        raise VehicleContentError("fence", head.seq, f"a polygon of {n} vertices, but the fence ends after "
                                                     f"{len(vertices)} of them")
    for v in vertices[1:]:
        if v.command != head.command or v.param1 != head.param1:
            what = f"vertex count {v.param1:g}" if v.command == head.command else command_name(v.command)
            raise VehicleContentError("fence", v.seq, f"{what} inside the polygon of {n} vertices that begins at item "
                                                      f"{head.seq} ({command_name(head.command)})")
        _check_position(v, "fence")
    return vertices


def rally_points(items: Sequence[MissionItem]) -> tuple[GeoPoint, ...]:
    """The rally points, with their altitudes."""
    points = []
    for item in items:
        if item.command != mavlink.MAV_CMD_NAV_RALLY_POINT:
            raise VehicleContentError("rally", item.seq, f"unsupported rally command {command_name(item.command)}")
        _check_position(item, "rally")
        points.append(_point(item, "rally"))
    return tuple(points)


def mission_places(items: Sequence[MissionItem],
                   home_at_zero: bool) -> tuple[GeoPoint | None, tuple[GeoPoint, ...], GeoPoint | None]:
    """``(home, vias, goal)`` of a mission: home from item 0 when ``home_at_zero`` (None if not set yet: all
    zeros), the goal the last place (a navigation item in :data:`PLACES` with a position), the vias the others."""
    home = None
    if home_at_zero and items:
        items = list(items)
        first = items.pop(0)
        if first.x or first.y:
            _check_position(first, "mission")
            home = _point(first, "mission")
    places = []
    for item in items:
        if item.command in PLACES and (item.x or item.y):
            _check_position(item, "mission")
            places.append(_point(item, "mission"))
    return home, tuple(places[:-1]), (places[-1] if places else None)


def _point(item: MissionItem, list_name: str) -> GeoPoint:
    """The item's position and altitude, the reference from its frame."""
    ref = ALTITUDE_REFS.get(normalise_frame(item.frame))
    if ref is None:
        raise VehicleContentError(list_name, item.seq, f"frame {item.frame} has no geographic altitude "
                                                       "(expected a global, relative or terrain frame)")
    return GeoPoint(item.lat, item.lon, Altitude(float(item.z), ref))


def _check_position(item: MissionItem, list_name: str) -> None:
    if not -_LAT_MAX_E7 <= item.x <= _LAT_MAX_E7:
        raise VehicleContentError(list_name, item.seq, f"latitude {item.x / 1e7:g}° is out of range")
    if not -_LON_MAX_E7 <= item.y <= _LON_MAX_E7:
        raise VehicleContentError(list_name, item.seq, f"longitude {item.y / 1e7:g}° is out of range")


__all__ = ["download_world", "fence_zones", "mission_places", "operator_world", "rally_points"]
