"""Fuzzing the scenario loader at its limits (issue 33), beside test_scenario_fuzz.py: numbers far outside any
physical range and values nested up to thousands of levels, in the file and in ``--set``, load or fail as one
ScenarioError line naming the file; a scenario that loads passes the work estimate or fails it in one line."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_config_ranges import FIELDS
from test_scenario_fuzz import BASES, _paths, document

from planner.errors import ScenarioError
from planner.plan import problem_from_scenario
from planner.workload import JobTooLarge, check_workload
from planner.world.scenario import Scenario, load_scenario

FUZZ = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
SENTINEL = "__NESTED__"

extreme_floats = st.one_of(
    st.sampled_from([1e308, -1e308, 1e300, 5e-324, -5e-324, 1e-300, 0.0, -0.0, 1e6, 1e9, 1e15, 2.0**63]),
    st.floats(min_value=-1e308, max_value=1e308, allow_nan=False, allow_infinity=False))
extreme_ints = st.one_of(st.sampled_from([0, -1, 2**31, 2**63 - 1, 2**63, 10**30, -(10**30)]),
                         st.integers(min_value=-(10**40), max_value=10**40))
extremes = st.one_of(extreme_floats, extreme_ints)


def nested(kind: str, depth: int) -> str:
    """A TOML value ``depth`` arrays or inline tables deep (text, so that no recursive writer is needed)."""
    return "[" * depth + "]" * depth if kind == "array" else "{a = " * depth + "1" + " }" * depth


def _numeric_paths(raw: dict[str, Any]) -> list[tuple]:
    out = []
    for path in _paths(raw):
        node: Any = raw
        for p in path:
            node = node[p]
        if isinstance(node, (int, float)) and not isinstance(node, bool):
            out.append(path)
    return out


def _load(path: Path, overrides: list[str] = ()) -> Scenario | None:
    """Load; a ScenarioError must be one line starting with the file. A loaded scenario's job is checked too."""
    try:
        sc = load_scenario(path, overrides)
    except ScenarioError as e:
        assert "\n" not in str(e) and str(e).startswith(str(path)), str(e)
        return None
    try:
        check_workload(problem_from_scenario(sc), sc.planner, source=str(path))
    except JobTooLarge as e:
        assert "\n" not in str(e) and str(e).startswith(str(path)), str(e)
    return sc


@FUZZ
@given(base=st.sampled_from(BASES), data=st.data())
def test_extreme_numbers_in_the_file(tmp_path: Path, base: dict[str, Any], data: st.DataObject) -> None:
    raw = copy.deepcopy(base)
    for _ in range(data.draw(st.integers(1, 3))):
        path = data.draw(st.sampled_from(_numeric_paths(raw)))
        parent: Any = raw
        for p in path[:-1]:
            parent = parent[p]
        parent[path[-1]] = data.draw(extremes)
    f = tmp_path / "extreme.toml"
    f.write_text(document(raw))
    _load(f)


@FUZZ
@given(base=st.sampled_from(BASES), field=st.sampled_from([n for n, _, _ in FIELDS]), value=extremes)
def test_extreme_numbers_in_overrides(tmp_path: Path, base: dict[str, Any], field: str, value: float) -> None:
    f = tmp_path / "base.toml"
    f.write_text(document(base))
    _load(f, [f"{field}={value!r}"])


@FUZZ
@given(base=st.sampled_from(BASES), kind=st.sampled_from(["array", "table"]),
       depth=st.one_of(st.integers(1, 40), st.integers(40, 3000)), data=st.data())
def test_deep_values_in_the_file(tmp_path: Path, base: dict[str, Any], kind: str, depth: int,
                                 data: st.DataObject) -> None:
    raw = copy.deepcopy(base)
    path = data.draw(st.sampled_from(_paths(raw)))
    parent: Any = raw
    for p in path[:-1]:
        parent = parent[p]
    parent[path[-1]] = SENTINEL
    f = tmp_path / "deep.toml"
    f.write_text(document(raw).replace(f'"{SENTINEL}"', nested(kind, depth)))
    if _load(f) is not None:
        assert depth < 16  # a scenario only loads while its nesting is within the limit


@FUZZ
@given(base=st.sampled_from(BASES), kind=st.sampled_from(["array", "table"]),
       depth=st.one_of(st.integers(1, 40), st.integers(40, 3000)),
       key=st.sampled_from(["planner.pso.n_pop", "route.start", "cylinders[0]", "extra", "a.b.c"]))
def test_deep_values_in_overrides(tmp_path: Path, base: dict[str, Any], kind: str, depth: int, key: str) -> None:
    f = tmp_path / "base.toml"
    f.write_text(document(base))
    _load(f, [f"{key}={nested(kind, depth)}"])
