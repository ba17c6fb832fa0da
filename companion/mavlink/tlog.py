"""A telemetry log (``.tlog``) of a link, as MAVProxy and pymavlink write one: per MAVLink message, its time as 8
bytes big-endian (microseconds since the epoch) and then its bytes as they went over the wire. pymavlink's
``mavutil.mavlink_connection("flight.tlog")``, ``mavlogdump.py``, MAVExplorer, Mission Planner and QGroundControl
read it back.

The two lowest bits of the time are the link number, as pymavlink's reader takes them (``msg._link``): 0 for what
we received, 3 for what we sent, as MAVProxy marks its own messages. Times never go backwards in the file (the wall
clock may step): each record is stamped at least 4 µs after the one before.
"""

from __future__ import annotations

import logging
import struct
import time
from pathlib import Path
from typing import BinaryIO

log = logging.getLogger(__name__)

RECEIVED_LINK = 0  # the link number of a received message (the low two bits of its time)
SENT_LINK = 3  # of one we sent (MAVProxy's mark for the messages it sends)
FLUSH_S = 1.0  # wall seconds between flushes: a flight cut short (a crash, a kill) loses at most this much


class Tlog:
    """Appends records to ``path``. The file is created (truncated) at the first record and flushed at least
    every :data:`FLUSH_S`; after :meth:`close` a further record reopens it for appending (a link opened again).
    A write that fails (a full disk) is logged once and recording stops: the link never fails for its log."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.records = 0
        self.failed: OSError | None = None
        self._file: BinaryIO | None = None
        self._created = False
        self._last_us = 0
        self._flushed = 0.0

    def write(self, buf: bytes, link: int = RECEIVED_LINK) -> None:
        """One message's bytes (``msg.get_msgbuf()``), stamped now."""
        if self.failed is not None or not buf:
            return
        us = max(int(time.time() * 1e6) & ~3, self._last_us + 4)
        self._last_us = us
        try:
            if self._file is None:
                self._file = self.path.open("ab" if self._created else "wb")
                self._created = True
            self._file.write(struct.pack(">Q", us | link) + bytes(buf))
            self.records += 1
            now = time.monotonic()
            if now - self._flushed >= FLUSH_S:
                self._file.flush()
                self._flushed = now
        except OSError as exc:
            self.failed = exc
            log.warning("telemetry log %s: %s; no more messages are recorded", self.path, exc)
            self.close()

    def close(self) -> None:
        """Flush and close the file (idempotent)."""
        f, self._file = self._file, None
        if f is not None:
            try:
                f.close()
            except OSError as exc:
                log.warning("closing telemetry log %s: %s", self.path, exc)
