"""Flight supervisor: readiness, verified upload, mode/arm/start, progress monitoring (docs/design.md, "Companion").

Top of the companion's layers (link → mission protocol → builder → supervisor). Every decision is written
to the :class:`EventLog`; the CLI decides what the user sees.
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from companion.flight.departure import VehicleFix
from companion.mavlink.errors import (
    CommandError,
    CompanionError,
    LinkError,
    MissionTimeout,
    MissionUploadError,
    MissionVerifyError,
    UploadAborted,
)
from companion.mavlink.items import FENCE, MISSION, MissionItem
from companion.mavlink.link import Link, Message, Subscription
from companion.mavlink.modes import heartbeat_mode
from companion.mavlink.profiles import ARM, MODE, PILOT_ARM, START, profile_for
from companion.mavlink.protocol import MissionClient
from companion.mission import picture
from companion.mission.events import EventLog
from companion.mission.geo import geodetic_to_enu
from companion.mission.restore import LINK_BACK_S, restore_mission
from companion.mission.vehicle_state import VehicleState, subscribe
from planner.world.home import Home

log = logging.getLogger(__name__)
PREARM_BIT = 0x10000000  # MAV_SYS_STATUS_PREARM_CHECK
EKF_GOOD = 0x33F  # attitude, velocities, horizontal/vertical position, predicted positions
PILOT_ARM_TIMEOUT_S = 600.0
REPLANNER_STOP_S = 5.0  # wall seconds a cancelled replanner may take to finish (a plan in progress)
UPLOAD_ATTEMPTS = 3  # whole verified uploads tried before the flight when the link breaks one
BOOT_TIMEOUT_S = 60.0  # wall seconds an autopilot may take to finish booting
VERDICT_S = 3.0  # wall seconds PX4's navigator may take to accept a verified mission (measured: ≤ 0.21 s)
VERDICT_SETTLE_S = 0.5  # after a readback, wall seconds an old mission's MISSION_CURRENT may still come (> 2 × 0.21)
POSITION_EVERY_S = 0.1  # wall seconds between two ``position`` records (the status page's vehicle and track)
BOOT_GRACE_S = 10.0  # a MAV_MISSION_NO_SPACE this soon after boot is the boot's, not the mission's size
FIX_TIMEOUT_S = 5.0  # wall seconds for the vehicle's position (GLOBAL_POSITION_INT) before the upload
RESYNC_RETRY_S = 2.0  # wall seconds before a failed readback after an outage is tried again
HOME_TIMEOUT_S = 2.0  # wall seconds for its HOME_POSITION, asked for with MAV_CMD_REQUEST_MESSAGE


class DepartureRefused(CompanionError):
    """The vehicle is not where the scenario can be flown from (nothing was uploaded)."""


@dataclass
class FlightOutcome:
    completed: bool
    reason: str
    items_reached: list[int] = field(default_factory=list)
    upload_s: float = 0.0
    flight_s: float = 0.0
    mission_count: int = 0
    fence_count: int = 0
    track: list[tuple[float, float, float, float]] = field(default_factory=list)  # (t, lat, lon, alt_rel)
    statustexts: list[str] = field(default_factory=list)
    holding: bool = False  # ended with the vehicle held (loitering) by the companion


def _booting(hb: object) -> bool:
    """A HEARTBEAT of an autopilot that has not finished booting (its profile's ``booting``)."""
    return profile_for(hb.autopilot, hb.type).booting(hb.system_status, hb.custom_mode)  # type: ignore[attr-defined]  # pymavlink's HEARTBEAT


def _mode_name(hb: object) -> str:
    """The mode a HEARTBEAT reports, by name (pymavlink's: FBWA, not MODE_5)."""
    return heartbeat_mode(hb)


class Pilot(Protocol):
    """Who flies the mission beside the supervisor: a :class:`FixedMission`, or a
    replanner (:class:`~companion.replanning.replanner.LiveReplanner`) that changes it in flight."""

    state: VehicleState  # the vehicle, fed by the supervisor's one subscription

    @property
    def holding(self) -> str | None: ...  # why the pilot holds the vehicle, or None

    @property
    def goal_seq(self) -> int: ...  # the goal waypoint's item in the live mission

    @property
    def mission(self) -> list[MissionItem]: ...  # the mission last verified on the vehicle

    @property
    def changing(self) -> bool: ...  # the pilot is changing the vehicle's mission now (an upload, a restore)

    def near_goal(self) -> bool: ...  # a completion report may end the flight (not one from before a swap)

    def note_upload(self, seconds: float) -> None: ...

    async def ready(self) -> None: ...

    async def run(self) -> None: ...  # beside the flight until cancelled; raising ends the flight

    async def hold(self, reason: str) -> None: ...


class FixedMission:
    """The mission flown as uploaded, with nobody changing it: the pilot of a flight without replanning."""

    holding: str | None = None
    changing = False

    def __init__(self, items: Sequence[MissionItem], state: VehicleState) -> None:
        self.items, self.state = list(items), state
        self.goal_seq = max(it.seq for it in self.items if it.command == mavlink.MAV_CMD_NAV_WAYPOINT)

    @property
    def mission(self) -> list[MissionItem]:
        return self.items

    def near_goal(self) -> bool:
        return True

    def note_upload(self, seconds: float) -> None:
        pass

    async def ready(self) -> None:
        pass

    async def run(self) -> None:
        await asyncio.Event().wait()  # nothing to do beside the flight: waits to be cancelled

    async def hold(self, reason: str) -> None:
        raise CompanionError(f"nobody can hold the vehicle ({reason})")


def check_one_autopilot(link: Link, events: EventLog) -> None:
    """Before anything is uploaded: the target was not merely the first autopilot to speak. HEARTBEATs from
    another autopilot system refuse the flight unless the user chose the target (``--target-system``)."""
    others = sorted(link.other_autopilots)
    if not others:
        return
    events.log("other_autopilots", systems=others, target=link.target_system, pinned=link.pinned)
    if not link.pinned:
        raise CompanionError(f"HEARTBEATs from more than one autopilot on {link.url}: system {link.target_system} "
                             f"(heard first) and {', '.join(map(str, others))}; pass --target-system N to choose; "
                             "nothing was uploaded")


class FlightSupervisor:
    """Flies one mission. ``arm``: may the companion arm the vehicle (only when asked, or our own sim)."""

    def __init__(self, link: Link, client: MissionClient, events: EventLog, *, arm: bool,
                 home: Home | None = None) -> None:
        self.link = link
        self.client = client
        self.events = events
        self.arm = arm
        self.home = home  # with it, the ``mission`` and ``position`` records in the local frame
        self._position_at = -math.inf  # wall time of the last ``position`` record
        self.booted_at: float | None = None  # time.monotonic() when the autopilot was seen booted
        self.verified: list[MissionItem] = []  # the mission last verified on the vehicle
        self.readback: list[MissionItem] = []  # the vehicle's readback that verified it (as the vehicle stores it)
        self._outages_checked = 0  # link.outages when the vehicle's mission was last known to be ``verified``
        self.started = False  # armed or started: from here on a failure leaves a flight, not just a refusal
        self.mismatch: MissionVerifyError | None = None  # the last resync's difference, if it found one
        self.outcome: FlightOutcome | None = None  # the flight's, as far as it went (set by :meth:`fly`)

    # -- readiness ---------------------------------------------------------------------------------
    async def wait_booted(self, timeout: float = BOOT_TIMEOUT_S) -> None:
        """Wait until the autopilot has finished booting before touching its mission: its HEARTBEAT no longer
        says UNINIT/BOOT/CALIBRATING (nor, on ArduPlane, mode INITIALISING) and, from ArduPilot or PX4, a first
        SYS_STATUS has come (the profile's boot fields). An ArduPilot that is still booting refuses every upload
        with MAV_MISSION_NO_SPACE (docs/autopilots.md §1.3: a companion usually powers up with its autopilot)."""
        t0 = time.monotonic()
        hb, status_seen, said = self.link.last_heartbeat_msg, not self.link.profile.boot_needs_status, False
        with self.link.subscribe("HEARTBEAT", "SYS_STATUS") as sub:
            while hb is None or _booting(hb) or not status_seen:
                if not said and hb is not None and _booting(hb):
                    self.events.log("booting", system_status=hb.system_status, mode=_mode_name(hb))
                    said = True
                left = timeout - (time.monotonic() - t0)
                if left <= 0:
                    what = (f"HEARTBEAT system_status {hb.system_status}, mode {_mode_name(hb)}"
                            if hb is not None and _booting(hb) else "no SYS_STATUS")
                    raise CompanionError(f"the autopilot did not finish booting within {timeout:.0f} s ({what}); "
                                         "nothing was uploaded")
                try:
                    msg = await sub.get(left)
                except TimeoutError:
                    continue
                if msg.get_type() == "HEARTBEAT":
                    hb = msg
                else:
                    status_seen = True
        self.booted_at = time.monotonic()
        if said:
            self.events.log("booted", seconds=round(self.booted_at - t0, 2))

    def _refused_while_booting(self, e: Exception, kind: int = MISSION) -> bool:
        """A mission upload refused with MAV_MISSION_NO_SPACE by an autopilot that is booting or has just booted
        (its mission storage is not ready yet): worth doing again, unlike a real lack of space. A fence or rally
        upload during the boot is not refused (ArduPilot answers it once booted), so their NO_SPACE is always a
        real lack of space (docs/autopilots.md §5.9)."""
        if kind != MISSION or not (isinstance(e, MissionUploadError) and e.result == mavlink.MAV_MISSION_NO_SPACE):
            return False
        hb = self.link.last_heartbeat_msg
        recent = self.booted_at is not None and time.monotonic() - self.booted_at < BOOT_GRACE_S
        return recent or (hb is not None and _booting(hb))

    async def wait_ready(self, timeout: float) -> None:
        """Wait for a 3-D GPS fix, a healthy pre-arm check and a good EKF (each only if the autopilot
        reports it), instead of retrying arming blindly (docs/autopilots.md §6.1–6.2: 'System not initialised')."""
        state: dict[str, bool | None] = {"gps": None, "prearm": None, "ekf": None}  # None: not reported

        def ready() -> bool:
            return all(v is None or v for v in state.values()) and state["gps"] is not None

        deadline = time.monotonic() + timeout
        health_only = self.link.profile.prearm_health_only
        with self.link.subscribe("GPS_RAW_INT", "SYS_STATUS", "EKF_STATUS_REPORT") as sub:
            while not ready():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise CompanionError(f"vehicle not ready to arm after {timeout:.0f} s: {state}")
                try:
                    msg = await sub.get(left)
                except TimeoutError:
                    continue
                kind = msg.get_type()
                if kind == "GPS_RAW_INT":
                    state["gps"] = msg.fix_type >= 3
                elif kind == "SYS_STATUS" and (msg.onboard_control_sensors_present & PREARM_BIT or health_only):
                    state["prearm"] = bool(msg.onboard_control_sensors_health & PREARM_BIT)
                elif kind == "EKF_STATUS_REPORT":
                    state["ekf"] = (msg.flags & EKF_GOOD) == EKF_GOOD
        self.events.log("ready", **{k: v for k, v in state.items() if v is not None})

    async def vehicle_fix(self, timeout: float = FIX_TIMEOUT_S) -> tuple[VehicleFix, bool]:
        """Where the vehicle is, its heading and its autopilot's home, in the scenario's frame (needs ``home``),
        and whether it is on the ground: the departure is planned and checked from there."""
        assert self.home is not None
        try:
            pos = await self.link.wait_for("GLOBAL_POSITION_INT", timeout=timeout)
        except TimeoutError:
            raise DepartureRefused(f"no GLOBAL_POSITION_INT from the vehicle within {timeout:.0f} s: cannot check "
                                   "where it takes off from; nothing was uploaded") from None
        home = None
        with self.link.subscribe("HOME_POSITION") as sub:
            try:
                await self.client.command_long(mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_HOME_POSITION,
                                               timeout=0.5, retries=2, persist=False)
                hp = await sub.get(HOME_TIMEOUT_S)
                home = geodetic_to_enu(hp.latitude / 1e7, hp.longitude / 1e7, hp.altitude / 1000.0, self.home)
            except (CommandError, TimeoutError):
                pass
        home_up = 0.0 if home is None else float(home[2])
        e, n, _u = geodetic_to_enu(pos.lat / 1e7, pos.lon / 1e7, self.home.alt, self.home)
        fix = VehicleFix(np.array([float(e), float(n), home_up + pos.relative_alt / 1000.0]),
                         None if pos.hdg == 65535 else pos.hdg / 100.0, home)
        on_ground = pos.relative_alt < 2000 and math.hypot(pos.vx, pos.vy) < 300
        self.events.log("vehicle_fix", on_ground=on_ground, **fix.summary())
        return fix, on_ground

    # -- upload ------------------------------------------------------------------------------------
    async def upload(self, items: Sequence[MissionItem], fence: Sequence[MissionItem] = (),
                     attempts: int = UPLOAD_ATTEMPTS, before: Callable[[], None] | None = None) -> float:
        """Upload and verify by readback (mission, then fence if any); returns the seconds it took. Before the
        flight a transfer the link broke (timeout, the autopilot's own timeout cancelling it, a readback that
        differs) is simply done again, up to ``attempts`` times; a refusal of an item is not. Each list is read
        first, so that if its upload fails for good the previous one can be restored (the stored list may be
        part new, part old): raises :class:`UploadAborted` saying what the vehicle was left with. A list that fails
        after an earlier one was stored (the fence after the mission) has the earlier one restored too, so the
        vehicle is not left with half of the upload. ``before`` is called after the backups are read, right before
        the first transfer (nothing changed yet): raising there (the vehicle armed meanwhile) leaves every list as it
        was."""
        self.events.log("upload_start", mission_items=len(items), fence_items=len(fence))
        dt = 0.0  # the uploads' own time, not the backups' (the replanner's first guess at a replan upload)
        if items and self.link.profile.first_item_current_on_upload:
            # PX4 keeps its current item across uploads: the first item flagged current resets it
            items = [replace(items[0], current=1), *items[1:]]
        stored: list[tuple[int, list[MissionItem] | None]] = []  # lists this call changed, with their backups
        for kind, payload in ((MISSION, items), (FENCE, fence)):
            if not payload:
                continue
            previous = await self._backup(kind)
            if before is not None and not stored:
                before()
            t0 = time.monotonic()
            got: list[MissionItem] = []
            for attempt in range(1, attempts + 1):
                try:
                    got = await self.client.upload_verified(payload, kind)
                    break
                except (MissionTimeout, MissionVerifyError, MissionUploadError, LinkError) as e:
                    booting = self._refused_while_booting(e, kind)
                    transient = booting or not (isinstance(e, MissionUploadError) and e.refused)
                    self.events.log("upload_failed", mission_type=kind, attempt=attempt, error=str(e),
                                    retrying=transient and attempt < attempts)
                    back = await self._link_back(e)
                    if not back:
                        raise UploadAborted(e, f"the link did not come back within {LINK_BACK_S:.0f} s, so the "
                                            "vehicle's list could not be restored: it may be part new, part old; "
                                            "do not start it") from e
                    if not transient or attempt == attempts:
                        _, left_with = await restore_mission(self.client, self.events, previous, kind)
                        for earlier, backup in stored:  # the mission stored before a failed fence: put back too
                            ok, also = await restore_mission(self.client, self.events, backup, earlier)
                            left_with = f"{left_with}; {also}"
                            if earlier == MISSION:
                                self.verified = list(backup or []) if ok else []
                        raise UploadAborted(e, left_with) from e
                    if booting:
                        await self.wait_booted()
                        await asyncio.sleep(1.0)
            dt += time.monotonic() - t0
            stored.append((kind, previous))
            if kind == MISSION:
                self.verified, self.readback, self._outages_checked = list(payload), got, self.link.outages
            if kind == MISSION and self.link.profile.awaits_mission_verdict:
                await self._mission_verdict(len(payload), settle=previous is None or len(previous) == len(payload))
        self.events.log("upload_verified", seconds=round(dt, 3))
        return dt

    async def _link_back(self, error: Exception) -> bool:
        """After a failed transfer: wait until the link is up again (a link fault, not a refusal: the transfer is
        done again or the previous list restored once it is back). False if it stays down LINK_BACK_S."""
        if self.link.connected and self.link.heartbeat_age <= self.link.heartbeat_timeout \
                and not isinstance(error, LinkError):
            return True
        self.events.log("waiting_for_link", error=str(error), up_to_s=LINK_BACK_S)
        back = await self.link.wait_back(LINK_BACK_S)
        self.events.log("link_back" if back else "link_not_back", reconnects=self.link.reconnects)
        return back

    async def check_outages(self, expected: Sequence[MissionItem] | None = None) -> bool | None:
        """If the autopilot's HEARTBEATs stopped for longer than the outage threshold (or the connection was
        made again) since the mission was last verified, read it back and compare (``resync``) before anything
        else: however the gap was noticed, by the monitor's poll or by the link's own reconnect. Returns whether
        the vehicle still has the verified mission (True when there was no outage); None when the readback could
        not be made (the link went again): still unknown, to be tried again."""
        expected = self.verified if expected is None else expected
        if self.link.outages == self._outages_checked or not expected:
            return True
        self.events.log("link_gap", outages=self.link.outages - self._outages_checked,
                        last_s=round(self.link.last_outage_s, 1))
        outages = self.link.outages
        try:
            ok = await self.resync(expected)
        except (MissionTimeout, MissionUploadError, LinkError, TimeoutError) as e:
            self.events.log("resync_failed", error=str(e), decision="not known yet: read back again")
            return None
        if ok:
            self._outages_checked = outages
        return ok

    async def _mission_verdict(self, count: int, timeout: float = VERDICT_S, settle: bool = False) -> None:
        """Wait for the navigator's verdict on a verified mission (the profile's ``awaits_mission_verdict``: PX4):
        MISSION_CURRENT with the new total and mission_state NOT_STARTED/ACTIVE (valid) or NO_MISSION (rejected,
        the reason only in PX4's EVENT messages). Starting before it is DENIED. With ``settle`` (the mission before
        had as many items, or is unknown) the total cannot tell the new mission's report from the old one's, which
        the navigator sends until it has taken the new one: a report is believed only VERDICT_SETTLE_S after the
        readback (in CI, a rejected mission once passed on the old one's valid report)."""
        valid = (mavlink.MISSION_STATE_NOT_STARTED, mavlink.MISSION_STATE_ACTIVE, mavlink.MISSION_STATE_PAUSED)
        with self.link.subscribe("MISSION_CURRENT", predicate=lambda m: m.total == count) as sub:
            start = time.monotonic()
            deadline = start + timeout
            state = None
            while (left := deadline - time.monotonic()) > 0:
                try:
                    state = (await sub.get(left)).mission_state
                except TimeoutError:
                    break
                if settle and time.monotonic() - start < VERDICT_SETTLE_S:
                    continue
                if state in valid:
                    self.events.log("mission_valid", items=count, mission_state=state)
                    return
        raise CompanionError(f"PX4 stored the {count} verified items but its navigator did not accept the mission "
                             f"within {timeout:.0f} s (MISSION_CURRENT mission_state {state}: "
                             "1 = NO_MISSION means it was rejected; PX4 says why in its events/log)")

    async def _backup(self, kind: int) -> list[MissionItem] | None:
        """The vehicle's ``kind`` list before we overwrite it (None if it cannot be read: a restore then
        clears the list instead)."""
        try:
            previous = await self.client.download(kind)
        except (CompanionError, TimeoutError) as e:
            self.events.log("backup_failed", mission_type=kind, error=str(e))
            return None
        self.events.log("backup", mission_type=kind, items=len(previous))
        return previous

    async def resync(self, expected: Sequence[MissionItem]) -> bool:
        """After a link outage, read the mission back before acting again: it must still be the one we
        verified (nobody else uploaded meanwhile, nothing half-written). False on a mismatch (logged)."""
        try:
            got = await self.client.verify(expected, MISSION)
        except MissionVerifyError as e:
            self.events.log("resync_mismatch", seq=e.seq, field=e.field, sent=str(e.sent), got=str(e.got))
            self.mismatch = e
            return False
        self.events.log("resync", items=len(got), result="the vehicle still has our verified mission")
        return True

    # -- start -------------------------------------------------------------------------------------
    async def set_mode(self, name: str) -> None:
        """MAV_CMD_DO_SET_MODE as the autopilot's profile packs it."""
        profile = self.link.profile
        await self.client.command_long(mavlink.MAV_CMD_DO_SET_MODE,
                                       *profile.set_mode_params(profile.mode_number(name)))
        self.events.log("mode", mode=name)

    async def arm_vehicle(self, attempts: int = 5) -> None:
        for attempt in range(attempts):
            try:
                await self.client.command_long(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
                self.events.log("armed")
                return
            except CommandError as e:
                self.events.log("arm_refused", result=e.result, attempt=attempt + 1)
                if e.result is None or attempt == attempts - 1:
                    raise
                await asyncio.sleep(1.0)

    async def start(self, first_seq: int) -> None:
        """Make the first item current, then the autopilot's start sequence (its profile's; the pilot arms
        unless the companion may): ArduPlane AUTO → arm → start; ArduCopter GUIDED → arm → AUTO → start; PX4
        arm → mission → start."""
        profile = self.link.profile
        await self.client.set_current(first_seq)
        self.events.log("set_current", seq=first_seq)
        for step in profile.start_sequence if self.arm else profile.pilot_arm_sequence:
            if step in (ARM, PILOT_ARM, START) and not await self.check_outages():
                raise CompanionError(f"the vehicle's mission changed during a link outage ({self.mismatch}) or "
                                     "could not be read back after one: it is not known to be the mission verified; "
                                     + ("not started" if self.started else "not armed or started"))
            if step.startswith(MODE):
                await self.set_mode(step.removeprefix(MODE))
            elif step == ARM:
                self.started = True  # from the command on: an ACK lost on the link does not mean it did not arm
                await self.arm_vehicle()
            elif step == PILOT_ARM:
                await self._wait_pilot_arm()
                self.started = True
                if not await self.check_outages():  # armed in AUTO, it flies at once: the wait may have been long
                    raise CompanionError(f"the vehicle's mission changed during a link outage while waiting for the "
                                         f"pilot to arm ({self.mismatch}), or could not be read back after one")
            elif step == START:  # (the profile has checked its steps)
                self.started = True
                await self.client.command_long(mavlink.MAV_CMD_MISSION_START, 0, 0)
                self.events.log("mission_start")

    async def _wait_pilot_arm(self) -> None:
        self.events.log("waiting_for_pilot_arm", note="the companion arms only with --arm")
        try:
            await self.link.wait_for("HEARTBEAT", timeout=PILOT_ARM_TIMEOUT_S,
                                     predicate=lambda m: m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        except TimeoutError:
            raise CompanionError(f"the vehicle was not armed within {PILOT_ARM_TIMEOUT_S:.0f} s "
                                 "(pass --arm to let the companion arm it)") from None

    # -- monitor -----------------------------------------------------------------------------------
    async def monitor(self, pilot: Pilot, timeout: float, outcome: FlightOutcome,
                      sub: Subscription | None = None) -> None:
        """Follow progress until the goal waypoint is reached (or the autopilot says the mission is complete);
        fills ``outcome``. ``timeout`` in wall seconds. Every message of the flight's one subscription (pass it
        opened before the start, so nothing sent right after MISSION_START is missed) goes to the pilot's vehicle
        state first. The pilot (a :class:`FixedMission`, or a replanner run here as its own task) says where the
        goal is and which mission is verified on the vehicle; its failure ends the flight with the vehicle held."""
        t0 = time.monotonic()
        task = asyncio.create_task(pilot.run(), name="pilot")
        try:
            with sub if sub is not None else subscribe(self.link) as sub:
                await self._follow(sub, pilot, timeout, outcome, task)
        finally:
            if not task.done():
                task.cancel()
                done, _ = await asyncio.wait({task}, timeout=REPLANNER_STOP_S)
                if not done:
                    log.error("the replanner did not stop within %.0f s of being cancelled", REPLANNER_STOP_S)
        outcome.flight_s = time.monotonic() - t0
        outcome.holding = pilot.holding is not None

    async def _resync_in_flight(self, pilot: Pilot, noticed: bool) -> bool | None:
        """After an outage in flight (``noticed``: the monitor's poll saw it; else the reconnect was quicker):
        the link's records, then the readback of the pilot's mission. True: still ours, the link is restored;
        False: changed; None: not known yet (the readback failed, or the pilot changed the mission meanwhile)."""
        state = pilot.state
        if not noticed:
            self.events.log("link_lost", age_s=round(self.link.last_outage_s, 1), noticed="on its return",
                            decision="the vehicle kept flying its verified mission")
            state.link_lost()
        self.events.log("link_restored", outage_s=round(self.link.last_outage_s, 1))
        expected = pilot.mission
        verdict = await self.check_outages(expected)
        if verdict is False and (pilot.changing or pilot.mission is not expected):
            return None  # the pilot changed the mission meanwhile: read it again once that is done
        if verdict:
            state.link_restored()
        return verdict

    async def _follow(self, sub: Subscription, pilot: Pilot, timeout: float, outcome: FlightOutcome,
                      task: asyncio.Task) -> None:
        state = pilot.state
        t0 = time.monotonic()
        last_current = None
        lost_at: float | None = None  # when the link was found lost
        resync_at = 0.0  # not before: a readback after an outage that failed is tried again from then
        while True:
            if task.done():
                exc = task.exception()
                outcome.reason = str(exc) if exc is not None else "replanner stopped"
                self.events.log("replanner_failed", error=outcome.reason)
                if exc is not None and not isinstance(exc, CompanionError):
                    log.error("replanner failed", exc_info=exc)
                if pilot.holding is None:
                    # it saw a conflict it could not resolve, or broke: do not fly on unsupervised into it
                    try:
                        await pilot.hold(f"replanner stopped: {outcome.reason}")
                    except CompanionError as e:
                        self.events.log("hold_failed", error=str(e))
                return
            left = timeout - (time.monotonic() - t0)
            if left <= 0:
                outcome.reason = f"timeout after {timeout:.0f} s"
                self.events.log("timeout", seconds=timeout)
                return
            try:
                msg = await sub.get(min(left, 0.2))
            except TimeoutError:
                msg = None
            # looked at on every pass: ADS-B from a receiver on another path may keep coming when the autopilot's
            # link is gone
            if lost_at is None and self.link.heartbeat_age > self.link.heartbeat_timeout:
                age = self.link.heartbeat_age
                lost_at = time.monotonic() - (age if math.isfinite(age) else 0.0)  # the last HEARTBEAT heard
                self.events.log("link_lost", age_s=round(age, 1),
                                decision="the vehicle keeps flying its verified mission; waiting for the link")
                state.link_lost()
            if msg is None:
                continue
            if self.link.outages != self._outages_checked and not pilot.changing \
                    and time.monotonic() >= resync_at:  # however the gap was noticed: one mechanism
                # (while the pilot changes the mission, its own readback proves what is stored: look after it)
                verdict = await self._resync_in_flight(pilot, noticed=lost_at is not None)
                if verdict is None:  # not known yet: still lost, read back again shortly
                    lost_at, resync_at = lost_at or time.monotonic(), time.monotonic() + RESYNC_RETRY_S
                    continue
                lost_at = None
                if not verdict:
                    outcome.reason = (f"the vehicle's mission changed during a link outage ({self.mismatch}): it "
                                      "is not the mission verified, so the companion stopped supervising; the "
                                      "vehicle keeps its mode and that mission")
                    self.events.log("aborted", reason=outcome.reason)
                    return
            state.observe(msg)
            kind = msg.get_type()
            t = time.monotonic() - t0
            goal_seq = pilot.goal_seq
            if kind == "GLOBAL_POSITION_INT":
                outcome.track.append((t, msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000.0))
                self._log_position(msg, state)
            elif kind == "MISSION_ITEM_REACHED":
                if msg.seq not in outcome.items_reached:
                    outcome.items_reached.append(msg.seq)
                    self.events.log("reached", seq=msg.seq, of=goal_seq)
                if msg.seq == goal_seq and pilot.near_goal():
                    outcome.completed, outcome.reason = True, "goal waypoint reached"
                    return
            elif kind == "MISSION_CURRENT" and msg.seq != last_current:
                last_current = msg.seq
                self.events.log("current", seq=msg.seq)
                if msg.seq > goal_seq and pilot.near_goal():
                    # past the goal (its REACHED may have been lost on the link)
                    outcome.completed, outcome.reason = True, f"mission current item {msg.seq} is past the goal"
                    return
            elif kind == "STATUSTEXT":
                text = msg.text.rstrip("\x00")
                outcome.statustexts.append(text)
                self.events.log("statustext", severity=msg.severity, text=text)
                if "mission complete" in text.lower():
                    outcome.completed, outcome.reason = True, text
                    return
            elif kind == "HEARTBEAT" and not msg.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED \
                    and outcome.items_reached:
                outcome.reason = "vehicle disarmed before the goal"
                self.events.log("disarmed")
                return

    def _log_position(self, msg: Message, state: VehicleState) -> None:
        """A ``position`` record (the vehicle state's position in the local frame, ground speed, heading), at most
        every :data:`POSITION_EVERY_S`."""
        now = time.monotonic()
        if self.home is None or state.position is None or now - self._position_at < POSITION_EVERY_S:
            return
        self._position_at = now
        x, y, z = (round(float(v), 1) for v in state.position)
        self.events.log("position", x=x, y=y, z=z, gs=round(state.groundspeed, 1),
                        hdg=None if msg.hdg == 65535 else round(msg.hdg / 100, 1))

    async def fly(self, items: Sequence[MissionItem], fence: Sequence[MissionItem] = (), *,
                  ready_timeout: float = 60.0, flight_timeout: float = 600.0,
                  replanner: Pilot | None = None,
                  departure: Callable[[VehicleFix, bool], None] | None = None) -> FlightOutcome:
        """Ready → where is the vehicle (``departure`` checks it, raising :class:`DepartureRefused`) → upload +
        verify → start → monitor (and replan, with a ``replanner``). Raises on link/upload failures (the CLI maps
        them)."""
        out = self.outcome = FlightOutcome(False, "", mission_count=len(items), fence_count=len(fence))
        hb = await self.link.wait_heartbeat(timeout=10.0)
        mode = _mode_name(hb)
        self.events.log("connected", system=self.link.target_system, autopilot=hb.autopilot,
                        vehicle_type=hb.type, mode=mode, armed=bool(hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED))
        if hb.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
            # an upload is not atomic: it would change, item by item, the mission the vehicle may be flying
            raise CompanionError(f"the vehicle is armed (mode {mode}): fuseplan fly uploads a mission only to a "
                                 "disarmed vehicle; nothing was uploaded")
        await self.wait_booted()
        await self.wait_ready(ready_timeout)  # a position fix first: the departure is checked from it
        if departure is not None:
            departure(*await self.vehicle_fix())
        check_one_autopilot(self.link, self.events)
        out.upload_s = await self.upload(items, fence)
        if self.home is not None:
            self.events.log("mission", **picture.mission(items, self.home))
        pilot: Pilot = replanner if replanner is not None else FixedMission(items, VehicleState(self.home))
        pilot.note_upload(out.upload_s)
        await pilot.ready()  # a replanner's planner process warmed up before take-off, not at the first conflict
        first = next(it.seq for it in items if it.command != mavlink.MAV_CMD_NAV_WAYPOINT or it.seq > 0)
        with subscribe(self.link) as sub:
            await self.start(first)
            pilot.state.mission_started(time.monotonic())
            await self.monitor(pilot, flight_timeout, out, sub)
        self.events.log("finished", completed=out.completed, reason=out.reason, reached=len(out.items_reached))
        return out
