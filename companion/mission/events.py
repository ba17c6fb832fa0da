"""The flight's event log: one JSON object per line (``events.jsonl``), optionally echoed to a callback and passed
to listeners (the status page)."""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO


class EventLog:
    """Append-only JSON-lines log with wall time ``t`` (s since the log opened) on every record."""

    def __init__(self, path: Path | None = None, echo: Callable[[dict[str, Any]], None] | None = None) -> None:
        self._file: TextIO | None = path.open("w") if path is not None else None
        self._t0 = time.monotonic()
        self.records: list[dict[str, Any]] = []
        self._listeners: list[Callable[[dict[str, Any]], None]] = [echo] if echo is not None else []

    def subscribe(self, listener: Callable[[dict[str, Any]], None]) -> None:
        """Pass every record from now on to ``listener`` too (it must not block: it runs inside :meth:`log`)."""
        self._listeners.append(listener)

    def unsubscribe(self, listener: Callable[[dict[str, Any]], None]) -> None:
        self._listeners.remove(listener)

    def log(self, event: str, **fields: Any) -> dict[str, Any]:
        rec = {"t": round(time.monotonic() - self._t0, 3), "event": event, **fields}
        self.records.append(rec)
        if self._file is not None:
            self._file.write(json.dumps(rec, default=str) + "\n")
            self._file.flush()
        for listener in self._listeners:
            listener(rec)
        return rec

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
