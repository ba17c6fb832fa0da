"""Deadlines as deadlines (issue 16): a budgeted search stops *before* an iteration that would overrun its budget,
predicted from the iterations it has measured. Timing here is made deterministic: an injected clock advanced by
the evaluation, or a real evaluation slowed by a fixed busy-wait that dominates everything else the loop does (so
the margins below are fractions of that delay, not guesses at the machine's speed)."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np
import pytest

from planner.deadline import Deadline
from planner.plan import plan, problem_from_scenario
from planner.problem import Evaluation, PlanningProblem
from planner.search.aco import AntColony, lattice_setup_s
from planner.search.encoding import make_encoding
from planner.search.spso import SphericalPSO
from planner.search.swarm import initial_swarm, run_swarm
from planner.search.termination import WallClock
from planner.world.scenario import load_scenario

SCENARIOS = Path(__file__).resolve().parents[3] / "sitl_scenarios"


class FakeClock:
    """Seconds that pass only when told to."""

    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


@dataclasses.dataclass(frozen=True, eq=False)
class SlowProblem(PlanningProblem):
    """A planning problem whose every evaluate() takes ``delay_s`` longer: a busy-wait on the real clock, or,
    with ``fake`` set, a step of that injected clock."""

    delay_s: float = 0.025
    fake: FakeClock | None = None

    def evaluate(self, paths: np.ndarray) -> Evaluation:
        if self.fake is not None:
            self.fake.t += self.delay_s
        else:
            end = time.perf_counter() + self.delay_s
            while time.perf_counter() < end:
                pass
        return super().evaluate(paths)


def slow(problem: PlanningProblem, delay_s: float, fake: FakeClock | None = None) -> SlowProblem:
    kw = {f.name: getattr(problem, f.name) for f in dataclasses.fields(problem) if f.init}
    return SlowProblem(**kw, delay_s=delay_s, fake=fake)


@pytest.fixture(scope="module", autouse=True)
def warm() -> None:
    """Load (or compile) the cost kernel and run every phase once, so no test times a first call."""
    sc = load_scenario(SCENARIOS / "rescue_dynamic.toml", ["planner.roadmap.enabled=true", "planner.pso.n_pop=30",
                                                          "planner.pso.max_iter=3", "planner.aco.max_iter=2"])
    plan(problem_from_scenario(sc), sc.planner, np.random.default_rng(0))


@pytest.fixture(scope="module")
def static():
    sc = load_scenario(SCENARIOS / "rescue_static.toml", ["planner.pso.n_pop=30"])
    return sc, problem_from_scenario(sc)


def test_a_deadline_shares_what_is_left_and_without_a_budget_is_never_out_of_time() -> None:
    """One object for a budget (issue 34): what is left, a share of it from now (never past the parent), a reserve
    kept out; ``never()`` is infinite, so the same code runs without a budget."""
    clock = FakeClock()
    d = Deadline.after(1.0, clock)
    assert d.bounded and d.remaining() == 1.0 and d.affords(1.0) and not d.affords(1.01)
    clock.t += 0.4
    assert d.elapsed() == pytest.approx(0.4) and d.remaining() == pytest.approx(0.6)
    half = d.share(0.5)  # from now, half of the 0.6 s left
    assert half.start == clock.t and half.seconds == pytest.approx(0.3) and half.remaining() == pytest.approx(0.3)
    assert d.share(2.0).seconds == pytest.approx(0.6)  # a share never ends after its parent
    assert d.minus(0.1).remaining() == pytest.approx(0.5) and d.minus(5.0).seconds == 0.0
    clock.t += 1.0  # overrun: nothing left to share
    assert d.remaining() == pytest.approx(-0.4) and d.share(0.5).seconds == 0.0 and not d.affords(0.0)
    free = Deadline.never(clock)
    assert not free.bounded and free.remaining() == math.inf and free.affords(1e9)
    assert free.share(0.0) is free and not free.minus(1.0).bounded and not Deadline.after(None, clock).bounded


def test_wall_clock_predicts_the_next_iteration_from_the_longest_recent_one() -> None:
    clock = FakeClock()
    wall = WallClock(Deadline.after(1.0, clock).minus(0.1), window=3, first_s=0.05)  # 0.1 s kept in reserve
    assert wall.predicted_s() == 0.05 and not wall.done()  # the prior, before any lap
    for lap in (0.1, 0.3, 0.1, 0.1):
        clock.t += lap
        wall.lap()
    assert wall.predicted_s() == pytest.approx(0.3)  # the 0.3 s lap is one of the last three
    assert wall.deadline.elapsed() == pytest.approx(0.6) and not wall.done()  # 0.6 + 0.3 + 0.1 reserve = 1.0: fits
    clock.t += 0.1
    wall.lap()  # the 0.3 s lap ages out of the window
    assert wall.predicted_s() == pytest.approx(0.1)
    assert not wall.done()  # 0.7 + 0.1 + 0.1
    clock.t += 0.15
    assert wall.done()  # 0.85 + 0.1 + 0.1 > 1.0
    assert wall.affords(0.05) and not wall.affords(0.06)


def test_run_swarm_on_an_injected_clock_stops_before_the_iteration_that_would_overrun(static) -> None:
    """Each evaluation advances the clock 25 ms: the initial one ends at 25 ms, iteration k at 25 (k + 1) ms.
    Against 140 ms the search runs 4 iterations (ending at 125 ms; a fifth would end at 150 ms). The old check
    after each iteration ran that fifth one and overran by 10 ms."""
    sc, prob = static
    clock = FakeClock()
    problem = slow(prob, 0.025, clock)
    cfg = sc.planner.pso
    enc = make_encoding(problem, cfg)
    rng = np.random.default_rng(0)

    def step(it: int, st) -> np.ndarray:
        return np.clip(st.x + 0.01 * (enc.hi - enc.lo) * rng.standard_normal(st.x.shape), enc.lo, enc.hi)

    x0 = initial_swarm(enc, rng, cfg.n_pop)
    res = run_swarm("test", problem, cfg, enc, x0, step, Deadline.after(0.14, clock))
    assert res.stop_reason == "timeout" and res.iterations == 4
    assert res.time_s == pytest.approx(0.125) and len(res.history) == 5
    spent = run_swarm("test", problem, cfg, enc, x0, step, Deadline.after(0.02, clock))
    assert spent.iterations == 0 and spent.stop_reason == "timeout"  # the initial evaluation used it all
    free = run_swarm("test", problem, dataclasses.replace(cfg, max_iter=7), enc, x0, step, Deadline.never(clock))
    assert free.iterations == 7 and free.stop_reason == "max_iterations"  # no budget: nothing timed


def test_spso_with_a_slow_evaluation_ends_within_its_budget(static) -> None:
    """30 ms per evaluation, budget 160 ms: the initial evaluation and four iterations end at 150 ms; a fifth
    would end at 180 ms (the old stop ran it). The margin is half an evaluation: what the loop does besides
    evaluating is a millisecond or two."""
    sc, prob = static
    delay, budget = 0.030, 0.160
    res = SphericalPSO(sc.planner.pso).run(slow(prob, delay), np.random.default_rng(1),
                                              deadline=Deadline.after(budget))
    assert res.stop_reason == "timeout"
    assert res.iterations in (3, 4)  # 3 when the machine stretched an iteration by more than 2 ms
    assert res.time_s <= budget + 0.5 * delay


def test_aco_with_a_slow_evaluation_ends_within_its_budget(static) -> None:
    """The colony's first iteration is predicted by the seed route's evaluation, later ones by the longest
    recent iteration; with 30 ms evaluations it stops before the one that would end past its budget (the
    lattice's set-up, tens of milliseconds, comes first). A budget its set-up cannot fit returns the seed."""
    sc, prob = static
    delay = 0.030
    route = prob.start + np.linspace(0.0, 1.0, sc.planner.pso.n_waypoints + 2)[:, None] * (prob.goal - prob.start)
    colony = AntColony(sc.planner.aco)
    budget = lattice_setup_s(prob, sc.planner.aco, len(route)) + 0.2
    res = colony.run(slow(prob, delay), np.random.default_rng(2), route, 1.0, deadline=Deadline.after(budget))
    assert res.stop_reason == "timeout" and res.iterations >= 1
    assert res.time_s <= budget + 0.5 * delay
    assert res.iterations == len(res.history) and res.iterations <= int(budget / delay)
    seed = colony.run(slow(prob, delay), np.random.default_rng(2), route, 1.0, deadline=Deadline.after(0.01))
    assert seed.iterations == 0 and seed.stop_reason == "timeout" and np.array_equal(seed.path, route)


@pytest.mark.parametrize("algorithm, roadmap", [("fusion", True), ("fusion", False), ("spso", True),
                                                ("spso", False), ("aco", False)])
def test_plan_with_a_slow_evaluation_ends_within_its_budget(algorithm: str, roadmap: bool) -> None:
    """planner.plan.plan end to end, each evaluation slowed by 20 ms, budget 150 ms: every phase (roadmap,
    repair, swarm, colonies) stops before a step it cannot finish in time. Allowed beyond the budget: one
    evaluation (the merged waypoints are scored again after the search; the reserve for the post-processing
    is sized for a real evaluation, microseconds, not for this one) and half an evaluation of other work."""
    sc = load_scenario(SCENARIOS / "rescue_dynamic.toml", [f'planner.algorithm="{algorithm}"',
                                                          f"planner.roadmap.enabled={str(roadmap).lower()}",
                                                          "planner.pso.n_pop=30"])
    delay, budget = 0.020, 0.150
    problem = slow(problem_from_scenario(sc), delay)
    plan(problem, sc.planner, np.random.default_rng(0), deadline=Deadline.after(budget))  # roadmap cache, imports
    res = plan(problem, sc.planner, np.random.default_rng(1), deadline=Deadline.after(budget))
    assert res.optimiser.stop_reason == "timeout"  # the budget, not the iteration limit, ended it
    assert res.plan_time_s <= budget + 1.5 * delay


@pytest.mark.parametrize("algorithm, roadmap", [("fusion", True), ("fusion", False), ("spso", False),
                                                ("pso", False), ("aco", False)])
def test_a_budget_that_never_fires_changes_nothing(algorithm: str, roadmap: bool) -> None:
    """The timing reads the clock only: with a budget too large to fire, the plan is bit for bit the plan
    without one (same seed, same waypoints), so budget None runs exactly the untimed search."""
    sc = load_scenario(SCENARIOS / "rescue_dynamic.toml", [f'planner.algorithm="{algorithm}"',
                                                          f"planner.roadmap.enabled={str(roadmap).lower()}",
                                                          "planner.pso.n_pop=30", "planner.pso.max_iter=20",
                                                          "planner.aco.max_iter=5"])
    problem = problem_from_scenario(sc)
    free = plan(problem, sc.planner, np.random.default_rng(3))
    timed = plan(problem, sc.planner, np.random.default_rng(3), deadline=Deadline.after(1e6))
    assert np.array_equal(free.waypoints, timed.waypoints)
    assert free.optimiser.history == timed.optimiser.history
    assert free.optimiser.stop_reason == timed.optimiser.stop_reason != "timeout"
    assert free.status == timed.status
