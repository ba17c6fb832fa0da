"""A scenario's raw tables as TOML text: what an imported mission becomes, so that it loads, is checked and is
named (PLAN.json's ``scenario_file``) exactly like a scenario someone wrote.

Only what scenarios hold: tables, arrays of tables, strings, booleans, finite numbers, arrays of those, and small
tables inline (a lat/lon point). ``None`` values are left out (a key omitted takes its default). Generated scenarios
(planner.bench.hardmaps) are written here too: numbers to fixed decimals (:class:`Fixed`), a comment above a table,
arrays of tables whose kinds interleave, a point table as a table (:class:`Table`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Fixed:
    """A number written with ``places`` decimals (``2400.00``), as a generated file writes all of its numbers."""

    value: float
    places: int = 2


class Table(dict):
    """A table written as ``[name]`` even when its keys make it look like a point (a generated file's ``[home]``)."""


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, (float, Fixed)):
        x = v.value if isinstance(v, Fixed) else v
        if not math.isfinite(x):
            raise ValueError(f"{x!r} has no TOML form in a scenario (leave the key out)")
        return f"{x:.{v.places}f}" if isinstance(v, Fixed) else repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a TOML basic string: JSON's escapes are TOML's
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items() if x is not None) + " }"
    raise TypeError(f"no TOML form for {type(v).__name__}")


def _key(k: str) -> str:
    return k if k.replace("_", "").replace("-", "").isalnum() and k.isascii() else json.dumps(k)


def _is_table_array(v: Any) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, Mapping) for x in v)


def dumps(raw: Mapping[str, Any], header: str = "", notes: Mapping[str, str] | None = None,
          entries: Sequence[tuple[str, Mapping[str, Any]]] = ()) -> str:
    """TOML text for ``raw``: scalars and inline values first, then its tables and arrays of tables in order, then
    ``entries``, (name, table) entries of top-level arrays of tables in the order given (kinds may interleave).
    ``header`` is a comment at the top; ``notes`` a comment line above a table, by the table's name."""
    lines = [f"# {line}" for line in header.splitlines()]
    notes = notes or {}

    def table(prefix: str, body: Mapping[str, Any], array: bool = False) -> None:
        if prefix:
            lines.append("")
            lines.extend(f"# {line}" for line in notes.get(prefix, "").splitlines())
            lines.append(f"[[{prefix}]]" if array else f"[{prefix}]")
        nested = []
        for k, v in body.items():
            if v is None:
                continue
            if isinstance(v, Mapping) and not _inline(v) or _is_table_array(v):
                nested.append((k, v))
            else:
                lines.append(f"{_key(k)} = {_value(v)}")
        for k, v in nested:
            name = f"{prefix}.{_key(k)}" if prefix else _key(k)
            if _is_table_array(v):
                for item in v:
                    table(name, item, array=True)
            else:
                table(name, v)

    table("", raw)
    for name, body in entries:
        table(_key(name), body, array=True)
    return "\n".join(lines).lstrip("\n") + "\n"


def _inline(v: Mapping[str, Any]) -> bool:
    """A point table ({lat, lon, alt, ref}) is written inline, as people write it."""
    return not isinstance(v, Table) and set(v) <= {"lat", "lon", "alt", "ref"} and {"lat", "lon"} <= set(v)
