"""What the tests of the compiled cost kernel share (tests/planner/test_kernel.py, test_prisms_kernel.py): random
swarms, and the check that the kernel's costs are the numpy reference's. The fixture that picks the compiled kernel
is ``compiled`` in tests/planner/conftest.py."""

from __future__ import annotations

import numpy as np
import pytest

from planner import kernel
from planner.problem import CATEGORIES, TERMS, Evaluation, PlanningProblem

RTOL = 1e-9  # the kernel's terms, penalties and totals against the reference's, relative


def swarm(problem: PlanningProblem, rng: np.random.Generator, n_pop: int = 64, n_wp: int = 8, spread: float = 0.25,
          *, straight: int = 3, zero_length: bool = True) -> np.ndarray:
    """Random paths start → goal (n_pop, n_wp + 2, 3): the straight line bent by noise of ``spread`` × the direct
    distance (at least 100 m; z a third of it), so a swarm has every kind of particle, from clean to colliding, out
    of the band and out of bounds; the first ``straight`` particles straight, and with ``zero_length`` a
    zero-length segment (particle 1's first)."""
    line = np.linspace(problem.start, problem.goal, n_wp + 2)
    scale = spread * max(problem.direct_distance, 100.0)
    paths = line[None] + rng.normal(0.0, scale, (n_pop, n_wp + 2, 3)) * np.array([1.0, 1.0, 0.3])
    paths[:, 0], paths[:, -1] = problem.start, problem.goal
    paths[:straight, 1:-1] = line[1:-1]
    if zero_length:
        paths[1, 1] = paths[1, 0]
    return paths


def assert_same(problem: PlanningProblem, paths: np.ndarray) -> None:
    """The compiled kernel's evaluation of ``paths`` is the reference's: terms, penalty and total to RTOL, the
    same violation counts."""
    got, ref = problem.evaluate(paths), problem.evaluate_reference(paths)
    for name in TERMS:
        np.testing.assert_allclose(got.terms[name], ref.terms[name], rtol=RTOL, atol=1e-12, err_msg=name)
    np.testing.assert_allclose(got.penalty, ref.penalty, rtol=RTOL, atol=1e-9)
    np.testing.assert_allclose(got.total, ref.total, rtol=RTOL, atol=1e-9)
    for c in CATEGORIES:
        np.testing.assert_array_equal(got.violations[c], ref.violations[c], err_msg=c)


def assert_broad_phase_exact(problem: PlanningProblem, paths: np.ndarray, monkeypatch: pytest.MonkeyPatch
                             ) -> Evaluation:
    """The compiled kernel costs ``paths`` bit for bit the same with its broad phase on and off (totals,
    penalties, terms, violation counts); returns the evaluation with it on."""
    on = problem.evaluate(paths)
    monkeypatch.setenv(kernel.BROAD_ENV_VAR, "off")
    off = problem.evaluate(paths)
    monkeypatch.delenv(kernel.BROAD_ENV_VAR)
    assert np.array_equal(on.total, off.total) and np.array_equal(on.penalty, off.penalty)
    assert all(np.array_equal(on.terms[t], off.terms[t]) for t in TERMS)
    assert all(np.array_equal(on.violations[c], off.violations[c]) for c in CATEGORIES)
    return on
