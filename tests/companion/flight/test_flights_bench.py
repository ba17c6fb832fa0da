"""`fuseplan bench flights`: one real flight of crossing_traffic on the built-in simulator end to end (files, numbers
equal to the flight's own flight.json, a second run that flies nothing), the track-error measures on a synthetic
track, and the one-line refusal of a backend whose autopilot is not there."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from companion.cli import main
from companion.flight import flights_bench as fb

ARGS = ["bench", "flights", "--backend", "sim", "--runs", "1", "--scenarios", "crossing_traffic"]


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One sim flight of crossing_traffic with replanning, as `fuseplan bench flights` flies it (about 15 s)."""
    out = tmp_path_factory.mktemp("flights")
    assert main([*ARGS, "-o", str(out), "-q"]) == 0
    return out


def test_the_bench_writes_its_files_with_flight_json_s_numbers(bench: Path) -> None:
    records = [json.loads(line) for line in (bench / "flights.jsonl").read_text().splitlines()]
    assert len(records) == 1
    rec = records[0]
    assert (rec["backend"], rec["scenario"], rec["replanning"], rec["run"]) == ("sim", "crossing_traffic", True, 1)
    report = bench / rec["report"]
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    for key in ("completed", "min_static_clearance_m", "nearest_obstacle", "min_traffic_separation_m",
                "nearest_traffic", "min_separation_m", "replans", "replan_attempts", "d_coll_m", "track_source"):
        assert rec[key] == flight[key], key
    assert rec["holds"] == sum(e["event"] == "hold" for e in events)
    assert rec["static_kept"] == (flight["min_static_clearance_m"] >= flight["d_coll_m"])
    assert rec["traffic_kept"] == (flight["min_traffic_separation_m"] >= flight["d_coll_m"])
    assert rec["exit"] == (0 if flight["completed"] and flight["flown_safe"] else 6 if not flight["flown_safe"] else 5)
    assert set(flight["min_separation_m"]) == {"ga-left", "ga-right"}  # both intruders flew
    err = fb.track_errors(events, json.loads((report / "PLAN.json").read_text()))
    assert err.reference == "live mission" and err.samples > 20
    assert (rec["xtrack_p50_m"], rec["xtrack_p95_m"], rec["climb_error_p50_m"], rec["climb_error_p95_m"]) == (
        err.xtrack_p50, err.xtrack_p95, err.climb_p50, err.climb_p95)
    assert 0 <= rec["xtrack_p50_m"] <= rec["xtrack_p95_m"] and 0 <= rec["climb_error_p50_m"] <= rec["climb_error_p95_m"]

    runs = list(csv.DictReader((bench / "flights_runs.csv").open()))
    assert len(runs) == 1 and float(runs[0]["min_static_clearance_m"]) == flight["min_static_clearance_m"]
    assert int(runs[0]["replans"]) == flight["replans"] and runs[0]["nearest_obstacle"] == flight["nearest_obstacle"]
    rows = list(csv.DictReader((bench / "flights.csv").open()))
    assert len(rows) == 1 and rows[0]["flights"] == "1" and rows[0]["completed"] == str(int(flight["completed"]))
    assert float(rows[0]["min_static_clearance_m_min"]) == round(flight["min_static_clearance_m"], 2)
    assert float(rows[0]["min_traffic_separation_m_median"]) == round(flight["min_traffic_separation_m"], 2)
    md = (bench / "flights.md").read_text()
    assert "fuseplan bench flights --backend sim --runs 1 --scenarios crossing_traffic" in md
    assert "Hosts: " in md and "| sim | crossing_traffic | on | 1 |" in md
    assert "the last mission verified before it" in md
    live = [r for r in flight["replan_log"] if r["latency_s"] is not None]
    assert rec["replan_latency_s"] == [r["latency_s"] for r in live] and len(live) == flight["replans"]
    assert rec["partial_writes"] == sum(r["upload_path"].startswith("partial") for r in live)
    if live:  # the latency table pools the flights' replans made live
        [row] = fb.latency_rows([rec])
        assert row["n"] == len(live) and row["median"] == pytest.approx(np.median(rec["replan_latency_s"]))
        assert f"| sim | crossing_traffic | {len(live)} | {row['median']:.3f} / " in md


def test_a_second_run_with_the_same_output_flies_nothing(bench: Path, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    def no_flight(*_args: object) -> dict:
        raise AssertionError("flew again")

    before = (bench / "flights.jsonl").read_text()
    monkeypatch.setattr(fb, "fly_one", no_flight)
    assert main([*ARGS, "-o", str(bench)]) == 0
    assert "0 to fly, 1 reused" in capsys.readouterr().err
    assert (bench / "flights.jsonl").read_text() == before
    # other settings for the same flights: refused, nothing flown
    assert main([*ARGS, "-o", str(bench), "--set", "hazard.d_coll=12"]) == 2
    assert "flown with other settings" in capsys.readouterr().err
    # nor under load: the busy processes are part of what a flight was flown with, and of the command reported
    assert main([*ARGS, "-o", str(bench), "--cpu-hog", "1"]) == 2
    assert "flown with other settings" in capsys.readouterr().err
    loaded = fb.FlightsSettings("sim", 1, (Path("crossing_traffic.toml"),), False, bench, hog=1)
    assert "--cpu-hog 1" in loaded.command()
    # a record written by an older version is read again from its report directory, not flown again
    old = json.loads(before)
    for key in ("version", "replan_latency_s", "partial_writes"):
        old.pop(key)
    (bench / "flights.jsonl").write_text(json.dumps(old) + "\n")
    assert main([*ARGS, "-o", str(bench)]) == 0
    assert "0 to fly, 1 reused" in capsys.readouterr().err
    assert list(csv.DictReader((bench / "flights_runs.csv").open()))[0]["partial_writes"] != ""  # read again
    (bench / "flights.jsonl").write_text(before)


def test_cross_track_and_climb_error_on_a_synthetic_track() -> None:
    route = np.array([[0.0, 0.0, 100.0], [1000.0, 0.0, 200.0], [1000.0, 1000.0, 200.0]])  # climbs 100 m, turns
    pts = np.array([[500.0, 5.0, 153.0], [-20.0, 0.0, 100.0], [1003.0, 600.0, 190.0], [200.0, -8.0, 110.0]])
    dist, z = fb.project(pts, route)
    np.testing.assert_allclose(dist, [5.0, 20.0, 3.0, 8.0])
    np.testing.assert_allclose(z, [150.0, 100.0, 200.0, 120.0])  # the route's altitude at the same along-track point

    later = route + [0.0, 50.0, 0.0]  # a replanned route, live from t = 10
    track = np.array([[5.0, 500.0, 5.0, 153.0], [12.0, 500.0, 5.0, 153.0]])
    xtrack, climb = fb.route_errors(track, [(0.0, route), (10.0, later)])
    np.testing.assert_allclose(xtrack, [5.0, 45.0])
    np.testing.assert_allclose(climb, [3.0, 3.0])

    # from events: the take-off item and the points before the route's start are left out, as are ground points
    mission = [[1, 0.0, 0.0, 100.0], [3, 0.0, 0.0, 100.0], [4, 1000.0, 0.0, 200.0], [5, 1000.0, 1000.0, 200.0]]
    events = [{"t": 0.0, "event": "mission", "items": mission},
              {"t": 1.0, "event": "position", "x": -300.0, "y": 0.0, "z": 40.0},  # climb-out: not counted
              {"t": 2.0, "event": "reached", "seq": 3},
              *({"t": 2.0 + k, "event": "position", "x": 100.0 * k, "y": 4.0, "z": 100.0 + 10.0 * k - 2.0}
                for k in range(1, 10)),
              {"t": 11.0, "event": "reached", "seq": 4},
              {"t": 11.5, "event": "position", "x": 1010.0, "y": 500.0, "z": 200.0},
              {"t": 12.0, "event": "finished"},
              {"t": 13.0, "event": "position", "x": 0.0, "y": 900.0, "z": 200.0}]  # after the end: not counted
    err = fb.track_errors(events, {})
    assert err.samples == 10 and err.reference == "live mission"
    assert err.xtrack_p50 == 4.0 and err.xtrack_p95 == pytest.approx(np.percentile([4.0] * 9 + [10.0], 95), abs=0.01)
    assert err.climb_p50 == 2.0 and err.climb_p95 == pytest.approx(np.percentile([2.0] * 9 + [0.0], 95), abs=0.01)
    # no mission record: the planned trajectory, from the first item reached
    plan = {"trajectory": {"points": route.tolist()}}
    err = fb.track_errors([e for e in events if e["event"] != "mission"], plan)
    assert err.reference == "planned trajectory" and err.samples == 10 and err.xtrack_p50 == 4.0


@pytest.mark.parametrize("backend", ["sitl-plane", "sitl-copter", "px4"])
def test_a_backend_whose_autopilot_is_missing_is_refused_in_one_line(
        backend: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.delenv("FUSEPLAN_SITL_DIR", raising=False)
    monkeypatch.delenv("FUSEPLAN_PX4_DIR", raising=False)
    assert main(["bench", "flights", "--backend", backend, "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"fuseplan: error: bench flights --backend {backend}: ")
    assert ("PX4 SITL not found" if backend == "px4" else "ArduPilot SITL not found") in err[0]
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["bench", "flights", "--backend", backend, "--sitl-dir", str(empty), "-o", str(tmp_path / "o")]) == 2
    assert "no executable" in capsys.readouterr().err
    assert not (tmp_path / "out").exists() and not (tmp_path / "o").exists()  # refused before anything was made
