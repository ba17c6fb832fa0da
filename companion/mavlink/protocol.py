"""MAVLink mission protocol client (upload, download, clear, set current) and COMMAND_LONG, over a :class:`Link`.

Follows https://mavlink.io/en/services/mission.html and what real autopilots do (docs/autopilots.md §3, §8.1):

* Upload: MISSION_COUNT → the autopilot requests items (MISSION_REQUEST_INT, or the legacy MISSION_REQUEST
  that ArduPilot uses) → we answer every request at once with MISSION_ITEM_INT for the requested seq (repeats,
  earlier seqs and out-of-order requests included) → MISSION_ACK. The autopilot drives the item phase and
  re-requests on its own clock (ArduPilot: after 1 s of *its* time), so our timeouts only decide when to nudge
  and when to give up: no first request within ``timeout`` → MISSION_COUNT again; no next request within
  ``item_timeout`` → the last requested item again; no ACK after the last item within ``timeout`` → the last
  item again. ``retries`` consecutive timeouts without progress → :class:`MissionTimeout`.
* Any MISSION_ACK error ends the operation with :class:`MissionUploadError` (result, seq in progress), with one
  exception: MAV_MISSION_INVALID_SEQUENCE during the item phase. ArduPilot sends it for a duplicate or
  out-of-order item *and keeps the transfer going* (it re-requests the item it wants), so it is logged and the
  transfer continues; it still counts against ``retries``.
* Download: MISSION_REQUEST_LIST → MISSION_COUNT → MISSION_REQUEST_INT per item (MISSION_ITEM_INT or legacy
  MISSION_ITEM accepted) → our MISSION_ACK.
* Changed tail (:meth:`MissionClient.upload_changed_verified`, where the profile has ``partial_write``):
  MISSION_WRITE_PARTIAL_LIST(first, last) in place of MISSION_COUNT, then the item phase as above for
  first…last only; verified by MISSION_REQUEST_LIST → MISSION_COUNT and MISSION_REQUEST_INT for first…last
  (ArduPilot keeps no download state, so single items may be asked for at any time outside a transfer).
* Only the target autopilot's messages addressed to us (or broadcast) and of the operation's mission type count.

One operation at a time per client (an internal lock serialises callers).
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Sequence
from dataclasses import replace

from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import (
    CommandError,
    CompanionError,
    MissionTimeout,
    MissionUploadError,
    MissionVerifyError,
)
from companion.mavlink.items import FENCE, MISSION, MissionItem
from companion.mavlink.link import Link, Message, Predicate, Subscription
from companion.mavlink.profiles import Firmware
from companion.mavlink.storage import changed_range, mission_difference

log = logging.getLogger(__name__)

ACCEPTED = mavlink.MAV_MISSION_ACCEPTED
_CMD_OK = (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS)


def command_result_name(result: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else f"MAV_RESULT {result}"


def command_name(command: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name if entry is not None else f"MAV_CMD {command}"


DOWNLOAD_RESTARTS = 3  # a stalled download is started again this many times (the last try is patient)
MAX_READ_ITEMS = 10_000  # beyond any mission ArduPilot's or PX4's storage holds on a flight controller
FINAL_ACK_MISSES = 3  # waits (of ``timeout``) for the final MISSION_ACK before checking by readback
# item requests in flight at once in a readback from an autopilot that answers single requests outside a transfer
# (profile ``partial_write``): small enough for its send buffer on a radio link, large enough that a readback
# costs about one of its loops instead of one per item (ArduPlane SITL at 10x: ~4 ms per item one by one)
READ_WINDOW = 8


def _numbered(items: Sequence[MissionItem], mission_type: int) -> list[MissionItem]:
    """``items`` as the whole list of ``mission_type``: renumbered 0… in order and stamped with the type."""
    return [replace(it, seq=i, mission_type=mission_type) for i, it in enumerate(items)]


def _matching(expected: list[MissionItem], got: list[MissionItem], home_at_zero: bool,
              firmware: Firmware) -> list[MissionItem]:
    """``got`` if it matches ``expected`` (:func:`mission_difference`), else :class:`MissionVerifyError`."""
    diff = mission_difference(expected, got, home_at_zero, firmware)
    if diff is not None:
        raise MissionVerifyError(*diff)
    return got


class MissionClient:
    """Mission protocol client for MISSION and FENCE (and RALLY) lists. Times in seconds.

    ``timeout`` (1.5 s): wait for the answer to MISSION_COUNT / MISSION_REQUEST_LIST / MISSION_CLEAR_ALL and for
    the final MISSION_ACK; ``item_timeout`` (0.25 s): wait for the next item request (upload) or item
    (download); ``retries`` (5): consecutive timeouts tolerated per step before :class:`MissionTimeout`.
    """

    def __init__(self, link: Link, *, timeout: float = 1.5, item_timeout: float = 0.25, retries: int = 5,
                 item_giveup_s: float = 10.0) -> None:
        self.link = link
        self.timeout = timeout
        self.item_timeout = item_timeout
        self.retries = retries
        self.item_giveup_s = item_giveup_s  # longer than ArduPilot's own 8 s abandon time
        self.set_current_by_message = False  # the autopilot answered DO_SET_MISSION_CURRENT UNSUPPORTED (PX4)
        self._lock = asyncio.Lock()

    # ------------------------------------------------------------------ helpers
    def _give_up(self, since: float) -> bool:
        """After the protocol's retries: stop when the autopilot has gone quiet (no HEARTBEAT), but keep
        going for up to ``item_giveup_s`` while it is alive and only our packets are being lost."""
        alive = self.link.heartbeat_age <= self.link.heartbeat_timeout
        return not alive or asyncio.get_running_loop().time() - since > self.item_giveup_s

    def _to_us(self, msg: Message) -> bool:
        """Addressed to us (or broadcast); messages without target fields pass."""
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.link.source_system) and tc in (0, self.link.source_component)

    def _for(self, mission_type: int) -> Predicate:
        def predicate(msg: Message) -> bool:
            return getattr(msg, "mission_type", MISSION) == mission_type and self._to_us(msg)
        return predicate

    def _target(self) -> tuple[int, int]:
        if self.link.target_system is None or self.link.target_component is None:
            raise MissionTimeout("target discovery")  # no autopilot HEARTBEAT yet
        return self.link.target_system, self.link.target_component

    # ------------------------------------------------------------------ upload
    async def upload(self, items: Sequence[MissionItem], mission_type: int = MISSION) -> None:
        """Upload ``items`` as the whole ``mission_type`` list. Items are renumbered 0… in order and stamped with
        ``mission_type``. Raises :class:`MissionUploadError` on a MISSION_ACK error, :class:`MissionTimeout`
        when the autopilot stops answering, :class:`LinkError` if the link drops."""
        async with self._lock:
            await self._upload(_numbered(items, mission_type), mission_type)

    async def _upload(self, items: list[MissionItem], mission_type: int) -> list[MissionItem] | None:
        """The upload; returns the readback when one was needed to confirm it (else None). A fence of fewer
        items than the autopilot's ``min_fence_items`` (ArduPilot: 3, see :mod:`companion.mavlink.profiles`) goes to a
        cleared fence: ArduPilot's fence loader would erase the stored fence just after acknowledging it.
        Cleared first, with two HEARTBEATs for the loader to see the drop, the fence that follows stays."""
        if mission_type == FENCE and 0 < len(items) < self.link.profile.min_fence_items:
            await self._clear(FENCE)
            for _ in range(2):
                try:
                    await self.link.wait_for("HEARTBEAT", timeout=3.0)
                except TimeoutError:
                    break
        ambiguous = await self._transfer(items, mission_type)
        if ambiguous is None:
            return None
        # The final MISSION_ACK went missing, and our resent last item met an autopilot that had already
        # finished (ArduPilot answers an item outside an upload with MAV_MISSION_ERROR) or nothing answered:
        # only a readback can tell whether the upload completed.
        result, seq, first_copy = ambiguous
        log.info("final MISSION_ACK of the upload not seen; checking by readback")
        try:
            got = await self._download(mission_type)
        except (MissionTimeout, MissionUploadError):
            got = None
        home = self.home_at_zero(mission_type)
        if got is None or mission_difference(items, got, home, self.firmware) is not None:
            if result is None:
                raise MissionTimeout("upload", seq)
            # an answer after the last item is never a refusal of an item (ArduPilot's to a duplicate, PX4's
            # for its own transfer trouble: seen at 20x while PX4 still floods the link): the upload is retried.
            # Except ArduPilot's to the only copy of a fence's last item with another fence read back: it checks a
            # fence as a whole once complete and refuses one it cannot store, keeping the old (docs/autopilots.md
            # §5.6); sending it again would be refused again
            refused = (first_copy and got is not None and mission_type == FENCE and self.firmware.ardupilot
                       and result == mavlink.MAV_MISSION_ERROR)
            raise MissionUploadError(result, seq, transfer_fault=not refused)
        log.info("uploaded %d items (mission type %d; confirmed by readback)", len(items), mission_type)
        return got

    async def _transfer(self, items: list[MissionItem], mission_type: int,
                        first: int | None = None, last: int | None = None) -> tuple[int | None, int, bool] | None:
        """The upload exchange: None once the autopilot ACKs it; ``(result or None, seq, first_copy)`` when the
        outcome is ambiguous because the final ACK went missing (``first_copy``: the result answered the last item
        as first sent, not a copy we resent unasked). ``first`` (and ``last``, default the end): write only
        ``items[first:last + 1]`` over the stored list (MISSION_WRITE_PARTIAL_LIST, the same length) instead of
        the whole list (MISSION_COUNT)."""
        link = self.link
        ts, tc = self._target()
        count = len(items)
        lowest = 0 if first is None else first  # the first seq the autopilot may ask for
        top = count - 1 if first is None or last is None else last  # and the last
        if first is None:
            count_msg = mavlink.MAVLink_mission_count_message(ts, tc, count, mission_type)
        else:
            count_msg = mavlink.MAVLink_mission_write_partial_list_message(ts, tc, first, top, mission_type)
        with link.subscribe("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK",
                            predicate=self._for(mission_type)) as sub:
            link.send(count_msg)
            requested: int | None = None  # seq of the latest request (the item being processed)
            last_sent: int | None = None
            final_resent = False  # the last item went out again unasked, while waiting for the final ACK
            stalled = False  # the item last sent went out again unasked (no request since)
            misses = 0
            answered = 0  # bounded even against a peer that re-requests forever
            max_answers = (top - lowest + 2) * (self.retries + 1) * 2
            loop = asyncio.get_running_loop()
            progress = loop.time()  # when the autopilot last asked for an item
            while True:
                waiting_ack = count > 0 and last_sent == top and requested == top
                wait = self.timeout if requested is None or waiting_ack else self.item_timeout
                try:
                    msg = await sub.get(wait)
                except TimeoutError:
                    misses += 1
                    # before the first request: MISSION_COUNT retries; after it: the autopilot re-requests
                    # on its own clock (ArduPilot: every 1 s, abandoning after 8 s), so give up only when it
                    # has been silent longer than that, whatever our resend count
                    silent = loop.time() - progress
                    if final_resent and misses >= FINAL_ACK_MISSES:
                        # the last item went out again and again with no answer at all (MAVSDK and PX4 do not
                        # answer an item after the transfer ended, ArduPilot would NACK it): the final ACK was
                        # probably lost, and a readback tells at once
                        return None, top, False
                    if (last_sent is None and misses > self.retries and self._give_up(progress)) or (
                            last_sent is not None and silent > self.item_giveup_s):
                        if final_resent:
                            return None, top, False
                        raise MissionTimeout("upload", requested) from None
                    if last_sent is None:
                        log.debug("no request for %s; resending (%d)", count_msg.get_type(), misses)
                        link.send(count_msg)
                    else:
                        log.debug("no request after item %d for %.2f s; resending it", last_sent, silent)
                        stalled = True
                        link.send(items[last_sent].to_message(ts, tc))
                        final_resent = waiting_ack
                    continue
                if msg.get_type() == "MISSION_ACK":
                    if msg.type == ACCEPTED:
                        if count == 0 or last_sent == top:
                            log.info("uploaded items %d-%d of %d (mission type %d)", lowest, top, count,
                                     mission_type)
                            return None
                        log.debug("ignoring early MISSION_ACK ACCEPTED (stale?) at item %s", requested)
                        continue
                    if final_resent or (waiting_ack and msg.type == mavlink.MAV_MISSION_ERROR):
                        # after the last item, ArduPilot's MISSION_ERROR is its answer to a copy of that item
                        # (ours, or one the network duplicated) arriving once the upload had ended: the final
                        # ACK may have been lost; a readback tells
                        return msg.type, top, not final_resent
                    if msg.type == mavlink.MAV_MISSION_ERROR and stalled:
                        # we had been resending an item nobody asked for again: the autopilot abandoned the
                        # transfer on its own clock (its OPERATION_CANCELLED lost) and now answers our resend
                        # as an item outside any upload. A link fault, not a refusal of that item.
                        raise MissionTimeout("upload", requested)
                    if msg.type == mavlink.MAV_MISSION_INVALID_SEQUENCE and last_sent is not None:
                        # ArduPilot's answer to a duplicate (our own resend): the transfer goes on
                        log.debug("MISSION_ACK INVALID_SEQUENCE after item %d; continuing", last_sent)
                        continue
                    fault = msg.type == mavlink.MAV_MISSION_ERROR and self.link.profile.error_may_be_transfer_fault
                    raise MissionUploadError(msg.type, requested, transfer_fault=fault)
                seq = msg.seq
                if not lowest <= seq <= top:
                    log.warning("autopilot requested item %d of %d-%d; ignored", seq, lowest, top)
                    continue
                answered += 1
                if answered > max_answers:
                    raise MissionTimeout("upload", seq)
                misses = 0  # the autopilot is talking to us
                progress = loop.time()
                final_resent = stalled = False
                requested = seq
                link.send(items[seq].to_message(ts, tc))
                last_sent = seq

    async def upload_verified(self, items: Sequence[MissionItem], mission_type: int = MISSION,
                              home_at_zero: bool | None = None) -> list[MissionItem]:
        """Upload, download and compare item by item as the target stores them (:mod:`companion.mavlink.storage`).
        ``home_at_zero`` (default: the target is ArduPilot and this is the MISSION list) skips seq 0, which
        ArduPilot replaces with home. Returns the readback; raises :class:`MissionVerifyError` on the first
        difference."""
        if home_at_zero is None:
            home_at_zero = self.home_at_zero(mission_type)
        sent = _numbered(items, mission_type)
        async with self._lock:
            got = await self._upload(sent, mission_type)
            if got is None:  # (else the upload was already confirmed by a readback)
                got = await self._download(mission_type, expected=len(sent))
        return _matching(sent, got, home_at_zero, self.firmware)

    async def upload_changed_verified(self, items: Sequence[MissionItem], previous: Sequence[MissionItem],
                                      mission_type: int = MISSION) -> str:
        """Replace the stored list ``previous`` (the one last verified on the vehicle) by ``items``, writing only
        what changed where the autopilot allows it; returns the path taken, for the log:

        * ``"partial FIRST-LAST"``: the profile has ``partial_write`` (ArduPilot) and both lists have the same
          length: items FIRST…LAST (the first and the last that differ as the autopilot stores them) went with
          MISSION_WRITE_PARTIAL_LIST and were verified by reading back the count and those items only;
        * ``"unchanged"``: as above, but no item differs: nothing is sent, nothing read back;
        * ``"whole"``: otherwise (PX4 and other autopilots, a change of length, or an autopilot that refused the
          partial list with MAV_MISSION_ERROR before writing anything: the stored list is not ``previous``'s
          length), :meth:`upload_verified`.

        The items outside FIRST…LAST are not read back: ``previous`` is taken to be what the vehicle holds.
        Raises what :meth:`upload_verified` raises: :class:`MissionUploadError`, :class:`MissionTimeout`,
        :class:`MissionVerifyError`. Like a whole upload, a partial one that fails part-way leaves new items
        before the failure and old ones after it (docs/autopilots.md §3.7)."""
        sent = _numbered(items, mission_type)
        if not self.writes_in_part or len(sent) != len(previous):
            await self.upload_verified(sent, mission_type)
            return "whole"
        changed = changed_range(sent, _numbered(previous, mission_type), self.home_at_zero(mission_type),
                                self.firmware)
        if changed is None:
            return "unchanged"
        first, last = changed
        try:
            async with self._lock:
                await self._upload_range(sent, first, last, mission_type)
        except MissionUploadError as exc:
            if exc.seq is not None or exc.operation != "upload" or exc.result != mavlink.MAV_MISSION_ERROR:
                raise
            # refused before any item was requested (ArduPilot: the range is past its count), so nothing written
            log.info("partial write of items %d-%d refused (%s); uploading the whole list", first, last, exc)
            await self.upload_verified(sent, mission_type)
            return "whole"
        return f"partial {first}-{last}"

    async def _upload_range(self, items: list[MissionItem], first: int, last: int,
                            mission_type: int) -> list[MissionItem]:
        """Write ``items[first:last + 1]`` in place and read them back (:meth:`_verify_range`); the readback. A
        final ACK that went missing is settled by that readback, as :meth:`_upload` does with a whole one."""
        ambiguous = await self._transfer(items, mission_type, first, last)
        if ambiguous is None:
            return await self._verify_range(items, first, last, mission_type)
        log.info("final MISSION_ACK of the partial write not seen; checking by readback")
        try:
            return await self._verify_range(items, first, last, mission_type)
        except (MissionTimeout, MissionUploadError, MissionVerifyError):
            result, seq, _ = ambiguous
            if result is None:
                raise MissionTimeout("upload", seq) from None
            raise MissionUploadError(result, seq, transfer_fault=True) from None

    async def _verify_range(self, items: list[MissionItem], first: int, last: int,
                            mission_type: int) -> list[MissionItem]:
        """The stored count (MISSION_REQUEST_LIST → MISSION_COUNT) and items ``first``…``last``
        (MISSION_REQUEST_INT, asked for together, :meth:`_read_items`), compared with ``items`` as
        :meth:`upload_verified` compares; the items read back, else :class:`MissionVerifyError`."""
        link = self.link
        ts, tc = self._target()
        got = await self._read_items(range(first, last + 1), mission_type, patient=True, count=len(items))
        link.send(mavlink.MAVLink_mission_ack_message(ts, tc, ACCEPTED, mission_type))
        log.info("read back items %d-%d of %d (mission type %d)", first, last, len(items), mission_type)
        return _matching(items[first:last + 1], got, self.home_at_zero(mission_type), self.firmware)

    async def _read_items(self, seqs: range, mission_type: int, patient: bool,
                          count: int | None = None) -> list[MissionItem]:
        """Items ``seqs`` of the stored list, in order; with ``count``, the stored count first (MISSION_REQUEST_LIST),
        which must equal it (else :class:`MissionVerifyError`). Where the autopilot answers single
        MISSION_REQUEST_INTs outside a transfer (profile ``partial_write``: ArduPilot keeps no download state) up to
        :data:`READ_WINDOW` requests, the count's included, are in flight at once; elsewhere one at a time, as the
        protocol's download does. Unanswered requests are sent again after ``item_timeout``; retries and
        MISSION_ACK errors as :meth:`_request`."""
        link = self.link
        ts, tc = self._target()
        pred = self._for(mission_type)
        window = READ_WINDOW if self.link.profile.partial_write else 1
        wanted = list(seqs)
        got: dict[int, MissionItem] = {}
        asked: list[int] = []  # requests in flight (-1: the count)
        misses = stray_errors = 0
        loop = asyncio.get_running_loop()
        start = loop.time()

        def ask(seq: int) -> None:
            if seq < 0:
                link.send(mavlink.MAVLink_mission_request_list_message(ts, tc, mission_type))
            else:
                link.send(mavlink.MAVLink_mission_request_int_message(ts, tc, seq, mission_type))

        with link.subscribe("MISSION_ITEM_INT", "MISSION_ITEM", "MISSION_COUNT", "MISSION_ACK", predicate=pred) as sub:
            todo = ([-1] if count is not None else []) + wanted
            while todo or asked:
                while todo and len(asked) < window:
                    asked.append(todo.pop(0))
                    ask(asked[-1])
                try:
                    msg = await sub.get(self.timeout if asked == [-1] else self.item_timeout)
                except TimeoutError:
                    misses += 1
                    if misses > self.retries and (not patient or self._give_up(start)):
                        raise MissionTimeout("download", min(asked)) from None
                    for seq in asked:
                        ask(seq)
                    continue
                mtype = msg.get_type()
                if mtype == "MISSION_ACK":
                    if msg.type == mavlink.MAV_MISSION_ERROR and stray_errors < self.retries:
                        stray_errors += 1  # a stray item's answer, or ours refused: asked again
                        log.debug("MISSION_ACK ERROR during a readback (stray item?); asking again")
                        for seq in asked:
                            ask(seq)
                        continue
                    if msg.type != ACCEPTED:
                        raise MissionUploadError(msg.type, min(asked), "download")
                    continue  # a stale ACK of something else
                seq = -1 if mtype == "MISSION_COUNT" else msg.seq
                if seq not in asked:
                    continue  # a late answer to a request already answered
                asked.remove(seq)
                misses = 0
                if seq < 0:
                    if msg.count != count:
                        raise MissionVerifyError(min(msg.count, count), "count", count, msg.count)
                else:
                    got[seq] = replace(MissionItem.from_message(msg), mission_type=mission_type)
        return [got[seq] for seq in wanted]

    async def verify(self, items: Sequence[MissionItem], mission_type: int = MISSION) -> list[MissionItem]:
        """Download ``mission_type`` and compare it with ``items`` as :meth:`upload_verified` does; returns the
        readback, raises :class:`MissionVerifyError` on the first difference (e.g. after a link outage)."""
        sent = _numbered(items, mission_type)
        async with self._lock:
            got = await self._download(mission_type, expected=len(sent))
        return _matching(sent, got, self.home_at_zero(mission_type), self.firmware)

    @property
    def writes_in_part(self) -> bool:
        """A changed tail of a list goes as a partial write (:meth:`upload_changed_verified`): the profile's
        ``partial_write``."""
        return self.link.profile.partial_write

    @property
    def firmware(self) -> Firmware:
        """How the target stores items (:mod:`companion.mavlink.storage`): its profile's."""
        return self.link.profile.storage

    def home_at_zero(self, mission_type: int) -> bool:
        """The target keeps its home at item 0 of the mission list (ArduPilot: replaced on upload, read back as
        the real home)."""
        return mission_type == MISSION and self.link.profile.home_at_zero

    # ------------------------------------------------------------------ download
    async def download(self, mission_type: int = MISSION) -> list[MissionItem]:
        """The autopilot's ``mission_type`` list, as sent (frames not normalised)."""
        async with self._lock:
            return await self._download(mission_type)

    async def _download(self, mission_type: int, expected: int | None = None) -> list[MissionItem]:
        """The list, started again from MISSION_REQUEST_LIST when an item stops coming: MAVSDK (and PX4) drop
        a download whose next request they miss too often, and then answer no more item requests; ArduPilot
        keeps no download state, so starting again costs it only the items already read."""
        for _ in range(DOWNLOAD_RESTARTS):
            try:
                return await self._download_once(mission_type, patient=False, expected=expected)
            except MissionTimeout as e:
                if self.link.heartbeat_age > self.link.heartbeat_timeout:
                    raise  # the autopilot has gone quiet, not just one transfer
                log.info("download stalled at item %s; starting it again", e.seq)
        return await self._download_once(mission_type, patient=True, expected=expected)

    async def _download_once(self, mission_type: int, patient: bool,
                             expected: int | None = None) -> list[MissionItem]:
        """One download. A readback (``expected``: the count uploaded) whose count differs fails at once, without
        reading the items; a count beyond :data:`MAX_READ_ITEMS` is refused (a hostile or broken autopilot's
        65535 would otherwise be read item by item for hours)."""
        link = self.link
        ts, tc = self._target()
        pred = self._for(mission_type)
        with link.subscribe("MISSION_COUNT", "MISSION_ACK", predicate=pred) as sub:
            count_msg = await self._request(
                sub, mavlink.MAVLink_mission_request_list_message(ts, tc, mission_type), "MISSION_COUNT",
                self.timeout, "download", None)
        count = count_msg.count
        refusal: CompanionError | None = None
        if expected is not None and count != expected:
            refusal = MissionVerifyError(min(count, expected), "count", expected, count)
        elif count > MAX_READ_ITEMS:
            refusal = CompanionError(f"mission download refused: the autopilot reports {count} items, more than "
                                     f"the {MAX_READ_ITEMS} the companion reads")
        if refusal is not None:
            # end the download on the autopilot's side too: PX4 stays in its send-list state, answering the next
            # transfer "busy", until it times out
            link.send(mavlink.MAVLink_mission_ack_message(ts, tc, mavlink.MAV_MISSION_OPERATION_CANCELLED,
                                                          mission_type))
            raise refusal
        got = await self._read_items(range(count), mission_type, patient)
        link.send(mavlink.MAVLink_mission_ack_message(ts, tc, ACCEPTED, mission_type))
        log.info("downloaded %d items (mission type %d)", count, mission_type)
        return got

    async def _request(self, sub: Subscription, request: Message, want: str | tuple[str, ...], wait: float,
                       operation: str, seq: int | None, match: Predicate | None = None,
                       patient: bool = True) -> Message:
        """Send ``request`` until a ``want`` message (passing ``match``) arrives. MISSION_ACK errors raise,
        except MAV_MISSION_ERROR, which ArduPilot also sends for a stray item that arrives after an upload (a
        duplicate on a lossy link): it is taken as an answer to our request only when it keeps coming. After
        ``retries`` unanswered sends, ``patient`` keeps going while the autopilot is alive (up to
        ``item_giveup_s``); otherwise it gives up at once."""
        want = (want,) if isinstance(want, str) else want
        self.link.send(request)
        misses = 0
        stray_errors = 0
        start = asyncio.get_running_loop().time()
        while True:
            try:
                msg = await sub.get(wait)
            except TimeoutError:
                misses += 1
                if misses > self.retries and (not patient or self._give_up(start)):
                    raise MissionTimeout(operation, seq) from None
                self.link.send(request)
                continue
            mtype = msg.get_type()
            if mtype == "MISSION_ACK":
                if msg.type == mavlink.MAV_MISSION_ERROR and stray_errors < self.retries:
                    stray_errors += 1
                    log.debug("MISSION_ACK ERROR during %s (stray item?); asking again", operation)
                    self.link.send(request)
                    continue
                if msg.type != ACCEPTED:
                    raise MissionUploadError(msg.type, seq, operation)
                continue  # a stale ACK of something else
            if mtype in want and (match is None or match(msg)):
                return msg

    # ------------------------------------------------------------------ clear / current
    async def clear(self, mission_type: int = MISSION) -> None:
        """MISSION_CLEAR_ALL, confirmed by MISSION_ACK."""
        async with self._lock:
            await self._clear(mission_type)

    async def _clear(self, mission_type: int) -> None:
        ts, tc = self._target()
        with self.link.subscribe("MISSION_ACK", predicate=self._for(mission_type)) as sub:
            msg = mavlink.MAVLink_mission_clear_all_message(ts, tc, mission_type)
            self.link.send(msg)
            misses = 0
            while True:
                try:
                    ack = await sub.get(self.timeout)
                except TimeoutError:
                    misses += 1
                    if misses > self.retries:
                        raise MissionTimeout("clear") from None
                    self.link.send(msg)
                    continue
                if ack.type != ACCEPTED:
                    raise MissionUploadError(ack.type, None, "clear")
                return

    async def set_current(self, seq: int, *, timeout: float = 0.5, retries: int = 2) -> None:
        """Make ``seq`` the active mission item: MAV_CMD_DO_SET_MISSION_CURRENT (ArduPilot restarts the item
        even if it already was current). If nothing ACKs the command (MAVSDK's server) or the autopilot
        answers it MAV_RESULT_UNSUPPORTED (PX4, which takes the MISSION_SET_CURRENT message), falls back to
        MISSION_SET_CURRENT confirmed by MISSION_CURRENT.seq, and after an UNSUPPORTED uses only that from
        then on. Raises :class:`CommandError` when refused or when neither confirms."""
        cmd = mavlink.MAV_CMD_DO_SET_MISSION_CURRENT
        if not self.set_current_by_message:
            try:
                await self.command_long(cmd, seq, timeout=timeout, retries=retries, persist=False)
                return
            except CommandError as exc:
                if exc.result == mavlink.MAV_RESULT_UNSUPPORTED:
                    self.set_current_by_message = True
                    log.info("DO_SET_MISSION_CURRENT unsupported; MISSION_SET_CURRENT from now on")
                elif exc.result is not None:
                    raise  # an explicit refusal (e.g. seq out of range)
                else:
                    log.info("no COMMAND_ACK for DO_SET_MISSION_CURRENT; trying MISSION_SET_CURRENT")
        if not await self._set_current_by_message(seq, timeout, retries):
            raise CommandError(cmd, None, f"neither COMMAND_ACK nor MISSION_CURRENT confirmed item {seq}")

    async def _set_current_by_message(self, seq: int, timeout: float, retries: int) -> bool:
        """MISSION_SET_CURRENT, sent up to ``1 + retries`` times until MISSION_CURRENT shows ``seq`` (within
        ``timeout`` s of each); False if it never does."""
        ts, tc = self._target()
        msg = mavlink.MAVLink_mission_set_current_message(ts, tc, seq)
        with self.link.subscribe("MISSION_CURRENT", predicate=lambda m: m.seq == seq) as sub:
            for _ in range(retries + 1):
                self.link.send(msg)
                try:
                    await sub.get(timeout)
                    return True
                except TimeoutError:
                    continue
        return False

    # ------------------------------------------------------------------ commands
    async def command_long(self, command: int, *params: float, timeout: float = 1.0, retries: int = 3,
                           target_component: int | None = None, persist: bool = True) -> int:
        """Send COMMAND_LONG (params padded to 7 with 0) until a COMMAND_ACK for it arrives, counting up
        ``confirmation`` on each resend. Returns the MAV_RESULT when ACCEPTED or IN_PROGRESS; otherwise raises
        :class:`CommandError` with the result (or ``None`` when no ACK came: after ``retries`` resends if the
        autopilot is silent or ``persist`` is off, else once it has been alive without answering for
        ``item_giveup_s`` — a lossy link must not fail a mode change that a second try would make)."""
        if len(params) > 7:
            raise ValueError("COMMAND_LONG has 7 params")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        link = self.link
        ts, tc = self._target()
        tc = tc if target_component is None else target_component

        def is_ack(m: Message) -> bool:
            return m.command == command and self._to_us(m)

        with link.subscribe("COMMAND_ACK", predicate=is_ack,
                            any_source=target_component is not None) as sub:
            start = asyncio.get_running_loop().time()
            for confirmation in range(256):  # ``retries`` resends, more while the autopilot is alive (_give_up)
                if confirmation > retries and (not persist or self._give_up(start)):
                    break
                link.send(mavlink.MAVLink_command_long_message(ts, tc, command, confirmation, *p))
                try:
                    ack = await sub.get(timeout)
                except TimeoutError:
                    log.debug("no COMMAND_ACK for %s (try %d)", command_name(command), confirmation + 1)
                    continue
                if ack.result in _CMD_OK:
                    return ack.result
                raise CommandError(command, ack.result, command_result_name(ack.result))
        raise CommandError(command, None, command_name(command))

    async def command_int(self, command: int, frame: int, *params: float, x: int = 0, y: int = 0, z: float = 0.0,
                          timeout: float = 1.0, retries: int = 3) -> int:
        """Send COMMAND_INT (``params`` are param1–4; ``x``/``y`` degrees × 1e7, ``z`` in ``frame``'s altitude)
        until its COMMAND_ACK; results as :meth:`command_long`. ArduPlane takes MAV_CMD_DO_REPOSITION only so."""
        p = [float(v) for v in params] + [0.0] * (4 - len(params))
        ts, tc = self._target()

        def is_ack(m: Message) -> bool:
            return m.command == command and self._to_us(m)

        with self.link.subscribe("COMMAND_ACK", predicate=is_ack) as sub:
            for _ in range(retries + 1):
                self.link.send(mavlink.MAVLink_command_int_message(ts, tc, frame, command, 0, 0, *p, x, y, z))
                try:
                    ack = await sub.get(timeout)
                except TimeoutError:
                    continue
                if ack.result in _CMD_OK:
                    return ack.result
                raise CommandError(command, ack.result, command_result_name(ack.result))
        raise CommandError(command, None, command_name(command))


__all__ = ["MissionClient", "command_result_name", "command_name"]
