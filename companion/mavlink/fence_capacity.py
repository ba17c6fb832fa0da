"""How much fence an autopilot can store, and whether a fence fits before any of it is sent (docs/autopilots.md §5.9).

An autopilot refuses a fence larger than its storage, but only once the upload has started: ArduPilot answers a
MISSION_COUNT above its item limit with MAV_MISSION_NO_SPACE, and a fence within that count but larger than its
fence storage in bytes with MAV_MISSION_ERROR after the last item ("Fence exceeds storage size"); PX4 answers a
count above its limit with MAV_MISSION_NO_SPACE. The companion checks first (:meth:`FenceCapacity.problem`) and
sends nothing when the fence does not fit.

The numbers were read in the autopilots' sources and measured on SITL (ArduPlane 84 items / 672 bytes, ArduCopter
70 / 560, PX4 64 items). A value module: it imports nothing of the companion above :mod:`companion.mavlink.items`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.items import MissionItem

# ArduPilot (libraries/AC_Fence/AC_PolyFence_loader.cpp): the fence lives in the StorageFence area of
# libraries/StorageManager/StorageManager.cpp, whose size is fixed per build: plane, rover and sub get 160 + 256 +
# 256 bytes, copter and heli 48 + 256 + 256, on boards with at least 16 kB of storage (SITL among them; 4 kB boards
# have only the first area, 160 or 48 bytes, which MAVLink cannot tell us). max_items() is that size / 8 (one
# latitude/longitude pair); BRD_SD_FENCE (kB, boards with an SD card) replaces the area by a file of that size,
# capped at 65535 bytes (StorageAccess::attach_file).
ARDUPILOT_BYTES_PER_ITEM = 8
ARDUPILOT_FENCE_BYTES_PLANE_LAYOUT = 672  # SITL: "Only 84 items are supported" (ArduPlane 4.7.0-dev)
ARDUPILOT_FENCE_BYTES_COPTER_LAYOUT = 560  # SITL: "Only 70 items are supported" (ArduCopter 4.7.0-dev)
ARDUPILOT_SD_FENCE_PARAM = "BRD_SD_FENCE"
ARDUPILOT_FILE_STORAGE_MAX = 0xFFFF
ARDUPILOT_MAX_POLYGON_VERTICES = 255  # a polygon's vertex count is stored in one byte (AC_PolyFenceItem)
# AC_PolyFence_loader::fence_storage_space_required(): a header, then per polygon a type and a count byte and 8
# bytes a vertex, per circle a type, 8 bytes of position and 4 of radius, a return point a type and 8 bytes
_AP_HEADER, _AP_POLYGON, _AP_VERTEX, _AP_CIRCLE, _AP_RETURN = 4, 2, 8, 13, 9
# the vehicle types ArduPilot builds with the plane/rover storage layout (all others: the copter one, the smaller)
_PLANE_LAYOUT_TYPES = frozenset({mavlink.MAV_TYPE_FIXED_WING, mavlink.MAV_TYPE_GROUND_ROVER,
                                 mavlink.MAV_TYPE_SURFACE_BOAT, mavlink.MAV_TYPE_SUBMARINE,
                                 *range(mavlink.MAV_TYPE_VTOL_DUOROTOR, mavlink.MAV_TYPE_VTOL_DUOROTOR + 7)})

# PX4 (src/modules/dataman/dataman.h DM_KEY_FENCE_POINTS_MAX, the MAX_COUNT of src/modules/mavlink/
# mavlink_mission.h): a fixed number of fence items of any kind, the same on every board but the memory-constrained
# builds; a MISSION_COUNT above it gets MAV_MISSION_NO_SPACE (SITL: 64 accepted, 65 refused)
PX4_FENCE_ITEMS = 64

_POLYGONS = frozenset({mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                       mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION})
_CIRCLES = frozenset({mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION})


def ardupilot_fence_bytes(items: Sequence[MissionItem]) -> int:
    """Bytes of ArduPilot fence storage ``items`` need (its ``fence_storage_space_required``): a polygon is as many
    consecutive vertex items as the count in their param1 (a byte, as ArduPilot keeps it)."""
    needed, left = _AP_HEADER, 0
    for item in items:
        if item.command in _POLYGONS:
            if left == 0:
                left = max(int(item.param1) % 256, 1)
                needed += _AP_POLYGON
            needed += _AP_VERTEX
            left -= 1
        elif item.command in _CIRCLES:
            needed += _AP_CIRCLE
        else:  # the return point
            needed += _AP_RETURN
    return needed


@dataclass(frozen=True)
class FenceCapacity:
    """What one autopilot's fence storage holds: ``max_items`` items (the count it accepts in MISSION_COUNT) and, on
    ArduPilot, ``storage_bytes`` of storage (:func:`ardupilot_fence_bytes`); ``source`` says where the numbers come
    from, for the log."""

    autopilot: str
    max_items: int
    storage_bytes: int | None = None
    source: str = ""
    max_polygon_vertices: int | None = None  # ArduPilot keeps a polygon's vertex count in a byte

    def problem(self, items: Sequence[MissionItem]) -> str | None:
        """Why ``items`` do not fit (what they need against what the autopilot has), or None."""
        if len(items) > self.max_items:
            return f"{len(items)} fence items, {self.autopilot} stores at most {self.max_items}"
        counts = [it.param1 for it in items if it.command in _POLYGONS]
        if self.max_polygon_vertices is not None and counts and max(counts) > self.max_polygon_vertices:
            return (f"a polygon of {max(counts):.0f} vertices, {self.autopilot} stores at most "
                    f"{self.max_polygon_vertices} a polygon")
        if self.storage_bytes is not None and (need := ardupilot_fence_bytes(items)) > self.storage_bytes:
            return (f"{len(items)} fence items need {need} bytes of fence storage, {self.autopilot} has "
                    f"{self.storage_bytes}")
        return None

    def fits(self, items: Sequence[MissionItem]) -> bool:
        return self.problem(items) is None


def capacity_params(autopilot: int | None) -> tuple[str, ...]:
    """The parameters :func:`fence_capacity` reads from this autopilot (MAV_AUTOPILOT of its HEARTBEAT)."""
    return (ARDUPILOT_SD_FENCE_PARAM,) if autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA else ()


def fence_capacity(autopilot: int | None, vehicle_type: int | None,
                   params: Mapping[str, float] | None = None) -> FenceCapacity | None:
    """The fence capacity of an autopilot from its HEARTBEAT's ``autopilot`` and ``type`` and the parameters read
    (``params``, :func:`capacity_params`); None for an autopilot whose limit is not known (nothing is checked)."""
    params = params or {}
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return FenceCapacity("PX4", PX4_FENCE_ITEMS, None, "PX4 dataman DM_KEY_FENCE_POINTS_MAX")
    if autopilot != mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA:
        return None
    name = "ArduPlane" if vehicle_type == mavlink.MAV_TYPE_FIXED_WING else \
        "ArduPilot" if vehicle_type in _PLANE_LAYOUT_TYPES else "ArduCopter"
    sd_kb = params.get(ARDUPILOT_SD_FENCE_PARAM, 0.0)
    if sd_kb > 0:
        size = min(ARDUPILOT_FILE_STORAGE_MAX, int(sd_kb) * 1024)
        source = f"{ARDUPILOT_SD_FENCE_PARAM} {int(sd_kb)} kB"
    elif vehicle_type in _PLANE_LAYOUT_TYPES:
        size, source = ARDUPILOT_FENCE_BYTES_PLANE_LAYOUT, "StorageManager's plane/rover layout"
    else:
        size, source = ARDUPILOT_FENCE_BYTES_COPTER_LAYOUT, "StorageManager's copter layout"
    return FenceCapacity(name, size // ARDUPILOT_BYTES_PER_ITEM, size, source, ARDUPILOT_MAX_POLYGON_VERTICES)


__all__ = ["ARDUPILOT_BYTES_PER_ITEM", "FenceCapacity", "PX4_FENCE_ITEMS", "ardupilot_fence_bytes",
           "capacity_params", "fence_capacity"]
