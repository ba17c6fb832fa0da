"""STATUSTEXT to the ground station: the companion's own lines in the pilot's message list (issue 36).

A line longer than STATUSTEXT's 50 characters goes out in chunks that share a non-zero ``id`` with ``chunk_seq``
0, 1, … (MAVLink 2's extension fields, as ArduPilot and PX4 send theirs); the last chunk holds a NUL, and a text
of an exact multiple of 50 characters ends with an empty chunk, so a receiver never waits for more. Ground stations
that reassemble (QGroundControl, MAVProxy) show one line; the others show the pieces in order.
"""

from __future__ import annotations

import enum
import logging
import weakref
from dataclasses import dataclass, field
from typing import Any, Protocol

log = logging.getLogger(__name__)

TEXT_BYTES = 50  # STATUSTEXT.text (MAVLink common.xml)
MAX_CHUNKS = 8  # a longer line is cut: the message list is for a glance, the report has the detail


class Severity(enum.IntEnum):
    """MAV_SEVERITY (RFC 5424 levels)."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


class _Sender(Protocol):
    dialect: Any

    def send(self, msg: Any) -> None: ...


def chunks(text: str, ident: int) -> list[tuple[bytes, int, int]]:
    """``(text bytes, id, chunk_seq)`` for each STATUSTEXT of ``text``: one with id 0 when it fits, else pieces
    of 50 bytes with ``ident`` (1…65535); non-ASCII characters become ``?`` (the field is ASCII on the wire)."""
    raw = text.encode("ascii", "replace")
    if len(raw) <= TEXT_BYTES:
        return [(raw, 0, 0)]
    if not 1 <= ident <= 0xFFFF:
        raise ValueError(f"a chunked STATUSTEXT needs an id in 1..65535, not {ident}")
    raw = raw[:TEXT_BYTES * MAX_CHUNKS - 1]  # room for the NUL that says "last chunk"
    pieces = [raw[k:k + TEXT_BYTES] for k in range(0, len(raw), TEXT_BYTES)]
    if len(pieces[-1]) == TEXT_BYTES:
        pieces.append(b"")
    return [(p, ident, seq) for seq, p in enumerate(pieces)]


# the next chunk id of each link: every sender on a link (one per request of `fuseplan serve`) counts on, so two
# long lines on the same link never share an id, which a ground station reassembles by (source, id)
_NEXT_ID: weakref.WeakKeyDictionary[Any, int] = weakref.WeakKeyDictionary()


@dataclass
class StatusTexts:
    """Sends the companion's lines on a link; ``send`` never raises (a lost link loses the line, logged here:
    the event log and the report keep it)."""

    link: _Sender
    sent: list[tuple[int, str]] = field(default_factory=list)  # (severity, text) of every line sent whole

    def send(self, text: str, severity: int = Severity.INFO) -> bool:
        """True when every chunk went out."""
        ident = _NEXT_ID.get(self.link, 1)
        parts = chunks(text, ident)
        if parts[0][1]:
            _NEXT_ID[self.link] = ident % 0xFFFF + 1
        try:
            for piece, pid, seq in parts:
                self.link.send(self.link.dialect.MAVLink_statustext_message(int(severity), piece, pid, seq))
        except Exception as exc:  # LinkError or a closed socket: the flight goes on without it
            log.info("STATUSTEXT not sent (%s): %s", exc, text)
            return False
        self.sent.append((int(severity), text))
        return True


class Reassembler:
    """A ground station's side: STATUSTEXT messages in, whole lines out (per source and id)."""

    def __init__(self) -> None:
        self._partial: dict[tuple[int, int, int], dict[int, bytes]] = {}

    def feed(self, msg: Any) -> str | None:
        """The whole line this message completes, or None while chunks are missing."""
        text = msg.text if isinstance(msg.text, bytes) else str(msg.text).encode("ascii", "replace")
        ident = int(getattr(msg, "id", 0) or 0)
        done = b"\0" in text or len(text) < TEXT_BYTES
        text = text.split(b"\0", 1)[0]
        if ident == 0:
            return text.decode("ascii", "replace")
        key = (msg.get_srcSystem(), msg.get_srcComponent(), ident)
        parts = self._partial.setdefault(key, {})
        parts[int(getattr(msg, "chunk_seq", 0) or 0)] = text
        if not done:
            return None
        if sorted(parts) != list(range(len(parts))):
            return None  # a chunk lost: keep waiting (a later id replaces nothing, the dict is per id)
        del self._partial[key]
        return b"".join(parts[k] for k in range(len(parts))).decode("ascii", "replace")

