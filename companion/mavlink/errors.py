"""Companion errors: each says what failed and where (MAVSDK's ``MissionError(result, origin)`` style)."""

from __future__ import annotations

from planner.errors import FuseplanError


class CompanionError(FuseplanError):
    """Root of companion failures."""


class LinkError(CompanionError):
    """The MAVLink connection could not be opened or was lost."""


class MissionTimeout(CompanionError):
    """A mission transfer step got no answer after all retries."""

    def __init__(self, operation: str, seq: int | None = None) -> None:
        self.operation = operation
        self.seq = seq
        where = f" at item {seq}" if seq is not None else ""
        super().__init__(f"mission {operation} timed out{where}")


class MissionUploadError(CompanionError):
    """The autopilot answered a transfer with a MISSION_ACK error (``result`` is a MAV_MISSION_RESULT)."""

    def __init__(self, result: int, seq: int | None = None, operation: str = "upload",
                 transfer_fault: bool = False) -> None:
        from companion.mavlink.items import mission_result_name

        self.result = result
        self.seq = seq
        self.operation = operation
        self.transfer_fault = transfer_fault  # the answer may be the autopilot's own transfer trouble
        where = f" at item {seq}" if seq is not None else ""
        super().__init__(f"mission {operation} refused{where}: {mission_result_name(result)}")

    @property
    def refused(self) -> bool:
        """A refusal (of an item or the list), not the autopilot's own timeout cancelling the transfer nor an
        answer that may stand for its transfer trouble (``transfer_fault``, e.g. PX4's MAV_MISSION_ERROR):
        doing the same upload again will likely be refused again."""
        from pymavlink.dialects.v20 import common as mavlink

        return not self.transfer_fault and self.result != mavlink.MAV_MISSION_OPERATION_CANCELLED


class MissionVerifyError(CompanionError):
    """The readback differs from what was uploaded."""

    def __init__(self, seq: int, field: str, sent: object, got: object) -> None:
        self.seq, self.field, self.sent, self.got = seq, field, sent, got
        super().__init__(f"mission readback differs at item {seq}: {field} sent {sent!r}, got {got!r}")


class UploadAborted(CompanionError):
    """An upload failed for good (``cause``); ``left_with`` says which verified mission the vehicle was left with
    (the previous one restored, or none if that failed too)."""

    def __init__(self, cause: CompanionError, left_with: str) -> None:
        self.cause, self.left_with = cause, left_with
        super().__init__(f"{cause}; {left_with}")


class CommandError(CompanionError):
    """A COMMAND_LONG was refused or not acknowledged."""

    def __init__(self, command: int, result: int | None, text: str = "") -> None:
        self.command, self.result = command, result
        what = "no COMMAND_ACK" if result is None else f"result {result}"
        super().__init__(f"command {command} failed: {what}{': ' + text if text else ''}")


class VehicleHolding(CompanionError):
    """The companion stopped with the vehicle holding (loitering): no verified mission could be made live."""


class VehicleContentError(CompanionError):
    """What the vehicle holds cannot be read as the operator's world: item ``seq`` of its ``list_name`` list
    ("fence", "rally", "mission") and why (``reason``), e.g. a polygon whose vertex count disagrees with its items."""

    def __init__(self, list_name: str, seq: int, reason: str) -> None:
        self.list_name, self.seq, self.reason = list_name, seq, reason
        super().__init__(f"the vehicle's {list_name} item {seq}: {reason}")


class FenceTooLarge(CompanionError):
    """The fence does not fit the autopilot's fence storage, found before any of it was sent (a user's zones to
    drop or simplify, not a link fault): the one-line ``reason`` says how much, the limit and which zones."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)
