"""Does the plan's fence fit the autopilot, and if not, which zones to drop or simplify (docs/autopilots.md §5.9).

:func:`companion.mission.builder.build_fence` turns a scenario's prisms and cylinders into fence items; an operator's
zones file with many polygons can make more than the autopilot stores. :func:`fence_refusal` says so in one line
before anything is sent, naming the zones as the scenario file numbers them, largest first, until the rest would fit.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.fence_capacity import FenceCapacity, fence_capacity
from companion.mavlink.items import MissionItem
from companion.mission.builder import build_fence
from planner.world.environment import Cylinders, Environment, Prisms
from planner.world.home import Home
from planner.world.scenario import Scenario


@dataclass(frozen=True)
class FencedZone:
    """One zone of the scenario as it goes into the fence: ``label`` as the scenario file numbers it
    (``prisms[2]``, ``cylinders[0]``) and its fence ``items``."""

    label: str
    items: tuple[MissionItem, ...]

    def describe(self) -> str:
        n = len(self.items)
        return f"{self.label} ({n} item{'' if n == 1 else 's'})"


def fenced_zones(env: Environment, home: Home, max_route_alt: float | None,
                 min_route_alt: float | None) -> list[FencedZone]:
    """Each prism and cylinder that :func:`build_fence` fences with these route heights, with its items (built one
    zone at a time, so a zone left out of the fence is left out here too)."""
    zones: list[FencedZone] = []
    prisms = env.prisms
    for k in range(len(prisms)):
        ring = prisms.vertices[int(prisms.start[k]):int(prisms.start[k + 1])]
        keep_in = bool(prisms.keep_in[k]) if prisms.keep_in is not None else False
        one = Prisms.from_polygons([ring], [prisms.floor[k]], [prisms.ceiling[k]], [keep_in])
        items = build_fence(Cylinders.empty(), home, max_route_alt, prisms=one, min_route_alt=min_route_alt)
        if items:
            zones.append(FencedZone(f"prisms[{k}]{' (keep-in)' if keep_in else ''}", tuple(items)))
    cyl = env.cylinders
    for k in range(len(cyl)):
        one_c = Cylinders([cyl.x[k]], [cyl.y[k]], [cyl.radius[k]], [cyl.top[k]], [cyl.z_ref[k]])
        items = build_fence(one_c, home, max_route_alt, min_route_alt=min_route_alt)
        if items:
            zones.append(FencedZone(f"cylinders[{k}]", tuple(items)))
    return zones


def fence_refusal(fence: Sequence[MissionItem], zones: Sequence[FencedZone], capacity: FenceCapacity) -> str | None:
    """One line when ``fence`` does not fit ``capacity`` (None when it does): what it needs, the limit, and the
    zones to drop or simplify, the largest first until the rest would fit."""
    problem = capacity.problem(fence)
    if problem is None:
        return None
    return (f"the fence does not fit the autopilot: {problem}{_source(capacity)}; {_advice(zones, capacity)}, or fly "
            "with --no-fence; nothing was uploaded")


def export_fence_warning(plan_doc: Mapping[str, Any], scenario: Scenario, autopilot: str) -> str | None:
    """For ``fuseplan export``: a line when the fence written into a ``.plan`` (built as ``fly`` builds it) is larger
    than the autopilot ``autopilot`` (ardupilot | px4 | px4-vtol) stores for the scenario's vehicle, without an SD
    card's widening; a ground station's upload of it would be refused. None when it fits."""
    points = plan_doc.get("trajectory", {}).get("points") or plan_doc["waypoints"]
    top = float(np.max(np.asarray(points, dtype=float)[:, 2]))
    env = scenario.environment
    fence = build_fence(env.cylinders, scenario.home, max_route_alt=top, prisms=env.prisms, min_route_alt=0.0)
    firmware = mavlink.MAV_AUTOPILOT_PX4 if autopilot.startswith("px4") else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
    frame = mavlink.MAV_TYPE_FIXED_WING if scenario.vehicle.type == "plane" else mavlink.MAV_TYPE_QUADROTOR
    capacity = fence_capacity(firmware, frame)
    problem = capacity.problem(fence) if capacity is not None and fence else None
    if problem is None or capacity is None:
        return None
    zones = fenced_zones(env, scenario.home, top, 0.0)
    return (f"its fence will not fit the vehicle: {problem}{_source(capacity)}; a ground station's upload of it will "
            f"be refused; {_advice(zones, capacity)}")


def _source(capacity: FenceCapacity) -> str:
    return f" ({capacity.source})" if capacity.source else ""


def _advice(zones: Sequence[FencedZone], capacity: FenceCapacity) -> str:
    """The zones to drop or simplify, the largest first until the rest would fit."""
    dropped: list[FencedZone] = []
    for zone in sorted(zones, key=lambda z: len(z.items), reverse=True):
        dropped.append(zone)
        rest = [it for z in zones if all(z is not d for d in dropped) for it in z.items]
        if capacity.fits(rest):
            break
    names = ", ".join(z.describe() for z in dropped)
    return f"drop or simplify {names}" if dropped else "drop or simplify zones"


__all__ = ["FencedZone", "export_fence_warning", "fence_refusal", "fenced_zones"]
