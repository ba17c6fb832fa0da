"""A scenario's raw tables as TOML text: what an imported mission becomes, so that it loads, is checked and is
named (PLAN.json's ``scenario_file``) exactly like a scenario someone wrote.

Only what scenarios hold: tables, arrays of tables, strings, booleans, finite numbers, arrays of those, and small
tables inline (a lat/lon point). ``None`` values are left out (a key omitted takes its default).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise ValueError(f"{v!r} has no TOML form in a scenario (leave the key out)")
        return repr(v)
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


def dumps(raw: Mapping[str, Any], header: str = "") -> str:
    """TOML text for ``raw``: scalars and inline values first, then tables, then arrays of tables, in order."""
    lines = [f"# {line}" for line in header.splitlines()]

    def table(prefix: str, body: Mapping[str, Any], array: bool = False) -> None:
        if prefix:
            lines.append("")
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
    return "\n".join(lines).lstrip("\n") + "\n"


def _inline(v: Mapping[str, Any]) -> bool:
    """A point table ({lat, lon, alt, ref}) is written inline, as people write it."""
    return set(v) <= {"lat", "lon", "alt", "ref"} and {"lat", "lon"} <= set(v)
