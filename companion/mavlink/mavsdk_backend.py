"""`fly --backend mavsdk`: the vehicle reached through MAVSDK-Python 4 (its bundled C++ library) instead of our own
pymavlink link; planning, replanning decisions, verification and the report stay ours.

* :class:`MavsdkLink` is a :class:`~companion.mavlink.link.Link` whose connection is MAVSDK's: the messages the
  supervisor and replanner read come from MAVSDK's ``mavlink_direct`` subscriptions (one per message name in
  :data:`MESSAGES`, turned into pymavlink message objects so every layer above reads them as on our own link);
  what we send goes out through MAVSDK; MAVSDK sends the HEARTBEAT.
* :class:`MavsdkMissionClient` does the transfers with MAVSDK's own implementations: ``mission_raw`` for mission,
  fence and rally upload and download, set-current and mission start, ``action`` for arming, and MAVSDK's command
  sender (``mavlink_direct.send_command``: retransmission, IN_PROGRESS handling) for every other command. Our
  readback comparison (:mod:`companion.mavlink.storage`) still decides whether an upload is verified.

What MAVSDK does not give us, the CLI refuses in one line (:func:`unsupported_options`). MAVSDK reports a failed
transfer as a ``MissionRawResult`` without the autopilot's MAV_MISSION_RESULT or the item; :func:`upload_error`
maps it to ours (docs/px4.md says where the two backends differ on a real autopilot).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from mavsdk import LogLevel, log_subscribe
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync
from mavsdk.plugins.action import ActionError
from mavsdk.plugins.mavlink_direct import MavlinkDirectError, MavlinkMessage
from mavsdk.plugins.mission_raw import MissionItem as RawItem
from mavsdk.plugins.mission_raw import MissionRawError
from pymavlink.dialects.v20 import ardupilotmega as dialect
from pymavlink.dialects.v20 import common as mavlink

from companion.mavlink.errors import CommandError, LinkError, MissionTimeout, MissionUploadError
from companion.mavlink.items import FENCE, MISSION, RALLY, MissionItem
from companion.mavlink.link import Link, Message
from companion.mavlink.protocol import MissionClient

log = logging.getLogger(__name__)
mavsdk_log = logging.getLogger("mavsdk")  # MAVSDK's own log lines, instead of its coloured console output
_LEVELS = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO, LogLevel.WARN: logging.WARNING,
           LogLevel.ERROR: logging.ERROR}

# Every message the companion's layers subscribe to (supervisor, replanner, telemetry rates, PX4's verdict).
MESSAGES = ("HEARTBEAT", "SYS_STATUS", "GPS_RAW_INT", "EKF_STATUS_REPORT", "MISSION_CURRENT", "MISSION_ITEM_REACHED",
            "GLOBAL_POSITION_INT", "STATUSTEXT", "COMMAND_ACK", "ADSB_VEHICLE")
SET_CURRENT_S = 5.0  # wall seconds MAVSDK may take to have a set-current confirmed
FIRST_AUTOPILOT_S = 10.0  # wall seconds MAVSDK may take to find the autopilot on the connection


def mavsdk_url(url: str) -> str:
    """A pymavlink connection string as MAVSDK writes it: ``udpin:H:P`` → ``udpin://H:P``, ``tcp:H:P`` →
    ``tcpout://H:P``, a serial device → ``serial:///dev/…``; a MAVSDK URL passes unchanged."""
    if "://" in url:
        return url
    scheme, _, rest = url.partition(":")
    if scheme in ("udpin", "udp"):
        return f"udpin://{rest}"
    if scheme == "udpout":
        return f"udpout://{rest}"
    if scheme in ("tcp", "tcpout"):
        return f"tcpout://{rest}"
    if url.startswith("/dev/") or url.upper().startswith("COM"):
        device, _, baud = url.partition(",")
        return f"serial://{device}" + (f":{baud}" if baud else "")
    raise LinkError(f"cannot use connection {url!r} with MAVSDK (udpin:, udpout:, tcp: or a serial device)")


_destroying = 0  # MAVSDK instances being destroyed: what they log meanwhile (closed sockets) is only debug
_log_loop: asyncio.AbstractEventLoop | None = None  # the loop of the last MavsdkLink opened


def _to_logging(level: LogLevel, message: str, file: str | None, line: int) -> bool:
    """MAVSDK's log line, called on one of its own threads: logged on the link's loop, since logging from a
    foreign thread would register a dummy Python thread for it that outlives MAVSDK."""
    loop = _log_loop
    if loop is not None and not loop.is_closed():
        level_no = logging.DEBUG if _destroying else _LEVELS.get(level, logging.INFO)
        with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
            loop.call_soon_threadsafe(mavsdk_log.log, level_no, "%s (%s:%s)", message, file, line)
    return True  # not printed by MAVSDK


def to_message(name: str, system: int, component: int, fields_json: str) -> Message:
    """A pymavlink message object from MAVSDK's JSON fields (NaN comes as null; missing extensions are 0)."""
    fields = json.loads(fields_json)
    cls = dialect.mavlink_map[fields.get("message_id", getattr(dialect, f"MAVLINK_MSG_ID_{name}"))]
    values = []
    for fname, ftype, length in zip(cls.fieldnames, cls.fieldtypes, cls.array_lengths):
        value = fields.get(fname)
        if ftype == "char":  # pymavlink's constructors take bytes
            value = value.encode() if isinstance(value, str) else bytes(value or b"")
        elif value is None:
            nan = math.nan if ftype in ("float", "double") else 0
            value = [nan] * length if length else nan
        values.append(value)
    msg = cls(*values)
    msg._header = dialect.MAVLink_header(cls.id, srcSystem=system, srcComponent=component)
    return msg


def from_message(msg: Message) -> dict[str, Any]:
    """The fields of a pymavlink message as MAVSDK's ``fields_json`` wants them."""
    return {k: v for k, v in msg.to_dict().items() if k != "mavpackettype"}


class MavsdkLink(Link):
    """A :class:`Link` whose connection is MAVSDK's (see the module docstring). ``url`` as for :class:`Link`."""

    def __init__(self, url: str, *, source_system: int = 1, open_timeout: float = FIRST_AUTOPILOT_S,
                 **kwargs: Any) -> None:
        super().__init__(url, source_system=source_system, open_timeout=open_timeout, **kwargs)
        self.sdk: Any = None
        self.system: Any = None
        self.direct: Any = None
        self.mission_raw: Any = None
        self.action: Any = None
        self.version = ""
        self.current_seq: int | None = None  # the vehicle's current mission item (its last MISSION_CURRENT)
        self._feeds: list[asyncio.Task] = []

    async def open(self) -> None:
        if self._loop is not None:
            raise LinkError("link already opened")
        self._loop = asyncio.get_running_loop()
        self._closing = False
        global _log_loop
        _log_loop = self._loop
        log_subscribe(_to_logging)
        config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        config.system_id = self.source_system
        self.source_component = config.component_id
        self.sdk = Mavsdk(config)
        config.destroy()
        self.version = await self.sdk.version()
        try:
            await self.sdk.add_any_connection(mavsdk_url(self.url))
        except Exception as exc:  # MavsdkConnectionError: the URL or the socket
            await self.close()
            raise LinkError(f"MAVSDK cannot open {self.url}: {exc}") from exc
        self.system = await self.sdk.first_autopilot(max(self.open_timeout, 0.1))
        if self.system is None:
            await self.close()
            raise LinkError(f"MAVSDK found no autopilot on {self.url} within {self.open_timeout:g} s")
        self.direct = MavlinkDirectAsync(self.system)
        self.mission_raw = MissionRawAsync(self.system)
        self.action = ActionAsync(self.system)
        self._conn = self.sdk  # "connected"
        self._feeds = [asyncio.create_task(self._feed(name), name=f"mavsdk {name}") for name in MESSAGES]
        self._heartbeat_task = asyncio.create_task(self._heartbeat_loop(), name=f"mavsdk-heartbeat {self.url}")
        try:
            await self.wait_heartbeat(timeout=max(self.open_timeout, 1.0))  # the target known, as on our link
        except BaseException:
            await self.close()  # nothing of MAVSDK's left running when the open fails
            raise
        log.info("MAVSDK %s on %s", self.version, self.url)

    async def _feed(self, name: str) -> None:
        async for raw in self.direct.subscribe_message(name):
            try:
                msg = to_message(raw.message_name, raw.system_id, raw.component_id, raw.fields_json)
            except (ValueError, KeyError, TypeError, AttributeError) as exc:
                self.bad_packets += 1
                if self.bad_packets == 1:
                    log.warning("unusable %s from MAVSDK (%s): %s", name, exc, raw.fields_json)
                continue
            self._dispatch(msg)

    async def close(self) -> None:
        feeds, self._feeds = self._feeds, []
        for task in feeds:
            task.cancel()
        await asyncio.gather(*feeds, return_exceptions=True)
        await super().close()  # the heartbeat watch, then _disconnect, then every waiter

    def _disconnect(self) -> None:
        """Destroy MAVSDK's plugins and the library instance (what closing our socket is on our own link)."""
        global _destroying
        for plugin in (self.direct, self.mission_raw, self.action):
            if plugin is not None:
                plugin.destroy()
        self.direct = self.mission_raw = self.action = self.system = None
        if self.sdk is not None:
            _destroying += 1
            try:
                self.sdk.destroy()
            finally:
                _destroying -= 1
            self.sdk = None
        self._conn = None

    def send(self, msg: Message) -> None:
        """Send through MAVSDK, in the background (MAVSDK's calls block a worker thread). A COMMAND_LONG goes
        through MAVSDK's command sender, which resends it until the autopilot answers; the answer is also
        delivered to our subscribers. Our HEARTBEAT is not sent: MAVSDK sends its own as a companion computer."""
        if self.direct is None:
            raise LinkError(f"link {self.url} is not connected")
        if msg.get_type() == "HEARTBEAT":
            return
        loop = asyncio.get_running_loop()
        if msg.get_type() == "COMMAND_LONG":
            task = loop.create_task(self.command(msg))
        else:
            task = loop.create_task(self.direct.send_message(self._outgoing(msg)))
        task.add_done_callback(_log_send_failure)

    def _outgoing(self, msg: Message) -> MavlinkMessage:
        fields = from_message(msg)
        return MavlinkMessage(msg.get_type(), self.source_system, self.source_component,
                              fields.get("target_system", 0), fields.get("target_component", 0), json.dumps(fields))

    async def command(self, msg: Message) -> Message | None:
        """A COMMAND_LONG through MAVSDK's command sender (resent until answered); its COMMAND_ACK, also delivered
        to our subscribers, or None when none came."""
        try:
            ack = await self.direct.send_command(self._outgoing(msg))
        except MavlinkDirectError as exc:
            log.debug("MAVSDK: no answer to %s: %s", msg, exc)
            return None
        if not ack.fields_json or self._loop is None:
            return None
        answer = to_message("COMMAND_ACK", ack.system_id or self.target_system or 0,
                            ack.component_id or self.target_component or 0, ack.fields_json)
        self._dispatch(answer)
        return answer

    # MAVSDK reconnects on its own; nothing of Link's connection handling applies
    def _connect(self) -> None:  # pragma: no cover - never called
        raise LinkError("MavsdkLink connects through MAVSDK")

    def _connection_lost(self, exc: BaseException) -> None:
        log.debug("MAVSDK send failed: %s", exc)

    def _dispatch(self, msg: Message) -> None:
        if msg.get_type() == "MISSION_CURRENT" and (msg.get_srcSystem(), msg.get_srcComponent()) == (
                self.target_system, self.target_component):
            self.current_seq = msg.seq
        super()._dispatch(msg)


def _log_send_failure(task: asyncio.Task) -> None:
    if not task.cancelled() and task.exception() is not None:
        log.warning("MAVSDK send failed: %s", task.exception())


# MAVSDK's MissionRawResult → (our exception, MAV_MISSION_RESULT). MAVSDK keeps neither the autopilot's own result
# code nor the item: ERROR and PROTOCOL_ERROR may be the autopilot's transfer trouble (as PX4's MAV_MISSION_ERROR).
_MISSION_REFUSALS = {
    "TOO_MANY_MISSION_ITEMS": mavlink.MAV_MISSION_NO_SPACE,
    "UNSUPPORTED": mavlink.MAV_MISSION_UNSUPPORTED,
    "DENIED": mavlink.MAV_MISSION_DENIED,
    "INVALID_SEQUENCE": mavlink.MAV_MISSION_INVALID_SEQUENCE,
    "INVALID_ARGUMENT": mavlink.MAV_MISSION_INVALID,
    "MISSION_TYPE_NOT_CONSISTENT": mavlink.MAV_MISSION_INVALID,
    "CURRENT_INVALID": mavlink.MAV_MISSION_INVALID,
    "INT_MESSAGES_NOT_SUPPORTED": mavlink.MAV_MISSION_UNSUPPORTED,
}
_MISSION_FAULTS = ("ERROR", "PROTOCOL_ERROR", "UNKNOWN")
_MISSION_TIMEOUTS = ("TIMEOUT", "BUSY", "TRANSFER_CANCELLED", "NO_SYSTEM", "NEXT")


def upload_error(exc: MissionRawError, operation: str) -> Exception:
    """Our error for a MAVSDK ``MissionRawError`` (its ``result`` is a MissionRawResult)."""
    name = exc.result.name
    if name in _MISSION_REFUSALS:
        return MissionUploadError(_MISSION_REFUSALS[name], None, operation)
    if name in _MISSION_FAULTS:
        return MissionUploadError(mavlink.MAV_MISSION_ERROR, None, operation, transfer_fault=True)
    if name == "NO_MISSION_AVAILABLE":
        return MissionUploadError(mavlink.MAV_MISSION_ERROR, None, operation)
    return MissionTimeout(f"{operation} (MAVSDK: {name or exc})")


def _to_mavsdk(item: MissionItem) -> Any:
    return RawItem(item.seq, item.frame, item.command, item.current, item.autocontinue, item.param1, item.param2,
               item.param3, item.param4, item.x, item.y, item.z, item.mission_type)


def _from_mavsdk(raw: Any, mission_type: int) -> MissionItem:
    return MissionItem(raw.seq, raw.frame, raw.command, raw.param1, raw.param2, raw.param3, raw.param4, raw.x,
                       raw.y, raw.z, raw.current, raw.autocontinue, mission_type)


# MAVSDK's ActionResult → MAV_RESULT (None: no answer, as our CommandError has it)
_ACTION_RESULTS = {
    "COMMAND_DENIED": mavlink.MAV_RESULT_DENIED,
    "COMMAND_DENIED_LANDED_STATE_UNKNOWN": mavlink.MAV_RESULT_DENIED,
    "COMMAND_DENIED_NOT_LANDED": mavlink.MAV_RESULT_DENIED,
    "BUSY": mavlink.MAV_RESULT_TEMPORARILY_REJECTED,
    "UNSUPPORTED": mavlink.MAV_RESULT_UNSUPPORTED,
    "FAILED": mavlink.MAV_RESULT_FAILED,
    "PARAMETER_ERROR": mavlink.MAV_RESULT_DENIED,
    "INVALID_ARGUMENT": mavlink.MAV_RESULT_DENIED,
}


class MavsdkMissionClient(MissionClient):
    """:class:`MissionClient` whose transfers and commands are MAVSDK's (module docstring); locking, verification
    by readback and the storage normalisation are inherited."""

    link: MavsdkLink

    def __init__(self, link: MavsdkLink) -> None:
        super().__init__(link)
        self._last_type: int | None = None  # the type of the last list MAVSDK transferred (see set_current)

    @property
    def writes_in_part(self) -> bool:
        """Never: ``mission_raw`` has no partial write."""
        return False

    async def _upload(self, items: list[MissionItem], mission_type: int) -> list[MissionItem] | None:
        """MAVSDK refuses a list without exactly one item flagged current (CURRENT_INVALID) and PX4 takes the flag
        as its new current item: when none is flagged, the item current on the vehicle now is (0 before any
        MISSION_CURRENT), so that PX4 keeps its index as it does with our own protocol."""
        raw = self.link.mission_raw
        if items and not any(it.current for it in items):
            now = self.link.current_seq if mission_type == MISSION else 0
            flag = now if now is not None and 0 <= now < len(items) else 0
            items = [replace(it, current=int(it.seq == flag)) for it in items]
        call = {MISSION: raw.upload_mission, FENCE: raw.upload_geofence, RALLY: raw.upload_rally_points}[mission_type]
        self._last_type = mission_type
        try:
            await call([_to_mavsdk(it) for it in items])
        except MissionRawError as exc:
            raise upload_error(exc, "upload") from exc
        except asyncio.CancelledError:
            # our wait ends, MAVSDK's transfer would go on in its thread: stop it as the protocol does
            asyncio.get_running_loop().create_task(raw.cancel_mission_upload()).add_done_callback(_log_send_failure)
            raise
        return None  # the caller reads it back

    async def upload_changed_verified(self, items: Sequence[MissionItem], previous: Sequence[MissionItem],
                                      mission_type: int = MISSION) -> str:
        """The whole list, verified (:meth:`upload_verified`): ``mission_raw`` has no partial write. Returns
        ``"whole"``, the path :meth:`MissionClient.upload_changed_verified` names so."""
        await self.upload_verified(items, mission_type)
        return "whole"

    async def _download(self, mission_type: int, expected: int | None = None) -> list[MissionItem]:
        """MAVSDK's download (its own transfer; ``expected`` is left to the comparison that follows)."""
        raw = self.link.mission_raw
        call = {MISSION: raw.download_mission, FENCE: raw.download_geofence,
                RALLY: raw.download_rallypoints}[mission_type]
        self._last_type = mission_type
        try:
            got = await call()
        except MissionRawError as exc:
            if exc.result.name == "NO_MISSION_AVAILABLE":
                return []  # MAVSDK's word for an empty list
            raise upload_error(exc, "download") from exc
        items = got if isinstance(got, list) else getattr(got, "mission_items", got)
        return [_from_mavsdk(it, mission_type) for it in items]

    async def _clear(self, mission_type: int) -> None:
        if mission_type != MISSION:
            await super()._clear(mission_type)  # MAVSDK clears only the mission: ours, through its link
            return
        try:
            await self.link.mission_raw.clear_mission()
        except MissionRawError as exc:
            raise upload_error(exc, "clear") from exc

    async def set_current(self, seq: int, *, timeout: float = 0.5, retries: int = 2) -> None:
        """MAVSDK's set_current_mission_item (MISSION_SET_CURRENT, confirmed by MISSION_CURRENT). MAVSDK 4.1 checks
        ``seq`` against the length of the last list it transferred, of whatever type (after a fence of 2 items
        it refuses item 2 of a 16-item mission with INVALID_ARGUMENT): the mission is read first when the last
        transfer was another list. MAVSDK's call can wait for ever (a MISSION_CURRENT of another item makes its
        SetCurrentWorkItem remove its timer, then refresh the removed one), and CI twice saw it unconfirmed after
        ``SET_CURRENT_S``. Then, or after MAVSDK's own TIMEOUT, the message goes out through the raw link, as the
        base client sends it (a MISSION_CURRENT with ``seq`` also ends MAVSDK's waiting call). Unconfirmed, or
        refused by MAVSDK, it is a :class:`CommandError`."""
        cmd = mavlink.MAV_CMD_DO_SET_MISSION_CURRENT
        async with self._lock:
            if self._last_type != MISSION:
                await self._download(MISSION)
            call = asyncio.ensure_future(self.link.mission_raw.set_current_mission_item(seq))
            call.add_done_callback(lambda f: f.cancelled() or f.exception())  # no "never retrieved" if abandoned
            try:
                await asyncio.wait_for(asyncio.shield(call), SET_CURRENT_S)
                return
            except MissionRawError as exc:
                if exc.result.name != "TIMEOUT":
                    raise CommandError(cmd, None, f"MAVSDK set_current_mission_item({seq}): {exc.result.name}") \
                        from exc
                why = "TIMEOUT"
            except TimeoutError:
                why = f"no confirmation within {SET_CURRENT_S:g} s"
            log.warning("MAVSDK set_current_mission_item(%d): %s; sending MISSION_SET_CURRENT itself", seq, why)
            if not await self._set_current_by_message(seq, timeout, retries):
                raise CommandError(cmd, None, f"MAVSDK set_current_mission_item({seq}): {why}, and MISSION_SET_CURRENT "
                                   f"unconfirmed {retries + 1} times")

    async def command_long(self, command: int, *params: float, timeout: float = 1.0, retries: int = 3,
                           target_component: int | None = None, persist: bool = True) -> int:
        """Arming through ``action``, MISSION_START through ``mission_raw``, anything else through MAVSDK's
        command sender; a refusal is a :class:`CommandError` with the MAV_RESULT (None: no answer)."""
        if command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and len(params) == 1 and params[0] in (0, 1):
            return await self._action(command, self.link.action.arm if params[0] else self.link.action.disarm)
        if command == mavlink.MAV_CMD_MISSION_START:
            try:
                await self.link.mission_raw.start_mission()
            except MissionRawError as exc:
                raise CommandError(command, None, f"MAVSDK start_mission: {exc}") from exc
            return mavlink.MAV_RESULT_ACCEPTED
        ts, tc = self._target()
        tc = tc if target_component is None else target_component
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        ack = await self.link.command(mavlink.MAVLink_command_long_message(ts, tc, command, 0, *p))
        if ack is None:
            raise CommandError(command, None, "MAVSDK got no COMMAND_ACK")
        if ack.result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            return int(ack.result)
        raise CommandError(command, int(ack.result))

    async def _action(self, command: int, call: Any) -> int:
        try:
            await call()
        except ActionError as exc:
            raise CommandError(command, _ACTION_RESULTS.get(exc.result.name), f"MAVSDK action: {exc}") from exc
        return mavlink.MAV_RESULT_ACCEPTED


def unsupported_options(*, signing: bool, target_system: bool = False) -> str | None:
    """Why ``--backend mavsdk`` cannot do what was asked (one line), or None."""
    if signing:
        return ("--backend mavsdk cannot sign MAVLink: MAVSDK-Python 4 has no signing API; "
                "use the default pymavlink backend with --signing-key or --signing-passphrase")
    if target_system:
        return ("--backend mavsdk follows the first autopilot MAVSDK discovers and cannot be pinned to a system: "
                "use the default pymavlink backend with --target-system")
    return None
