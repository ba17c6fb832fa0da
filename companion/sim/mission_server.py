"""Autopilot side of the MAVLink mission protocol, as ArduPilot's ``MissionItemProtocol`` behaves (sans-IO).

Messages come in through :meth:`MissionServer.handle` and go out through the ``send`` callback; timeouts run on
the simulator's clock (:meth:`MissionServer.tick`), so at a speed-up they shrink in wall time as in SITL.

ArduPilot behaviour reproduced (docs/autopilots.md §1.3, §3–5, ``libraries/GCS_MAVLink/MissionItemProtocol.cpp``):

- Uploads are requested with the legacy MISSION_REQUEST (id 40); MISSION_ITEM_INT and MISSION_ITEM are accepted.
- A request is repeated after 1 s without an item; after 8 s without progress the upload is abandoned with
  MISSION_ACK MAV_MISSION_OPERATION_CANCELLED, then STATUSTEXT "Mission upload timeout" ("Fence …", "Rally …").
- An item whose seq is not the one requested → MISSION_ACK MAV_MISSION_INVALID_SEQUENCE (the upload goes on and
  the request is repeated on the next timeout); an item from another sysid/compid → MAV_MISSION_DENIED; an item
  while no upload runs → MAV_MISSION_ERROR; MISSION_COUNT from another sender during an upload → DENIED (the same
  sender restarts); a download request during an upload → DENIED.
- Mission uploads are **not atomic**. MISSION_COUNT truncates the stored mission to ``count`` items at once; each
  accepted item is then written into place (replacing, or appending at the end), so an upload that fails part-way
  leaves the new items 1..k followed by the old items k+1..count-1 (as far as the old mission reached).
  Fence uploads are staged and replace the fence only when complete (ArduPilot's polyfence loader does that);
  rally points are written in place as the mission is (AP_Rally).
- A completed fence upload is checked as a whole before it replaces the fence (AC_PolyFence_loader's
  ``validate_fence`` and ``write_fence``, :func:`fence_problem`): a polygon of fewer than 3 vertices, a vertex of
  another polygon type or count before the polygon's count is reached, a polygon cut short by the end of the list,
  a circle of radius ≤ 0, a second return point, or more than the fence storage holds → STATUSTEXT with the reason,
  "Fence validation failed" (not for the storage), MISSION_ACK MAV_MISSION_ERROR, and the old fence stays.
- Item 0 of the mission is home: an uploaded item 0 is acknowledged and ignored; a download of item 0 returns
  the live home in MAV_FRAME_GLOBAL with AMSL altitude; downloads answer with the non-INT frame numbers
  (5→0, 6→3, 11→10). MISSION_REQUEST_INT is answered with MISSION_ITEM_INT, the legacy MISSION_REQUEST with a
  float MISSION_ITEM, as ArduPilot does.
- Validation: global frames (plain or INT, relative, terrain) for every command; MAV_FRAME_MISSION only for
  commands without a location; anything else → MAV_MISSION_UNSUPPORTED_FRAME. NaN only in param4 of NAV
  commands (NaN in param n → MAV_MISSION_INVALID_PARAMn, in z → INVALID_PARAM7); latitude/longitude range →
  INVALID_PARAM5_X / INVALID_PARAM6_Y; unknown commands → MAV_MISSION_UNSUPPORTED. A failed item ends the upload.
- MISSION_WRITE_PARTIAL_LIST(start, end): DENIED while any upload of that list runs; MISSION_ACK
  MAV_MISSION_ERROR and STATUSTEXT "Flight plan update rejected" unless start ≤ end ≤ count; otherwise the range
  is requested item by item with the legacy MISSION_REQUEST and written in place (seq == count appends one,
  nothing is truncated), then MISSION_ACK ACCEPTED (4.7 SITL, tests/conformance/test_partial_write.py).
- Downloads keep no state: a single MISSION_REQUEST_INT is answered at any time outside an upload; one past the
  end gets MISSION_COUNT (the real count) and then MISSION_ACK MAV_MISSION_INVALID_SEQUENCE, as SITL answers.
- MISSION_CLEAR_ALL is refused (MAV_MISSION_ERROR) during an upload or while the mission is running.
- Items are kept as ArduPilot stores them: :func:`companion.mavlink.storage.stored` for the vehicle's firmware (fence
  points in frame GLOBAL with autocontinue 0 and only param1, NAV_WAYPOINT's radii on a plane / hold time on a
  copter, commands without a position in frame GLOBAL…), so a readback is the real one.
- While booting (``capacity`` says so) a mission upload is refused at MISSION_COUNT with MAV_MISSION_NO_SPACE
  and STATUSTEXT "Only 0 items are supported"; a fence or rally MISSION_COUNT gets no answer until the boot is
  over, then its upload starts (SITL: the first MISSION_REQUEST ~0.1 s after "ArduPilot Ready"). Until home is
  set (``home_set``) an untouched mission reads back with count 0, and item 0 as all zeros.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass, replace

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.mavlink.fence_capacity import ARDUPILOT_BYTES_PER_ITEM, ardupilot_fence_bytes
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem, normalise_frame
from companion.mavlink.storage import Firmware, stored

logger = logging.getLogger(__name__)

REQUEST_RESEND_S = 1.0  # ArduPilot: 1000 ms (+ stream slow-down) without an item → request again
UPLOAD_TIMEOUT_S = 8.0  # ArduPilot upload_timeout_ms
LIST_NAME = {MISSION: "Mission", FENCE: "Fence", RALLY: "Rally"}  # in ArduPilot's STATUSTEXTs
# what ArduPlane 4.7 SITL holds ("Only 84 items are supported" for a fence of 85, "Only 50 …" for 100 rally points);
# the simulated copter's fence is ArduCopter's (companion.mavlink.fence_capacity: 70 items, 560 bytes)
MAX_ITEMS = {MISSION: 724, FENCE: 84, RALLY: 50}
FENCE_BYTES_PER_ITEM = ARDUPILOT_BYTES_PER_ITEM  # AC_PolyFence_loader::max_items() is the storage's size / 8

GLOBAL_FRAMES = frozenset({
    mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
})
NAV_LAST = 95  # MAV_CMD_NAV_LAST: commands below this are NAV commands
_LOCATIONLESS = frozenset({  # commands ArduPilot does not store with a location: MAV_FRAME_MISSION is fine
    mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, mavlink.MAV_CMD_NAV_DELAY,
    mavlink.MAV_CMD_CONDITION_DELAY, mavlink.MAV_CMD_CONDITION_DISTANCE, mavlink.MAV_CMD_CONDITION_YAW,
    mavlink.MAV_CMD_DO_JUMP, mavlink.MAV_CMD_DO_CHANGE_SPEED, mavlink.MAV_CMD_DO_SET_SERVO,
    mavlink.MAV_CMD_DO_SET_RELAY, mavlink.MAV_CMD_DO_REPEAT_SERVO, mavlink.MAV_CMD_DO_REPEAT_RELAY,
    mavlink.MAV_CMD_DO_DIGICAM_CONTROL, mavlink.MAV_CMD_DO_SET_CAM_TRIGG_DIST, mavlink.MAV_CMD_DO_FENCE_ENABLE,
    mavlink.MAV_CMD_DO_AUTOTUNE_ENABLE, mavlink.MAV_CMD_DO_MOUNT_CONTROL, mavlink.MAV_CMD_DO_GRIPPER,
    mavlink.MAV_CMD_DO_SET_ROI_NONE, mavlink.MAV_CMD_DO_VTOL_TRANSITION, mavlink.MAV_CMD_DO_SET_RESUME_REPEAT_DIST,
    mavlink.MAV_CMD_DO_ENGINE_CONTROL, mavlink.MAV_CMD_DO_INVERTED_FLIGHT, mavlink.MAV_CMD_DO_PARACHUTE,
    mavlink.MAV_CMD_IMAGE_START_CAPTURE, mavlink.MAV_CMD_IMAGE_STOP_CAPTURE, mavlink.MAV_CMD_VIDEO_START_CAPTURE,
    mavlink.MAV_CMD_VIDEO_STOP_CAPTURE, mavlink.MAV_CMD_JUMP_TAG, mavlink.MAV_CMD_DO_JUMP_TAG,
})
_WITH_LOCATION = frozenset({
    mavlink.MAV_CMD_NAV_WAYPOINT, mavlink.MAV_CMD_NAV_LOITER_UNLIM, mavlink.MAV_CMD_NAV_LOITER_TURNS,
    mavlink.MAV_CMD_NAV_LOITER_TIME, mavlink.MAV_CMD_NAV_LAND, mavlink.MAV_CMD_NAV_TAKEOFF,
    mavlink.MAV_CMD_NAV_CONTINUE_AND_CHANGE_ALT, mavlink.MAV_CMD_NAV_LOITER_TO_ALT,
    mavlink.MAV_CMD_NAV_SPLINE_WAYPOINT, mavlink.MAV_CMD_NAV_VTOL_TAKEOFF, mavlink.MAV_CMD_NAV_VTOL_LAND,
    mavlink.MAV_CMD_NAV_PAYLOAD_PLACE, mavlink.MAV_CMD_DO_SET_HOME, mavlink.MAV_CMD_DO_LAND_START,
    mavlink.MAV_CMD_DO_GO_AROUND, mavlink.MAV_CMD_DO_SET_ROI, mavlink.MAV_CMD_DO_SET_ROI_LOCATION,
    mavlink.MAV_CMD_CONDITION_CHANGE_ALT,
})
_FENCE_COMMANDS = frozenset({
    mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION,
})


# AC_PolyFenceType numbers, as ArduPilot's validation texts show them (a circle inside a polygon: "want=98 got=93" on
# ArduPlane 4.7 SITL; 96 and 94 are the whole-metre circles' storage types)
_POLYFENCE_TYPE = {
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION: 98, mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION: 97,
    mavlink.MAV_CMD_NAV_FENCE_RETURN_POINT: 95, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION: 93,
    mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION: 92,
}
_POLYGON_VERTEX = frozenset({mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
                             mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION})
_CIRCLES = frozenset({mavlink.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, mavlink.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION})


def _vertex_count(item: MissionItem) -> int:
    """A polygon vertex's count (param1, which :func:`stored` has made the byte ArduPilot keeps)."""
    return int(max(item.param1, 0.0))


def fence_problem(items: list[MissionItem], storage_bytes: int) -> tuple[str, bool] | None:
    """Why ArduPilot would refuse a completed fence upload, or None: its STATUSTEXT and whether "Fence validation
    failed" follows. AC_PolyFence_loader's ``validate_fence`` item by item, then the storage the fence needs
    (``fence_storage_space_required``, :func:`companion.mavlink.fence_capacity.ardupilot_fence_bytes`)."""
    want_type = left = count = 0
    seen_return = False
    for item in items:
        kind = _POLYFENCE_TYPE[item.command]
        if item.command in _POLYGON_VERTEX:
            n = _vertex_count(item)
            if n < 3:
                return f"Invalid vertex count ({n})", True
            if left == 0:
                want_type, left, count = kind, n, n
            elif kind != want_type:
                return f"Received incorrect vertex type (want={want_type} got={kind})", True
            elif n != count:
                return f"Unexpected vertex count want={count} got={n}\n", True  # ArduPilot's text ends so
            left -= 1
            continue
        if left:
            return f"Received incorrect type (want={want_type} got={kind})", True
        if item.command in _CIRCLES:
            if not item.param1 > 0:
                return "Non-positive circle radius", True
        else:  # the return point
            if seen_return:
                return "Multiple return points", True
            seen_return = True
    if left:
        return "Incorrect item count", True  # ArduPilot sends this one as MAV_SEVERITY_INFO
    if ardupilot_fence_bytes(items) > storage_bytes:
        return "Fence exceeds storage size", False
    return None


def is_nav(command: int) -> bool:
    return command < NAV_LAST


def validate_item(item: MissionItem) -> int:
    """MAV_MISSION_RESULT for one uploaded item: ACCEPTED or the error ArduPilot would give."""
    if item.mission_type in (FENCE, RALLY):
        allowed = _FENCE_COMMANDS if item.mission_type == FENCE else {mavlink.MAV_CMD_NAV_RALLY_POINT}
        if item.command not in allowed:
            return mavlink.MAV_MISSION_UNSUPPORTED
        if item.frame not in GLOBAL_FRAMES:
            return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    else:
        if item.command not in _LOCATIONLESS and item.command not in _WITH_LOCATION:
            return mavlink.MAV_MISSION_UNSUPPORTED
        if item.frame not in GLOBAL_FRAMES and not (
                item.frame == mavlink.MAV_FRAME_MISSION and item.command in _LOCATIONLESS):
            return mavlink.MAV_MISSION_UNSUPPORTED_FRAME
    for n, value in enumerate((item.param1, item.param2, item.param3, item.param4), start=1):
        if math.isnan(value) and not (n == 4 and is_nav(item.command)):
            return getattr(mavlink, f"MAV_MISSION_INVALID_PARAM{n}")
    if math.isnan(item.z):
        return mavlink.MAV_MISSION_INVALID_PARAM7
    if item.command in _WITH_LOCATION or item.mission_type in (FENCE, RALLY):
        if not -900_000_000 <= item.x <= 900_000_000:
            return mavlink.MAV_MISSION_INVALID_PARAM5_X
        if not -1_800_000_000 <= item.y <= 1_800_000_000:
            return mavlink.MAV_MISSION_INVALID_PARAM6_Y
    return mavlink.MAV_MISSION_ACCEPTED


@dataclass
class _Upload:
    """One running upload (ArduPilot's ``receiving`` state)."""

    sysid: int
    compid: int
    next_seq: int  # request_i
    last_seq: int  # request_last
    last_request_t: float
    last_receive_t: float
    staged: list[MissionItem] | None = None  # fence: committed on completion


class MissionServer:
    """Mission and fence lists of the simulated autopilot, and the upload/download state machine.

    ``mission[0]`` is always the home item; ``home_item()`` supplies the live one for downloads.
    ``running()`` tells whether the mission is executing (MISSION_CLEAR_ALL is refused then).
    ``on_set_current(seq)`` handles MISSION_SET_CURRENT. Items are stored as ``firmware`` stores them.
    ``capacity(mission_type)``: how many items an upload may have now (None: that list is not loaded yet, its
    MISSION_COUNT is answered once it is);
    ``home_set()``: False until the vehicle has a home (an untouched mission reads back empty until then).
    """

    def __init__(self, send: Callable[[mavlink.MAVLink_message], None], home_item: Callable[[], MissionItem],
                 running: Callable[[], bool], on_set_current: Callable[[int], bool],
                 text: Callable[[int, str], None], firmware: Firmware = Firmware.GENERIC,
                 capacity: Callable[[int], int | None] | None = None,
                 home_set: Callable[[], bool] = lambda: True) -> None:
        self._send = send
        self._home_item = home_item
        self._running = running
        self._on_set_current = on_set_current
        self._text = text
        self.firmware = firmware
        self._capacity = capacity if capacity is not None else MAX_ITEMS.get
        self._home_set = home_set
        self._written = False  # a mission was uploaded since power-up
        self.lists: dict[int, list[MissionItem]] = {MISSION: [home_item()], FENCE: [], RALLY: []}
        self._uploads: dict[int, _Upload] = {}
        self._deferred: dict[int, mavlink.MAVLink_message] = {}  # MISSION_COUNTs received while booting
        self.completed_uploads = 0
        self.abandoned: list[list[MissionItem]] = []  # the mission as left by each abandoned upload
        self.refuse: Callable[[MissionItem], int] | None = None  # fault injection: a result for an item, or ACCEPTED

    @property
    def mission(self) -> list[MissionItem]:
        return self.lists[MISSION]

    def receiving(self, mission_type: int = MISSION) -> bool:
        return mission_type in self._uploads

    # --- dispatch -------------------------------------------------------------------------------------------

    def handle(self, msg: mavlink.MAVLink_message, now: float) -> bool:
        """Handle a mission-protocol message addressed to us; False if it is not one."""
        handler = {
            "MISSION_COUNT": self._count,
            "MISSION_ITEM_INT": self._item,
            "MISSION_ITEM": self._item,
            "MISSION_REQUEST_LIST": self._request_list,
            "MISSION_REQUEST_INT": self._request,
            "MISSION_REQUEST": self._request,
            "MISSION_CLEAR_ALL": self._clear_all,
            "MISSION_WRITE_PARTIAL_LIST": self._write_partial,
            "MISSION_SET_CURRENT": self._set_current,
            "MISSION_ACK": self._download_done,
        }.get(msg.get_type())
        if handler is None:
            return False
        handler(msg, now)
        return True

    def tick(self, now: float) -> None:
        """Start deferred uploads whose list is ready, re-request overdue items and abandon stalled uploads
        (sim-time clock)."""
        for mission_type, msg in list(self._deferred.items()):
            if self._capacity(mission_type) is not None:
                del self._deferred[mission_type]
                self._count(msg, now)
        for mission_type, up in list(self._uploads.items()):
            if now - up.last_receive_t > UPLOAD_TIMEOUT_S:
                del self._uploads[mission_type]
                if mission_type == MISSION:
                    self.abandoned.append(list(self.mission))
                self._ack_to(up.sysid, up.compid, mavlink.MAV_MISSION_OPERATION_CANCELLED, mission_type)
                self._text(mavlink.MAV_SEVERITY_WARNING, f"{LIST_NAME[mission_type]} upload timeout")
                logger.info("simulator: upload of type %d abandoned at item %d", mission_type, up.next_seq)
            elif now - up.last_request_t > REQUEST_RESEND_S:
                self._request_next(mission_type, up, now)

    # --- helpers --------------------------------------------------------------------------------------------

    def _ack_to(self, sysid: int, compid: int, result: int, mission_type: int) -> None:
        self._send(mavlink.MAVLink_mission_ack_message(sysid, compid, result, mission_type))

    def _ack(self, msg: mavlink.MAVLink_message, result: int, mission_type: int) -> None:
        self._ack_to(msg.get_srcSystem(), msg.get_srcComponent(), result, mission_type)

    def _request_next(self, mission_type: int, up: _Upload, now: float) -> None:
        up.last_request_t = now
        self._send(mavlink.MAVLink_mission_request_message(up.sysid, up.compid, up.next_seq, mission_type))

    def _supported(self, msg: mavlink.MAVLink_message, mission_type: int) -> bool:
        if mission_type in self.lists:
            return True
        self._ack(msg, mavlink.MAV_MISSION_UNSUPPORTED, mission_type)
        return False

    def _start_upload(self, msg: mavlink.MAVLink_message, mission_type: int, first: int, last: int,
                      now: float, staged: list[MissionItem] | None = None) -> None:
        up = _Upload(msg.get_srcSystem(), msg.get_srcComponent(), first, last, now, now, staged)
        self._uploads[mission_type] = up
        self._request_next(mission_type, up, now)

    def _complete(self, msg: mavlink.MAVLink_message, mission_type: int) -> None:
        up = self._uploads.pop(mission_type, None)
        if mission_type == FENCE and up is not None and up.staged is not None:
            capacity = self._capacity(FENCE) or 0
            problem = fence_problem(up.staged, capacity * FENCE_BYTES_PER_ITEM)
            if problem is not None:
                text, validation = problem
                info = text == "Incorrect item count"
                self._text(mavlink.MAV_SEVERITY_INFO if info else mavlink.MAV_SEVERITY_WARNING, text)
                if validation:
                    self._text(mavlink.MAV_SEVERITY_WARNING, "Fence validation failed")
                self._ack(msg, mavlink.MAV_MISSION_ERROR, mission_type)
                logger.info("simulator: fence refused: %s", text)
                return
        if up is not None and up.staged is not None:
            self.lists[mission_type] = up.staged
        self.completed_uploads += 1
        self._ack(msg, mavlink.MAV_MISSION_ACCEPTED, mission_type)
        logger.info("simulator: %d items of type %d stored", len(self.lists[mission_type]), mission_type)

    # --- handlers -------------------------------------------------------------------------------------------

    def _count(self, msg: mavlink.MAVLink_message, now: float) -> None:
        mission_type = msg.mission_type
        if not self._supported(msg, mission_type):
            return
        up = self._uploads.get(mission_type)
        if up is not None:
            if (msg.get_srcSystem(), msg.get_srcComponent()) != (up.sysid, up.compid):
                self._ack(msg, mavlink.MAV_MISSION_DENIED, mission_type)
                return
            del self._uploads[mission_type]  # the same uploader restarts
        capacity = self._capacity(mission_type)
        if capacity is None:  # still booting, that list not loaded yet: answered once the boot is over
            self._deferred[mission_type] = msg
            return
        if msg.count > capacity:
            self._ack(msg, mavlink.MAV_MISSION_NO_SPACE, mission_type)
            self._text(mavlink.MAV_SEVERITY_WARNING, f"Only {capacity} items are supported")
            return
        staged = None
        if mission_type == MISSION:
            self._written = True
            del self.mission[max(msg.count, 1):]  # truncate now; items are written as they arrive
        elif mission_type == RALLY:
            del self.lists[RALLY][msg.count:]  # AP_Rally: truncated, then each point written as it arrives
        else:
            staged = self.lists[mission_type][:msg.count]
        if msg.count == 0:
            if staged is not None:
                self.lists[mission_type] = []
            self._complete(msg, mission_type)
            return
        self._start_upload(msg, mission_type, 0, msg.count - 1, now, staged)

    def _write_partial(self, msg: mavlink.MAVLink_message, now: float) -> None:
        mission_type = msg.mission_type
        if not self._supported(msg, mission_type):
            return
        if mission_type in self._uploads:  # whoever is uploading, the same sender included
            self._ack(msg, mavlink.MAV_MISSION_DENIED, mission_type)
            return
        count = len(self.lists[mission_type])
        if not 0 <= msg.start_index <= msg.end_index <= count:
            self._text(mavlink.MAV_SEVERITY_WARNING, "Flight plan update rejected")
            self._ack(msg, mavlink.MAV_MISSION_ERROR, mission_type)
            return
        staged = list(self.lists[mission_type]) if mission_type == FENCE else None
        self._start_upload(msg, mission_type, msg.start_index, msg.end_index, now, staged)

    def _item(self, msg: mavlink.MAVLink_message, now: float) -> None:
        mission_type = msg.mission_type
        if not self._supported(msg, mission_type):
            return
        if msg.get_type() == "MISSION_ITEM":
            self._text(mavlink.MAV_SEVERITY_WARNING, "got MISSION_ITEM; GCS should send MISSION_ITEM_INT")
        up = self._uploads.get(mission_type)
        if up is None:
            self._ack(msg, mavlink.MAV_MISSION_ERROR, mission_type)
            return
        if msg.seq != up.next_seq:
            self._ack(msg, mavlink.MAV_MISSION_INVALID_SEQUENCE, mission_type)
            return
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (up.sysid, up.compid):
            self._ack(msg, mavlink.MAV_MISSION_DENIED, mission_type)
            return
        item = MissionItem.from_message(msg)
        if mission_type == MISSION and item.seq == 0:
            result = mavlink.MAV_MISSION_ACCEPTED  # home: acknowledged (by the next request) and ignored
        else:
            result = validate_item(item)
            if result == mavlink.MAV_MISSION_ACCEPTED and self.refuse is not None:
                result = self.refuse(item)
            if result == mavlink.MAV_MISSION_ACCEPTED:
                result = self._store(mission_type, up, replace(stored(item, self.firmware), current=0))
        if result != mavlink.MAV_MISSION_ACCEPTED:
            del self._uploads[mission_type]
            self._ack(msg, result, mission_type)
            logger.info("simulator: upload refused at item %d: %d", item.seq, result)
            return
        up.last_receive_t = now
        up.next_seq += 1
        if up.next_seq > up.last_seq:
            self._complete(msg, mission_type)
        else:
            self._request_next(mission_type, up, now)

    def _store(self, mission_type: int, up: _Upload, item: MissionItem) -> int:
        target = up.staged if up.staged is not None else self.lists[mission_type]
        if item.seq < len(target):
            target[item.seq] = item
        elif item.seq == len(target):
            target.append(item)
        else:
            return mavlink.MAV_MISSION_ERROR
        return mavlink.MAV_MISSION_ACCEPTED

    def _download_allowed(self, msg: mavlink.MAVLink_message) -> bool:
        """A download of a supported list that is not being uploaded right now (else DENIED)."""
        if not self._supported(msg, msg.mission_type):
            return False
        if msg.mission_type in self._uploads:
            self._ack(msg, mavlink.MAV_MISSION_DENIED, msg.mission_type)
            return False
        return True

    def _request_list(self, msg: mavlink.MAVLink_message, now: float) -> None:
        mission_type = msg.mission_type
        if not self._download_allowed(msg):
            return
        self._send(mavlink.MAVLink_mission_count_message(
            msg.get_srcSystem(), msg.get_srcComponent(), self._count_of(mission_type), mission_type))

    def _count_of(self, mission_type: int) -> int:
        """What a download says: a fresh vehicle's mission is empty (no home item either) until home is set."""
        if mission_type == MISSION and not self._written and not self._home_set():
            return 0
        return len(self.lists[mission_type])

    def _request(self, msg: mavlink.MAVLink_message, now: float) -> None:
        mission_type = msg.mission_type
        if not self._download_allowed(msg):
            return
        items = self.lists[mission_type]
        if not 0 <= msg.seq < len(items):
            if msg.get_type() == "MISSION_REQUEST_INT":  # ArduPilot tells the client the real count first
                self._send(mavlink.MAVLink_mission_count_message(
                    msg.get_srcSystem(), msg.get_srcComponent(), self._count_of(mission_type), mission_type))
            self._ack(msg, mavlink.MAV_MISSION_INVALID_SEQUENCE, mission_type)
            return
        item = self._home_item() if (mission_type == MISSION and msg.seq == 0) else items[msg.seq]
        item = replace(item, frame=normalise_frame(item.frame))
        sysid, compid = msg.get_srcSystem(), msg.get_srcComponent()
        if msg.get_type() == "MISSION_REQUEST_INT":
            out = item.to_message(sysid, compid)
        else:
            out = mavlink.MAVLink_mission_item_message(
                sysid, compid, item.seq, item.frame, item.command, item.current, item.autocontinue, item.param1,
                item.param2, item.param3, item.param4, item.x / 1e7, item.y / 1e7, item.z, mission_type)
        self._send(out)

    def _download_done(self, msg: mavlink.MAVLink_message, now: float) -> None:
        """The MISSION_ACK a client sends after a download: nothing to do (ArduPilot keeps no download state)."""

    def _clear_all(self, msg: mavlink.MAVLink_message, now: float) -> None:
        mission_type = msg.mission_type
        if not self._supported(msg, mission_type):
            return
        if mission_type in self._uploads or (mission_type == MISSION and self._running()):
            self._ack(msg, mavlink.MAV_MISSION_ERROR, mission_type)
            return
        self.lists[mission_type] = [self._home_item()] if mission_type == MISSION else []
        self._ack(msg, mavlink.MAV_MISSION_ACCEPTED, mission_type)

    def _set_current(self, msg: mavlink.MAVLink_message, now: float) -> None:
        self._on_set_current(msg.seq)  # answered with MISSION_CURRENT by the autopilot
