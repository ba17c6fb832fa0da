"""The flight's event log: one JSON object per line (``events.jsonl``), optionally echoed to a callback."""

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
        self._echo = echo
        self._t0 = time.monotonic()
        self.records: list[dict[str, Any]] = []

    def log(self, event: str, **fields: Any) -> dict[str, Any]:
        rec = {"t": round(time.monotonic() - self._t0, 3), "event": event, **fields}
        self.records.append(rec)
        if self._file is not None:
            self._file.write(json.dumps(rec, default=str) + "\n")
            self._file.flush()
        if self._echo is not None:
            self._echo(rec)
        return rec

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
