"""Fuzzing the scenario loader (issue 7): whatever a file holds, loading it gives a Scenario or a ScenarioError
(one line, file and field), never any other exception."""

from __future__ import annotations

import copy
import json
import math
import re
import tomllib
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from planner.errors import ScenarioError
from planner.world.scenario import Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[3]
BASES = [tomllib.loads((ROOT / "sitl_scenarios" / name).read_text())
         for name in ("rescue_dynamic.toml", "large_obstacle_field.toml", "mountain_rescue.toml",
                      "crossing_traffic.toml")]
FILE_SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def _key(k: str) -> str:
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k)


def to_toml(value: Any) -> str:
    """A TOML value (inline tables and arrays only; TOML 1.0 allows mixed arrays)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(to_toml(v) for v in value) + "]"
    return "{ " + ", ".join(f"{_key(k)} = {to_toml(v)}" for k, v in value.items()) + " }"


def document(raw: dict[str, Any]) -> str:
    return "\n".join(f"{_key(k)} = {to_toml(v)}" for k, v in raw.items()) + "\n"


scalars = st.one_of(
    st.booleans(), st.integers(min_value=-(2**63), max_value=2**63 - 1),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    st.sampled_from([0, -1, 1e9, 1e-9, 1e308, 0xFFFFFF + 1, "plane", "copter", "loiter", "fusion", ""]))
values = st.recursive(scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)), max_leaves=12)


def _paths(node: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, prefix + (i,))
    return out


@st.composite
def mutated(draw: st.DrawFn) -> dict[str, Any]:
    """A shipped scenario with a few random edits: a value replaced by anything, a key deleted, a key added."""
    raw = copy.deepcopy(draw(st.sampled_from(BASES)))
    for _ in range(draw(st.integers(1, 4))):
        paths = _paths(raw)
        path = draw(st.sampled_from(paths))
        parent = raw
        for p in path[:-1]:
            parent = parent[p]
        action = draw(st.sampled_from(["replace", "delete", "add"]))
        if action == "replace":
            parent[path[-1]] = draw(values)
        elif action == "delete":
            del parent[path[-1]]
        elif isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=8))] = draw(values)
    return raw


def _load(tmp_path: Path, text: str | bytes) -> None:
    f = tmp_path / "fuzz.toml"
    f.write_bytes(text if isinstance(text, bytes) else text.encode("utf-8", "surrogatepass"))
    try:
        result = load_scenario(f)
    except ScenarioError as e:
        assert "\n" not in str(e) and str(e).startswith(str(f))
        return
    assert isinstance(result, Scenario)


@FILE_SETTINGS
@given(raw=mutated())
def test_mutated_scenarios_load_or_fail_cleanly(tmp_path: Path, raw: dict[str, Any]) -> None:
    _load(tmp_path, document(raw))


@FILE_SETTINGS
@given(raw=st.dictionaries(st.text(min_size=1, max_size=10), values, max_size=6))
def test_random_documents_fail_cleanly(tmp_path: Path, raw: dict[str, Any]) -> None:
    _load(tmp_path, document(raw))


@FILE_SETTINGS
@given(blob=st.binary(max_size=300))
def test_random_bytes_fail_cleanly(tmp_path: Path, blob: bytes) -> None:
    _load(tmp_path, blob)


def test_the_emitter_round_trips_the_shipped_scenarios(tmp_path: Path) -> None:
    for raw in BASES:
        assert tomllib.loads(document(raw)) == raw
        _load(tmp_path, document(raw))
