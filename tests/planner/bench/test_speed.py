"""``fuseplan bench speed`` (issue 16) on a tiny budget, and the plain-numpy SPSO reference it times.

No wall-clock asserts: the machine is shared. These check structure (both kernels, the ratio, broad phase on and
off, the reference row, the latency table) and reproducible numbers (same seed → same cost).
"""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from planner.bench import reference_spso as ref
from planner.bench import speed
from planner.bench.runner import SCENARIO_DIR
from planner.errors import FuseplanError
from planner.world.geometry import segment_point_distance_2d
from planner.world.scenario import load_scenario

TINY = dataclasses.replace(
    speed.QUICK, runs=2, scaling_runs=1, latency_seeds=2,
    budget_overrides=("planner.pso.n_pop=20", "planner.pso.max_iter=4", "planner.aco.max_iter=2"),
    scaling_base={"n_pop": 20, "max_iter": 4, "n_waypoints": 4, "obstacles": 10},
    scaling_levels={"n_pop": (10, 20), "max_iter": (2, 4), "n_waypoints": (3, 4), "obstacles": (5, 10)})


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("speed")
    records, reused = speed.run(TINY, out)
    return out, records, reused


def test_every_part_runs_and_each_record_names_its_kernel_and_broad_phase(tiny_run) -> None:
    _, records, reused = tiny_run
    assert reused == 0 and len(records) == speed.n_jobs(TINY)
    head = [r for r in records if r["part"] == "headline"]
    assert {r["kernel"] for r in head} == {"compiled", "numpy"}  # as planner.kernel.chosen() saw it in the worker
    assert len(head) == TINY.runs * len(speed.HEADLINE) * 2
    scal = [r for r in records if r["part"] == "scaling"]
    assert {(r["kernel"], r["broad_phase"]) for r in scal} == set(TINY.scaling_arms)
    assert {r["kernel"] for r in records if r["part"] == "reference"} == {"reference"}
    lat = [r for r in records if r["part"] == "latency"]
    assert {r["load"] for r in lat} == {0, TINY.hog} and all(r["budget_s"] == TINY.budget_s for r in lat)
    assert all(r["overrun_s"] == pytest.approx(r["time_s"] - r["budget_s"]) for r in lat)
    # the headline budget reached the plans: nPop 20 × (4 + 1) evaluations for the SPSO row
    spso = [r for r in head if r["key"] == "spso_table6"]
    assert {r["evaluations"] for r in spso} == {20 * 5} and {r["n_pop"] for r in spso} == {20}


def test_costs_are_reproducible(tiny_run, tmp_path) -> None:
    _, records, _ = tiny_run
    rep = speed.reproducible(records)
    assert rep["same_kernel"] and rep["groups"] > 0
    for key in ("spso_table6", "fusion_default"):  # repeats of one seed: one cost, bit for bit
        for k in ("compiled", "numpy"):
            assert len({r["cost"] for r in records if r["key"] == key and r["kernel"] == k}) == 1
    for key in {r["key"] for r in records if r["part"] == "scaling"}:  # broad phase on and off: the same cost
        on_off = {r["cost"] for r in records if r["key"] == key and r["kernel"] == "compiled"}
        assert len(on_off) == 1
    again, _ = speed.run(dataclasses.replace(TINY, parts=("headline", "reference")), tmp_path)  # a fresh run
    first = {r["id"]: r["cost"] for r in records}
    assert all(first[r["id"]] == r["cost"] for r in again)


def test_report_has_headline_first_with_both_kernels_the_ratio_and_the_reference(tiny_run) -> None:
    out, records, _ = tiny_run
    files = speed.report(out, records, TINY)
    assert [f.name for f in files] == ["speed.md", "speed.csv", "speed_runs.csv", "speed.png"]
    assert all(f.stat().st_size > 0 for f in files)
    md = (out / "speed.md").read_text()
    assert md.index("## Headline") < md.index("## Scaling") < md.index("## Replan latency")
    assert "| row | compiled | numpy | ratio |" in md
    assert "fuseplan bench speed" in md and "cores" in md and "serially" in md
    head = md[md.index("## Headline"):md.index("## Scaling")]
    assert "SPSO, Table 6 (nPop 20 × 4 iterations), rescue_static" in head
    assert "default plan (fusion, as shipped), large_obstacle_field" in head
    assert "plain-numpy SPSO reference" in head and "ours compiled" in head
    scal = md[md.index("## Scaling"):md.index("## Replan latency")]
    assert "compiled, broad phase on (s)" in scal and "compiled, broad phase off (s)" in scal
    assert "| broad off ÷ on | numpy ÷ compiled (on) |" in scal
    lat = md[md.index("## Replan latency"):]
    for name in ("rescue_dynamic", "crossing_traffic"):
        assert f"| {name} | idle |" in lat and f"| {name} | cpu_hog(1) |" in lat
    csv = (out / "speed.csv").read_text().splitlines()
    assert "ratio" in csv[0].split(",") and any(line.startswith("reference,") for line in csv)


def test_a_second_run_resumes_and_other_settings_are_refused(tiny_run) -> None:
    out, records, _ = tiny_run
    again, reused = speed.run(TINY, out)
    assert reused == len(records) and again == records
    with pytest.raises(FuseplanError, match="other settings"):
        speed.run(dataclasses.replace(TINY, seed_base=7), out)


def test_jsonl_records_are_json_lines(tiny_run) -> None:
    out, records, _ = tiny_run
    lines = (out / "speed.jsonl").read_text().splitlines()
    assert {json.loads(line)["id"] for line in lines} == {r["id"] for r in records}


def test_command_line_runs_the_chosen_parts(tmp_path) -> None:
    from companion.cli import main

    assert main(["bench", "speed", "--quick", "--parts", "headline,reference", "--runs", "1", "-o", str(tmp_path),
                 "--set", "planner.pso.n_pop=20", "--set", "planner.pso.max_iter=3", "-q"]) == 0
    md = (tmp_path / "speed.md").read_text()
    assert "--parts headline,reference" in md and "## Headline" in md and "## Scaling" not in md
    assert "nPop 20 × 3" in md and (tmp_path / "speed.png").read_bytes()[:4] == b"\x89PNG"
    assert main(["bench", "speed", "--parts", "nope", "-o", str(tmp_path), "-q"]) == 2


def test_settings_from_the_command_line() -> None:
    s = speed.settings_from(False, None, 2000, None, ["hazard.d_coll=12"], "headline,latency", None)
    assert s.workers == 1 and s.runs == 5 and s.latency_seeds == 20 and s.parts == ("headline", "latency")
    assert "--parts headline,latency" in s.command() and "--set 'hazard.d_coll=12'" in s.command()
    assert speed.FULL.command() == ("fuseplan bench speed --runs 5 --seed-base 2000 --workers 1 "
                                    "--latency-seeds 20")
    with pytest.raises(FuseplanError, match="--parts"):
        speed.settings_from(False, None, 2000, None, [], "headline,nope", None)
    with pytest.raises(FuseplanError, match=">= 1"):
        speed.settings_from(True, 0, 2000, None, [], None, None)


def test_full_default_is_the_issue_16_headline() -> None:
    groups = {(part, load): js for part, load, js in speed.jobs(speed.FULL)}
    head = groups[("headline", 0)]
    assert {j.kernel for j in head} == {"compiled", "numpy"} and {j.repeat for j in head} == set(range(5))
    spso = load_scenario(head[0].scenario, head[0].overrides)
    assert (spso.planner.algorithm, spso.planner.pso.n_pop, spso.planner.pso.max_iter) == ("spso", 500, 200)
    assert not spso.planner.roadmap.enabled and spso.planner.pso.stagnation_iters >= 200
    assert len(groups[("latency", 0)]) == len(groups[("latency", 1)]) == 2 * 20
    assert all(j.budget_s == 0.15 for j in groups[("latency", 1)])


# --- the plain-numpy SPSO reference ------------------------------------------------------------------------------
WORLD = ref.ReferenceWorld.of(load_scenario(SCENARIO_DIR / "rescue_static.toml"))
SMALL = ref.ReferenceConfig(n_pop=100, max_iter=60)


def test_reference_finds_a_route_clear_of_the_cylinders() -> None:
    r = ref.solve(WORLD, SMALL, np.random.default_rng(3))
    assert np.isfinite(r.cost) and r.violations == 0 and r.cost < SMALL.penalty
    assert r.path.shape == (SMALL.n_waypoints + 2, 3)
    np.testing.assert_array_equal(r.path[0], WORLD.start)
    np.testing.assert_array_equal(r.path[-1], WORLD.goal)
    a, b = r.path[:-1], r.path[1:]
    cx, cy, cr = WORLD.cylinders.T  # an independent check: the planner's own segment–axis distance
    d = segment_point_distance_2d(a[:, 0, None], a[:, 1, None], b[:, 0, None], b[:, 1, None], cx, cy) - cr
    assert d.min() >= WORLD.d_coll
    assert np.all((r.path[1:-1, 2] >= WORLD.z_min) & (r.path[1:-1, 2] <= WORLD.z_max))
    assert r.evaluations == SMALL.n_pop * (SMALL.max_iter + 1) and len(r.history) == SMALL.max_iter + 1
    assert np.all(np.diff(r.history) <= 0)  # the best cost never gets worse


def test_reference_is_deterministic() -> None:
    a = ref.solve(WORLD, SMALL, np.random.default_rng(11))
    b = ref.solve(WORLD, SMALL, np.random.default_rng(11))
    assert a.cost == b.cost and a.terms == b.terms
    np.testing.assert_array_equal(a.path, b.path)
    np.testing.assert_array_equal(a.history, b.history)
    c = ref.solve(WORLD, SMALL, np.random.default_rng(12))
    assert not np.array_equal(a.path, c.path)


def test_reference_cost_by_hand() -> None:
    """One straight particle: J1 is the path length; a leg through a cylinder is one flat penalty."""
    world = dataclasses.replace(WORLD, cylinders=np.array([[500.0, 500.0, 50.0]]))
    cfg = ref.ReferenceConfig(n_waypoints=2)
    d = world.goal - world.start
    r = float(np.linalg.norm(d)) / 2
    x = np.array([[[r, 0.0, np.arctan2(d[1], d[0])]] * 2])
    j, viol = ref.terms(ref.decode(x, world), world)
    assert j[0, 0] == pytest.approx(np.linalg.norm(d)) and viol[0] == 2  # both legs touch the cylinder at (500, 500)
    assert ref.cost(x, world, cfg)[0] == pytest.approx(np.dot(j[0], cfg.weights) + 2 * cfg.penalty)


# --- the polygons part: prisms against cylinders of the same size ---------------------------------------------------
def test_polygon_field_is_the_cylinder_field_drawn_as_polygons(tiny_run) -> None:
    f = speed.FieldSettings(count=30)
    for roofed in (False, True):
        cyl = speed.obstacle_field("cylinders", roofed, 7, f).cylinders
        pri = speed.obstacle_field("prisms", roofed, 7, f).prisms
        assert len(cyl) == len(pri) == 30 and np.array_equal(pri.ceiling, cyl.top)
        assert np.all(np.isfinite(pri.ceiling)) == roofed and np.all(np.isneginf(pri.floor))
        for k in range(30):  # each polygon lies in its cylinder's disc, at 0.6–1 × its radius
            d = np.hypot(*(pri.polygon(k) - [cyl.x[k], cyl.y[k]]).T)
            assert 0.6 * cyl.radius[k] - 1e-9 <= d.min() and d.max() <= cyl.radius[k] + 1e-9
    _, records, _ = tiny_run
    rows = speed.polygon_rows(records)
    assert [r["key"] for r in rows] == ["unlimited", "roofed"]
    assert all(r["ratio"] == pytest.approx(r["prisms_us"] / r["cylinders_us"]) and r["prism_collisions"] > 0
               for r in rows)
    md = speed.markdown(records, TINY)
    assert "## Polygon prisms against cylinders" in md and "| unlimited |" in md and "| roofed |" in md
