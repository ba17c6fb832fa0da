"""`fuseplan fly` against a hostile autopilot (issue 33): the built-in simulator behind a proxy that misbehaves in
one way per test (tests/hostile.py), real TCP on 127.0.0.1, the real CLI. Each test asserts the documented
outcome: the exit code, one ``fuseplan:`` line and no traceback, and that the vehicle was never armed with a
mission that had not been verified."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hostile import running

from companion.cli import main

ROOT = Path(__file__).resolve().parents[3]
STATIC = ROOT / "sitl_scenarios" / "rescue_static.toml"


@pytest.fixture(scope="module")
def plan_json(tmp_path_factory, static_plan_doc) -> Path:
    """One PLAN.json of the static rescue, flown by every test (so each checks it again, as fly does)."""
    out = tmp_path_factory.mktemp("plan") / "PLAN.json"
    out.write_text(json.dumps(static_plan_doc()))
    return out


def _fly(plan: Path, port: int, report: Path, *extra: str) -> int:
    return main(["fly", str(plan), "--connect", f"tcp:127.0.0.1:{port}", "--arm", "--report", str(report), "-q",
                 *extra])


def _events(report: Path) -> list[dict]:
    return [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]


def _our_lines(err: str) -> list[str]:
    """stderr's own lines (the log's WARNING lines aside), after checking there is no traceback at all."""
    assert "Traceback" not in err, err
    return [line for line in err.splitlines() if line.startswith("fuseplan")]


def _stored(left: dict) -> list[tuple]:
    return [(it.seq, it.command, it.x, it.y, round(it.z, 2)) for it in left["mission"]]


def _armed_only_with_the_verified_mission(record, left: dict, report: Path) -> None:
    """Every time the vehicle was armed, it held exactly the mission the companion verified (and still holds it)."""
    names = [e["event"] for e in _events(report)]
    assert names.index("upload_verified") < names.index("armed")
    assert record.armed_with and all(m == record.armed_with[0] for m in record.armed_with)
    assert record.armed_with[0][1:] == _stored(left)[1:]  # item 0 is home, which the autopilot sets itself


def test_a_link_cut_mid_upload_waits_for_the_reconnect_and_uploads_again(plan_json, tmp_path, capsys) -> None:
    """TCP closed as item 3 arrives: a link fault, not a refusal. The companion waits for the reconnect, uploads
    the whole mission again, verifies it, and only then arms and flies (exit 0)."""
    report = tmp_path / "r"
    with running(STATIC, "disconnect_mid_upload") as (port, record, left):
        code = _fly(plan_json, port, report)
    assert code == 0, capsys.readouterr().err
    assert record.cut_at_item == 3 and record.sessions >= 2
    events = _events(report)
    names = [e["event"] for e in events]
    failed = next(e for e in events if e["event"] == "upload_failed")
    assert failed["retrying"] and failed["attempt"] == 1
    assert names.index("upload_failed") < names.index("waiting_for_link") < names.index("link_back") \
        < names.index("upload_verified")
    _armed_only_with_the_verified_mission(record, left, report)
    assert _our_lines(capsys.readouterr().err) == []


def test_an_item_changed_during_an_outage_is_found_and_the_flight_ends_5(plan_json, tmp_path, capsys) -> None:
    """In flight the link goes silent for 7 s (TCP half-open, connects refused) while another ground station
    moves an item of the mission. Whoever notices the gap first, the mission is read back when the link is back,
    the change is found, and fly stops supervising: exit 5 (the flight had started), one line, a whole report."""
    report = tmp_path / "r"

    def cut(sim, record) -> bool:
        if sim.mission_time is None or sim.mission_time < 15.0:
            return False
        from hostile import change_item_in_outage

        change_item_in_outage(sim, record, len(sim.mission) - 2, 7.0)
        return True

    with running(STATIC, "pass", speedup=4.0, during=cut) as (port, record, left):
        code = _fly(plan_json, port, report)
    err = _our_lines(capsys.readouterr().err)
    assert code == 5, err
    assert len(err) == 1 and "changed during a link outage" in err[0], err
    assert record.changed_item is not None
    events = _events(report)
    names = [e["event"] for e in events]
    assert "resync_mismatch" in names and names.index("link_restored") < names.index("resync_mismatch")
    mismatch = next(e for e in events if e["event"] == "resync_mismatch")
    assert mismatch["seq"] == record.changed_item
    flight = json.loads((report / "flight.json").read_text())
    assert flight["completed"] is False and "changed during a link outage" in flight["reason"]
    assert (report / "track.png").exists()
    assert names.index("upload_verified") < names.index("armed")
    armed, now = record.armed_with[0], _stored(left)
    assert [a for a, b in zip(armed, now) if a != b] == [armed[record.changed_item]]  # only the changed item


def test_a_rogue_autopilot_that_speaks_first_is_never_silently_followed(plan_json, tmp_path, capsys) -> None:
    """System 2 sends HEARTBEATs a second before the real autopilot (system 1) does. Without --target-system the
    companion refuses before any upload (exit 4, one line naming both); nothing is uploaded, nothing armed."""
    report = tmp_path / "r"
    with running(STATIC, "rogue_first") as (port, record, left):
        code = _fly(plan_json, port, report)
    err = _our_lines(capsys.readouterr().err)
    assert code == 4, err
    assert len(err) == 1 and "more than one autopilot" in err[0] and "--target-system" in err[0], err
    assert record.armed_with == [] and left["armed"] is False
    assert len(left["mission"]) == 1  # home only: nothing uploaded
    assert "upload_start" not in [e["event"] for e in _events(report)]


def test_with_target_system_the_rogue_is_ignored_and_the_flight_completes(plan_json, tmp_path, capsys) -> None:
    report = tmp_path / "r"
    with running(STATIC, "rogue_first") as (port, record, left):
        code = _fly(plan_json, port, report, "--target-system", "1")
    assert code == 0, capsys.readouterr().err
    other = next(e for e in _events(report) if e["event"] == "other_autopilots")
    assert other["systems"] == [2] and other["target"] == 1 and other["pinned"] is True
    _armed_only_with_the_verified_mission(record, left, report)


def test_a_request_beyond_the_count_is_ignored(plan_json, tmp_path, capsys) -> None:
    """The 'autopilot' asks for item count + 5 of every upload: no such item is sent, the upload goes on, is
    verified, and the flight completes (exit 0)."""
    report = tmp_path / "r"
    with running(STATIC, "request_beyond_count") as (port, record, left):
        code = _fly(plan_json, port, report)
    assert code == 0, capsys.readouterr().err
    assert record.injected >= 1 and record.items_beyond == 0  # asked, never answered with a made-up item
    _armed_only_with_the_verified_mission(record, left, report)


def test_a_count_of_65535_on_readback_is_refused_quickly_and_never_armed(plan_json, tmp_path, capsys) -> None:
    """Every MISSION_COUNT the autopilot sends says 65535: the backup cannot be read, no readback ever matches,
    the restore cannot be verified either. Exit 4 with one line saying so; the vehicle is never armed."""
    import time

    report = tmp_path / "r"
    t0 = time.monotonic()
    with running(STATIC, "count_65535") as (port, record, left):
        code = _fly(plan_json, port, report)
    err = _our_lines(capsys.readouterr().err)
    assert code == 4, err
    assert len(err) == 1 and "do not start it" in err[0], err
    assert record.rewritten >= 3 and record.armed_with == [] and left["armed"] is False
    assert time.monotonic() - t0 < 30.0  # not item by item through 65535 of them (2.5-4 s here)


def test_garbage_after_every_heartbeat_does_not_stop_the_flight(plan_json, tmp_path, capsys) -> None:
    report = tmp_path / "r"
    with running(STATIC, "garbage_after_heartbeat") as (port, record, left):
        code = _fly(plan_json, port, report)
    assert code == 0, capsys.readouterr().err
    assert record.injected >= 5
    _armed_only_with_the_verified_mission(record, left, report)


def test_a_failure_after_arming_is_a_flight_not_completed_exit_5_with_a_whole_report(plan_json, tmp_path,
                                                                                      capsys) -> None:
    """The vehicle is armed, then MISSION_START is denied: the flight had begun (armed in AUTO, an ArduPlane may be
    taking off), so it is not a refusal before the flight (4) but a flight not completed (5), one line, and the
    report is the flight's (its track and flown clearance), not a stub."""
    report = tmp_path / "r"
    with running(STATIC, "deny_start") as (port, record, left):
        code = _fly(plan_json, port, report)
    err = _our_lines(capsys.readouterr().err)
    assert code == 5, err
    assert len(err) == 1 and "NOT completed" in err[0] and "after the start" in err[0], err
    assert record.injected >= 1 and record.armed_with
    flight = json.loads((report / "flight.json").read_text())
    assert flight["completed"] is False and "after the start" in flight["reason"]
    assert "min_static_clearance_m" in flight and (report / "track.png").exists()
    _armed_only_with_the_verified_mission(record, left, report)
