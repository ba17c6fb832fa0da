"""``fuseplan bench NAME``: the paper's experiments, one command each (issue 5).

A bench is a :class:`~planner.bench.runner.Bench`: a scenario, a budget, variants and a report writer.
:mod:`planner.bench.runner` runs it (process pool, JSON-lines records, resume); each bench module writes its
own tables and figures.
"""

from __future__ import annotations

import importlib

from planner.bench.runner import Bench

# each module exports BENCHES, a tuple of Bench
_MODULES = ("ablation", "comparison", "constraints", "gkdm", "large_scale", "speed", "robustness")


def _load() -> dict[str, Bench]:
    benches: dict[str, Bench] = {}
    for name in _MODULES:
        try:
            module = importlib.import_module(f"planner.bench.{name}")
        except ModuleNotFoundError as e:  # a bench not written yet
            if e.name == f"planner.bench.{name}":
                continue
            raise
        benches.update({b.name: b for b in module.BENCHES})
    return benches


BENCHES: dict[str, Bench] = _load()

__all__ = ["BENCHES", "Bench"]
