"""Fuzzing what a user hands `fly` and `export` (issue 33), beside the scenario loader's fuzz tests: a PLAN.json with
any key replaced by any JSON value (or removed) and the options checked before planning. Every outcome is an exit
code the README documents, with at most one `fuseplan` line on stderr and never a traceback."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from companion.cli import main
from companion.mavlink.link import NETWORK_SCHEMES, check_url
from planner.errors import FuseplanError

ROOT = Path(__file__).resolve().parents[2]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"
FUZZ = settings(max_examples=120, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

json_values = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(min_value=-(10**400), max_value=10**400),
              st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=4)),
    max_leaves=12)


@pytest.fixture(scope="module")
def good_plan(static_plan_doc) -> dict[str, Any]:
    return static_plan_doc()


def _paths(doc: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key and list index path in ``doc`` (the waypoints' coordinates included)."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list) and len(doc) <= 40:  # the trajectory's thousands of samples: the list itself only
        for i, v in enumerate(doc):
            out += _paths(v, prefix + (i,))
    return out


def _outcome(capsys) -> list[str]:
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("fuseplan")]
    assert len(lines) <= 1, lines
    return lines


@FUZZ
@given(data=st.data())
def test_any_damage_to_a_plan_file_is_one_line_and_a_documented_exit(good_plan, tmp_path, capsys, data) -> None:
    """One key or index of a good PLAN.json replaced by any JSON value, or removed: `export` writes it (the change
    did not matter), refuses it as malformed (2) or as failing its check (3), in one line, never half a file."""
    doc = json.loads(json.dumps(good_plan))
    path = data.draw(st.sampled_from(_paths(doc)), label="path")
    node = doc
    for key in path[:-1]:
        node = node[key]
    if data.draw(st.booleans(), label="remove") and isinstance(node, dict):
        del node[path[-1]]
    else:
        node[path[-1]] = data.draw(json_values, label="value")
    plan = tmp_path / "PLAN.json"
    plan.write_text(json.dumps(doc, allow_nan=True))
    out = tmp_path / "m.plan"
    out.unlink(missing_ok=True)
    code = main(["export", str(plan), "--format", "plan", "-o", str(out)])
    lines = _outcome(capsys)
    assert code in (0, 2, 3), (code, lines)
    assert (code == 0) == out.exists() and (code == 0) == (not lines)
    assert not list(tmp_path.glob("*.part"))


@FUZZ
@given(url=st.text(max_size=40))
def test_any_connect_string_is_taken_only_in_a_documented_form(url) -> None:
    """check_url accepts exactly SCHEME:HOST:PORT (port 1-65535), a serial device or a MAVSDK URL, and refuses
    anything else in one line."""
    try:
        check_url(url)
    except FuseplanError as e:
        assert "\n" not in str(e) and str(e).startswith("--connect ")
        return
    if url.startswith("/dev/") or url.upper().startswith("COM"):
        return
    scheme, _, rest = url.partition("://") if "://" in url else url.partition(":")
    host, _, port = rest.rpartition(":")
    assert ("://" in url or scheme in NETWORK_SCHEMES) and host and 0 < int(port) < 65536


bad_seconds = st.one_of(st.floats(max_value=0.0), st.just(math.inf), st.just(-math.inf), st.just(math.nan))


@FUZZ
@given(option=st.sampled_from(["--heartbeat-timeout", "--replan-budget"]), value=bad_seconds)
def test_a_bad_number_of_seconds_is_refused_before_planning(tmp_path, capsys, option, value) -> None:
    report = tmp_path / "report"
    code = main(["fly", str(STATIC), "--connect", "tcp:127.0.0.1:5760", f"{option}={value!r}", "--report",
                 str(report), "-q"])  # OPTION=VALUE: argparse takes a bare "-inf" for an option
    lines = _outcome(capsys)
    assert code == 2 and len(lines) == 1 and option in lines[0], lines
    assert not report.exists()
