"""Fence capacities as each autopilot has them (companion.mavlink.fence_capacity), with the numbers measured on SITL:
ArduPlane takes a MISSION_COUNT of 84 fence items and 672 bytes of storage (an 83-vertex polygon stored, 84 refused
"Fence exceeds storage size", 85 refused at the count), ArduCopter 70 and 560 (69 stored, 70 refused, 71 refused at
the count), PX4 64 items (64 stored, 65 refused at the count)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.fence_capacity import ardupilot_fence_bytes, capacity_params, fence_capacity
from companion.mavlink.items import FENCE, FRAME_GLOBAL_INT, MissionItem
from companion.mission.fence_fit import FencedZone, fence_refusal
from companion.sim.mission_server import fence_problem

AP, PX4 = mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, mavlink.MAV_AUTOPILOT_PX4
EXC = mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION


def polygon(n: int) -> list[MissionItem]:
    return [MissionItem(k, FRAME_GLOBAL_INT, EXC, param1=float(n), x=-353600000 + 1000 * k, y=1491600000,
                        mission_type=FENCE) for k in range(n)]


def circles(n: int) -> list[MissionItem]:
    return [MissionItem(k, FRAME_GLOBAL_INT, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, param1=5.0,
                        x=-353600000 + 1000 * k, y=1491600000, mission_type=FENCE) for k in range(n)]


@pytest.mark.parametrize("vehicle_type, items, size", [
    (mavlink.MAV_TYPE_FIXED_WING, 84, 672), (mavlink.MAV_TYPE_QUADROTOR, 70, 560),
    (mavlink.MAV_TYPE_HEXAROTOR, 70, 560), (mavlink.MAV_TYPE_GROUND_ROVER, 84, 672),
    (mavlink.MAV_TYPE_VTOL_TILTROTOR, 84, 672)])
def test_ardupilot_capacity_follows_its_storage_layout(vehicle_type: int, items: int, size: int) -> None:
    cap = fence_capacity(AP, vehicle_type)
    assert (cap.max_items, cap.storage_bytes) == (items, size)


def test_ardupilot_sd_card_fence_storage_is_read_from_its_parameter() -> None:
    assert capacity_params(AP) == ("BRD_SD_FENCE",) and capacity_params(PX4) == ()
    cap = fence_capacity(AP, mavlink.MAV_TYPE_QUADROTOR, {"BRD_SD_FENCE": 2.0})
    assert (cap.max_items, cap.storage_bytes) == (256, 2048) and "BRD_SD_FENCE" in cap.source
    big = fence_capacity(AP, mavlink.MAV_TYPE_QUADROTOR, {"BRD_SD_FENCE": 100.0})
    assert big.storage_bytes == 65535 and big.fits(polygon(255))
    assert big.problem(polygon(256)) == "a polygon of 256 vertices, ArduCopter stores at most 255 a polygon"


def test_px4_takes_64_items_and_other_autopilots_are_not_checked() -> None:
    cap = fence_capacity(PX4, mavlink.MAV_TYPE_QUADROTOR)
    assert (cap.max_items, cap.storage_bytes) == (64, None)
    assert cap.fits(polygon(64)) and not cap.fits(polygon(65))
    assert fence_capacity(mavlink.MAV_AUTOPILOT_GENERIC, mavlink.MAV_TYPE_QUADROTOR) is None


@pytest.mark.parametrize("vehicle_type, largest", [(mavlink.MAV_TYPE_FIXED_WING, 83),
                                                   (mavlink.MAV_TYPE_QUADROTOR, 69)])
def test_the_largest_polygon_that_fits_is_the_one_sitl_stored(vehicle_type: int, largest: int) -> None:
    """The byte count is ArduPilot's, and the simulator refuses exactly what the check refuses."""
    cap = fence_capacity(AP, vehicle_type)
    assert ardupilot_fence_bytes(polygon(largest)) == 6 + 8 * largest
    assert cap.fits(polygon(largest)) and fence_problem(polygon(largest), cap.storage_bytes) is None
    too_big = polygon(largest + 1)
    assert "bytes of fence storage" in cap.problem(too_big)
    assert fence_problem(too_big, cap.storage_bytes) == ("Fence exceeds storage size", False)
    assert "stores at most" in cap.problem(polygon(cap.max_items + 1))


def test_fifty_two_circles_are_more_than_arduplane_stores() -> None:
    """84 items would pass the count, but 4 + 52 x 13 bytes are more than 672 (measured on ArduPlane SITL)."""
    cap = fence_capacity(AP, mavlink.MAV_TYPE_FIXED_WING)
    assert ardupilot_fence_bytes(circles(51)) == 667 and cap.fits(circles(51))
    assert ardupilot_fence_bytes(circles(52)) == 680 and not cap.fits(circles(52))


def test_the_refusal_names_the_largest_zones_until_the_rest_fits() -> None:
    zones = [FencedZone("prisms[0]", tuple(polygon(40))), FencedZone("prisms[1]", tuple(polygon(50))),
             FencedZone("cylinders[0]", tuple(circles(1)))]
    fence = [it for z in zones for it in z.items]
    cap = fence_capacity(AP, mavlink.MAV_TYPE_FIXED_WING)
    line = fence_refusal(fence, zones, cap)
    assert line is not None and "\n" not in line
    assert line.startswith("the fence does not fit the autopilot: 91 fence items, ArduPlane stores at most 84")
    assert "drop or simplify prisms[1] (50 items)," in line and "prisms[0]" not in line
    assert line.endswith("nothing was uploaded")
    assert fence_refusal(fence[:40], zones[:1], cap) is None
