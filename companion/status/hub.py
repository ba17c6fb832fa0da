"""The status page's event fan-out: one bounded ring of encoded records that every browser reads with its own
cursor (docs/design.md, "The status page").

Publishing is O(1) whatever the number of browsers and never waits for one: a record is encoded once, appended
to the ring (the oldest falls out when it is full) and the readers are woken. A reader that falls more than the
ring behind skips what fell out (drop-oldest) and is told how many it missed; the latest ``scene`` and
``mission`` are pinned so that it, or a browser that joins late, still has the map and the mission.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import threading
from collections import deque
from collections.abc import AsyncGenerator, Iterable
from typing import Any

from companion.mission.events import Event
from planner.plan import json_safe

log = logging.getLogger(__name__)
HISTORY = 20_000  # records kept for browsers that join late or fall behind (~4 MB at 200 bytes a record)
PINNED = (Event.SCENE, Event.MISSION)  # kinds whose latest record every reader gets, even after it left the ring
CHUNK_BYTES = 64 * 1024  # at most this much per write to one browser


def sse(seq: int, rec: dict[str, Any]) -> bytes:
    """One Server-Sent Event: ``id`` the sequence number, ``data`` the record as strict JSON on one line (a
    non-finite number, which the log may hold, becomes null: a browser's JSON.parse refuses Infinity)."""
    data = json.dumps(json_safe(rec), default=str, separators=(",", ":"), allow_nan=False)
    return f"id: {seq}\ndata: {data}\n\n".encode()


class StatusHub:
    """Fan-out of event records to any number of readers; safe to publish from any thread."""

    def __init__(self, history: int = HISTORY) -> None:
        self._ring: deque[tuple[int, bytes]] = deque(maxlen=history)
        self._pinned: dict[str, tuple[int, bytes]] = {}
        self._seq = 0  # sequence number of the last record published
        self._wake = asyncio.Event()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: int | None = None
        self.closed = False
        self.readers = 0  # readers attached now
        self.skipped = 0  # records dropped for slow readers, in all

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """The loop the readers run in (publishing from another thread hops onto it)."""
        self._loop, self._thread = loop, threading.get_ident()

    def publish(self, rec: dict[str, Any]) -> None:
        """Append one record (an :class:`~companion.mission.events.EventLog` listener: it runs inside the flight's
        ``log()``, so it never raises: a record it cannot encode is left off the page with a warning, one published
        from another thread after the loop has closed is dropped, as no browser is left to read it)."""
        if self._loop is not None and threading.get_ident() != self._thread:
            with contextlib.suppress(RuntimeError):  # the loop has closed: no reader is left to wake
                self._loop.call_soon_threadsafe(self.publish, rec)
            return
        try:
            data = sse(self._seq + 1, rec)
        except Exception as e:  # TypeError, ValueError, RecursionError, a __str__ that raises: never the flight's
            log.warning("status page: a %r record cannot be sent to browsers (%s: %s); left off the page",
                        rec.get("event"), type(e).__name__, e)
            return
        self._seq += 1
        entry = (self._seq, data)
        self._ring.append(entry)
        if rec.get("event") in PINNED:
            self._pinned[rec["event"]] = entry
        self._notify()

    def extend(self, records: Iterable[dict[str, Any]]) -> None:
        for rec in records:
            self.publish(rec)

    def close(self) -> None:
        """Stop every reader after what it has already been sent."""
        self.closed = True
        self._notify()

    def _notify(self) -> None:
        self._wake.set()
        self._wake = asyncio.Event()

    @property
    def buffered_bytes(self) -> int:
        """Bytes held in the ring (the hub's whole memory, whatever the number of readers)."""
        return sum(len(b) for _s, b in self._ring)

    async def read(self, heartbeat_s: float = 15.0) -> AsyncGenerator[bytes, None]:
        """Chunks for one reader: a ``reset``, the pinned records older than the ring, the ring, then each new
        record as it comes; an SSE comment every ``heartbeat_s`` of silence (a vanished reader shows up as a
        failed write). Ends when the hub closes."""
        self.readers += 1
        try:
            yield b'event: reset\ndata: {}\n\n'
            cursor = 0  # the last sequence number this reader has
            while True:
                wake = self._wake
                chunk = self._take(cursor)
                if chunk is not None:
                    cursor, data = chunk
                    yield data
                    continue
                if self.closed:
                    return
                try:
                    await asyncio.wait_for(wake.wait(), heartbeat_s)
                except TimeoutError:
                    yield b": keep-alive\n\n"
        finally:
            self.readers -= 1

    def _take(self, cursor: int) -> tuple[int, bytes] | None:
        """(new cursor, bytes) of what follows ``cursor``, at most :data:`CHUNK_BYTES` (one record at least)."""
        if not self._ring or self._ring[-1][0] <= cursor:
            return None
        first = self._ring[0][0]
        parts: list[bytes] = []
        if cursor < first - 1:  # it fell behind the ring, or is new: the pinned records it no longer finds there
            missed = first - 1 - cursor
            if cursor:
                self.skipped += missed
                parts.append(sse(0, {"event": Event.STATUS_SKIPPED.value, "records": missed,
                                     "note": "this browser fell behind; the oldest records were dropped"}))
            parts.extend(b for s, b in sorted(self._pinned.values()) if s < first)
            cursor = first - 1
        size = sum(map(len, parts))
        for s, b in itertools.islice(self._ring, cursor + 1 - first, None):  # sequence numbers are contiguous
            if parts and size + len(b) > CHUNK_BYTES:
                break
            parts.append(b)
            size += len(b)
            cursor = s
        return cursor, b"".join(parts)

