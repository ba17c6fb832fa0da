"""The fusion planner (docs/method.md §9, paper Algorithm 1): SPSO until its switch criterion fires, then
GKDM-seeded ant-colony refinement of its best route; the better of the two is the answer, so the fusion never
returns a higher cost than its own SPSO phase."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from planner.deadline import NEVER, Deadline
from planner.problem import PlanningProblem
from planner.search import roadmap
from planner.search.aco import AntColony, lattice_setup_s
from planner.search.encoding import Encoding, guided_encoding, resample_keeping_vertices, resample_paths
from planner.search.repair import repair
from planner.search.roadmap_colony import RoadmapColony
from planner.search.roadmap_colony import setup_s as colony_setup_s
from planner.search.spso import SphericalPSO
from planner.search.swarm import OptimiserResult
from planner.search.termination import Settled
from planner.world.config import ACOConfig, PlannerSettings


@dataclass
class PhaseRecord:
    best_cost: float
    iterations: int
    time_s: float
    evaluations: int
    stop_reason: str


@dataclass
class FusionResult(OptimiserResult):
    """An :class:`OptimiserResult` whose history is the PSO iterations then the ACO iterations (best so
    far), with a record per phase and which phase's route won."""

    phases: dict[str, PhaseRecord] = field(default_factory=dict)
    winner: str = "pso"
    trace: dict[str, list[np.ndarray]] = field(default_factory=dict)  # roadmap guides, ant paths (figures)


MIN_ACO_BUDGET_S = 0.005  # below this a colony cannot even build its lattice
MIN_COLONY_BUDGET_S = 0.05  # below this the roadmap colony is skipped (a walk of 30 ants takes milliseconds)
REPAIR_SHARE = 0.8  # of the time left that the guide's repair may use (docs/method.md §15.5)
ROUTES_SHARE = 0.5  # of a budget that the roadmap's extra routes and fallbacks may use (the first route always runs)


class Fusion:
    """The fusion planner; ``swarm_only``: with the roadmap, stop after the guided swarm (the ``spso`` algorithm
    with the roadmap's seeds, docs/method.md §15.3 steps 1–2)."""

    def __init__(self, settings: PlannerSettings, swarm_only: bool = False) -> None:
        self.settings = settings
        self.swarm_only = swarm_only

    def run(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None = None,
        deadline: Deadline = NEVER, progress: Callable[[int, int, float], None] | None = None,
    ) -> FusionResult:
        """Phase I SPSO (its stop criteria are the switch), phase II ACO on what is left of ``deadline``; with
        the roadmap enabled, the roadmap pipeline (:meth:`_run_roadmap`)."""
        t0 = time.perf_counter()
        s = self.settings
        if s.roadmap.enabled:
            return self._run_roadmap(problem, rng, initial_paths, deadline, progress, t0)
        share = _swarm_share(deadline.remaining(), problem, s.aco, s.pso.n_waypoints + 2)
        pso = SphericalPSO(s.pso).run(problem, rng, initial_paths=initial_paths, deadline=deadline.share(share),
                                      progress=progress)
        if not _affords_lattice(deadline.remaining(), problem, s.aco, len(pso.path), _iteration_s(pso)):
            return self._finish([("pso", pso)], t0)  # no time for a colony: SPSO's answer stands
        aco = AntColony(s.aco).run(problem, rng, pso.path, pso.cost, deadline=deadline, progress=progress)
        return self._finish([("pso", pso), ("aco", aco)], t0)

    def _run_roadmap(
        self, problem: PlanningProblem, rng: np.random.Generator, initial_paths: np.ndarray | None,
        deadline: Deadline, progress: Callable[[int, int, float], None] | None, t0: float,
    ) -> FusionResult:
        """docs/method.md §15: roadmap guides → SPSO in the guide's encoding, seeded with every guide → GKDM from
        the swarm's elites onto the roadmap → ants walk the roadmap → if they found a better corridor, SPSO
        around it → the corridor-lattice colony refines the winner. Without a roadmap route: the paper's
        fusion, and the record says at which resolution none was found."""
        s = self.settings
        rm, q, weights, routes, cfg = roadmap.routes(problem, s.roadmap, deadline.share(ROUTES_SHARE))
        trace: dict[str, list[np.ndarray]] = {"guides": list(routes)}
        extra = {"roadmap": PhaseRecord(math.nan, len(routes), time.perf_counter() - t0, 0,
                                        f"{len(routes)} routes at {rm.spacing:.0f} m resolution" if routes
                                        else f"no route at {rm.spacing:.0f} m resolution")}
        if not routes:  # the paper's planner from the cone (SPSO alone for the spso algorithm)
            if self.swarm_only:
                pso = SphericalPSO(s.pso).run(problem, rng, initial_paths=initial_paths, deadline=deadline,
                                              progress=progress)
                return self._finish([("pso", pso)], t0, extra)
            paper = Fusion(replace(s, roadmap=replace(s.roadmap, enabled=False))).run(
                problem, rng, initial_paths, deadline, progress)
            paper.phases = {**extra, **paper.phases}
            paper.time_s = time.perf_counter() - t0
            return paper
        enc, seeds = self._guided(problem, routes[0], routes[1:], initial_paths, rng, deadline, extra)
        left = deadline.remaining()
        share = 1.0 - s.aco.budget_share
        guided = replace(s.pso, stagnation_tol=cfg.stagnation_tol)
        # the swarm's share of what is left: all of it when nothing follows (swarm only) or nothing could (neither
        # colony affordable in the rest), else 1 − budget_share
        first = (1.0 if self.swarm_only else share if _affords_colony(left * (1.0 - share), q, 0.0)
                 else _swarm_share(left, problem, s.aco, enc.n + 2))
        pso = SphericalPSO(guided).run(problem, rng, initial_paths=seeds, encoding=enc, progress=progress,
                                      deadline=deadline.share(first))
        done: list[tuple[str, OptimiserResult]] = [("pso", pso)]
        if self.swarm_only or pso.stop_reason == Settled.name:  # a safe route was all that was asked for
            return self._finish(done, t0, extra, lattice=False, trace=trace)
        step_s = _iteration_s(pso)  # what one swarm iteration took: the guess at any later phase's first step
        if _affords_colony(deadline.remaining(), q, step_s):
            colony = RoadmapColony(s.aco, enc.n + 2, cfg.colony_iter).run(
                q, weights, problem, self._elites(pso, enc, rm.spacing), rng, deadline.share(0.5), first_s=step_s)
            trace["ants"] = colony.ant_paths
            if colony.route is not None and colony.evaluation is not None and colony.path is not None:  # together
                done.append(("colony", OptimiserResult(
                    colony.route, colony.cost, colony.evaluation, colony.history, colony.iterations,
                    f"{100 * colony.arrived:.0f}% of ants arrived", colony.time_s, colony.evaluations)))
                guide = roadmap.guide(colony.path, rm, problem, cfg)
                # the ants found a cheaper route (on a hard map: a way SPSO could not make flyable) or another
                # corridor: the swarm makes it flyable around the ants' corridor
                # (only when a repair step, the swarm's first evaluation and an iteration fit)
                if (colony.cost < pso.cost or roadmap.mean_distance(guide, pso.path) > rm.spacing) and (
                        deadline.affords(3.0 * step_s)):
                    enc2, seeds2 = self._guided(problem, guide, [colony.route, pso.path], None, rng, deadline)
                    pso2 = SphericalPSO(replace(guided, max_iter=max(1, s.pso.max_iter // 2))).run(
                        problem, rng, initial_paths=seeds2, encoding=enc2, progress=progress,
                        deadline=deadline.share(share))
                    done.append(("pso2", pso2))
        best = min(done, key=lambda d: d[1].cost)[1]
        if _affords_lattice(deadline.remaining(), problem, s.aco, len(best.path), step_s):
            done.append(("aco", AntColony(s.aco).run(problem, rng, best.path, best.cost, deadline=deadline,
                                                     progress=progress)))
        return self._finish(done, t0, extra, trace=trace)

    def _guided(self, problem: PlanningProblem, guide: np.ndarray, others: list[np.ndarray],
                initial_paths: np.ndarray | None, rng: np.random.Generator, deadline: Deadline,
                record: dict[str, PhaseRecord] | None = None) -> tuple[Encoding, np.ndarray]:
        """The encoding around ``guide`` (docs/method.md §15.2) and the seeds: the guide as the swarm's points,
        repaired where it has faults (§15.5, on at most ``REPAIR_SHARE`` of what is left of ``deadline``), then
        ``others`` and the caller's ``initial_paths``, each fitted to the encoding's waypoint count. ``record``:
        gets the repair's phase record."""
        cfg = self.settings.roadmap
        if len(guide) - 2 > cfg.max_guide_points:
            guide = resample_paths(guide[None], cfg.max_guide_points + 2)[0]
        enc, guide_pts = guided_encoding(problem, self.settings.pso, guide)
        t = time.perf_counter()
        fix = repair(problem, guide_pts, rng, deadline.share(REPAIR_SHARE))
        if fix.rounds:  # the guide had faults: the encoding follows the repaired route
            enc, guide_pts = guided_encoding(problem, self.settings.pso, fix.path, n=len(fix.path) - 2)
        if record is not None:
            record["repair"] = PhaseRecord(fix.cost, fix.rounds, time.perf_counter() - t, fix.evaluations,
                                           f"{fix.violations} violations left")
        seeds = [guide_pts] + [_fit(r, enc.n + 2) for r in others]
        if initial_paths is not None:
            seeds += [_fit(p, enc.n + 2) for p in np.asarray(initial_paths, dtype=float)]
        return enc, np.stack(seeds)

    @staticmethod
    def _elites(pso: OptimiserResult, enc: Encoding, spacing: float, count: int = 5) -> list[np.ndarray]:
        """Up to ``count`` of the swarm's personal bests as paths, best first, each more than one roadmap
        spacing (mean distance) from those before it."""
        st = pso.state
        if st is None:
            return [pso.path]
        order = np.argsort(st.pbest_f, kind="stable")
        paths = enc.decode(st.pbest_x[order[: 20 * count]])
        elites = [pso.path]
        for p in paths:  # at most 20 × count candidates
            if len(elites) >= count:
                break
            if all(roadmap.mean_distance(p, e) > spacing for e in elites):
                elites.append(p)
        return elites

    @staticmethod
    def _finish(done: list[tuple[str, OptimiserResult]], t0: float, extra: dict[str, PhaseRecord] | None = None,
                lattice: bool = True, trace: dict[str, list[np.ndarray]] | None = None) -> FusionResult:
        """The best of the phases ``done`` (in the order they ran; SPSO first) and their records; ``extra``:
        records of the phases that are not swarms (the roadmap); ``trace``: what figures draw."""
        pso = done[0][1]
        phases = dict(extra or {})
        phases.update({name: PhaseRecord(r.cost, r.iterations, r.time_s, r.evaluations, r.stop_reason)
                       for name, r in done})
        if lattice:
            phases.setdefault("aco", PhaseRecord(pso.cost, 0, 0.0, 0, "skipped: no time left"))
        win_name, winner = min(done, key=lambda d: d[1].cost)  # first of equals: SPSO's on a tie
        history = list(pso.history)
        for _, r in done[1:]:  # each later phase's best after each of its iterations (a swarm's initial best left out)
            history += [min(history[-1], h) for h in r.history[len(r.history) - r.iterations:]]
        stop = "timeout" if any(r.stop_reason == "timeout" for _, r in done) else pso.stop_reason
        return FusionResult(winner.path, winner.cost, winner.evaluation, history,
                            sum(r.iterations for _, r in done), stop, time.perf_counter() - t0,
                            sum(r.evaluations for _, r in done), pso.state, phases, win_name, dict(trace or {}))


def _fit(route: np.ndarray, count: int) -> np.ndarray:
    """A seed route as ``count`` points: vertices kept when they fit, else evenly along its length."""
    if len(route) <= count:
        return resample_keeping_vertices(route, count)
    return resample_paths(route[None], count)[0]


def _affords_lattice(left_s: float, problem: PlanningProblem, cfg: ACOConfig, n_points: int,
                     step_s: float) -> bool:
    """True when a corridor-lattice colony fits in ``left_s`` seconds: its set-up (the estimate with a quarter
    more), the seed's evaluation and an iteration (each guessed as ``step_s``, a swarm iteration's time)."""
    return left_s >= max(MIN_ACO_BUDGET_S, 1.25 * lattice_setup_s(problem, cfg, n_points) + 2.0 * step_s)


def _affords_colony(left_s: float, q: roadmap.Query, step_s: float) -> bool:
    """True when the roadmap colony, given half of ``left_s``, fits its set-up (the estimate with a quarter
    more, :func:`planner.search.roadmap_colony.setup_s`) and a first walk (guessed as two ``step_s``)."""
    return left_s > MIN_COLONY_BUDGET_S and 0.5 * left_s >= 1.25 * colony_setup_s(q) + 2.0 * step_s


def _swarm_share(left_s: float, problem: PlanningProblem, cfg: ACOConfig, n_points: int) -> float:
    """The share of the ``left_s`` seconds a swarm phase gets before the colonies: ``1 − budget_share``, or all
    of it when what it would leave could not pay for a lattice colony's set-up (the colony would be skipped
    anyway)."""
    rest = left_s * cfg.budget_share
    return 1.0 - cfg.budget_share if _affords_lattice(rest, problem, cfg, n_points, 0.0) else 1.0


def _iteration_s(r: OptimiserResult) -> float:
    """Mean seconds per iteration of a swarm phase, its initial evaluation counted as one."""
    return r.time_s / (r.iterations + 1)
