"""Putting a verified mission back after an upload failed part-way.

ArduPilot writes uploaded items to storage as they arrive (docs/autopilots.md §3.7: uploads are not atomic), so an
upload refused at item k, or abandoned, leaves items 1…k−1 new and the rest old: a mission nobody verified.
The companion then restores the mission it last verified (or, before a flight, the one it read from the vehicle
first) and proves it by readback, so the vehicle is never left able to fly a mixed list.
"""

from __future__ import annotations

from collections.abc import Sequence

from companion.mavlink.errors import CompanionError, LinkError, MissionVerifyError
from companion.mavlink.items import MISSION, MissionItem
from companion.mavlink.protocol import MissionClient
from companion.mission.events import EventLog

RESTORE_ATTEMPTS = 3  # whole verified uploads tried to put the previous mission back
LINK_BACK_S = 30.0  # wall seconds a lost link may take to come back before a restore (or an upload) gives up


async def restore_mission(client: MissionClient, events: EventLog, previous: Sequence[MissionItem] | None,
                          mission_type: int = MISSION, attempts: int = RESTORE_ATTEMPTS) -> tuple[bool, str]:
    """Upload ``previous`` again and verify it; with ``previous`` None (never read), clear the list instead and
    read back that it is empty. Logs ``mission_restored`` (``which``: previous or cleared) or
    ``mission_restore_failed``; returns whether a verified list is stored now and what the vehicle was left
    with, in words, for the error message."""
    kind = "mission" if mission_type == MISSION else "fence"
    error: Exception | None = None
    for attempt in range(1, attempts + 1):
        if not await client.link.wait_back(LINK_BACK_S):  # a link fault: nothing can be restored without it
            error = LinkError(f"the link did not come back within {LINK_BACK_S:.0f} s")
            break
        try:
            if previous is None:
                await client.clear(mission_type)
                got = await client.download(mission_type)
                if len(got) > (1 if client.home_at_zero(mission_type) else 0):  # ArduPilot keeps home at 0
                    raise MissionVerifyError(len(got) - 1, "count", 0, len(got))
                events.log("mission_restored", mission_type=mission_type, which="cleared", attempt=attempt)
                return True, (f"the vehicle's previous {kind} was unknown, so its {kind} list was cleared "
                              "(verified empty)")
            got = await client.upload_verified(previous, mission_type)
            events.log("mission_restored", mission_type=mission_type, which="previous", items=len(got),
                       attempt=attempt)
            n = f"{len(got)} item{'' if len(got) == 1 else 's'}"
            return True, f"the previous verified {kind} ({n}) was restored (readback matches)"
        except (CompanionError, TimeoutError) as e:
            error = e
            events.log("mission_restore_attempt_failed", mission_type=mission_type, attempt=attempt, error=str(e))
    events.log("mission_restore_failed", mission_type=mission_type, error=str(error))
    return False, (f"restoring the previous {kind} failed too ({error}): the stored {kind} may be part old, "
                   "part new; do not start it")
