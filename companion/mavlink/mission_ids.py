"""MISSION_CURRENT's plan ids, which pymavlink 2.4.50's dialects do not know (docs/autopilots.md; AUTOPILOT_FACTS:
"no opaque_id / mission_id fields"): MAVLink's newer common.xml appends ``mission_id``, ``fence_id`` and
``rally_points_id`` (uint32 each) to MISSION_CURRENT's extensions, after ``total``, ``mission_state`` and
``mission_mode``. A MAVLink 2 message carries them on the wire whatever the receiver's dialect, so they are read
from the message's own bytes here. PX4 (main of 2026-05, SITL) sends a checksum of the stored list as each id, new
on every upload (a mission of the same length too); ArduPilot 4.7 sends 0 ("unknown"): there only ``total`` tells,
and a readback must find a change that keeps the count."""

from __future__ import annotations

import struct
from typing import Any, NamedTuple

MAVLINK2_MAGIC = 0xFD
HEADER = 10  # MAVLink 2: magic, len, incompat, compat, seq, sysid, compid, msgid (3)
_LAYOUT = struct.Struct("<HHBBIII")  # seq, total, mission_state, mission_mode, mission_id, fence_id, rally_points_id


class PlanIds(NamedTuple):
    mission: int
    fence: int
    rally: int

    @property
    def known(self) -> bool:
        """The autopilot says which plan it holds (0 everywhere: it does not)."""
        return any(self)


def plan_ids(msg: Any) -> PlanIds:
    """The ids a MISSION_CURRENT carries (0 for each one absent: MAVLink 2 drops trailing zero bytes, MAVLink 1
    has no extensions)."""
    buf = bytes(msg.get_msgbuf())
    if len(buf) < HEADER or buf[0] != MAVLINK2_MAGIC:
        return PlanIds(0, 0, 0)
    payload = buf[HEADER:HEADER + buf[1]].ljust(_LAYOUT.size, b"\0")
    return PlanIds(*_LAYOUT.unpack_from(payload)[4:])


__all__ = ["PlanIds", "plan_ids"]
