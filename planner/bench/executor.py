"""Where the runs of a sweep execute (issue 17): this machine's process pool (``local``), an existing
dask.distributed cluster (``dask``), or a dask ``LocalCluster`` started here (``dask-local``).

A run is a task: a module-level function and its spec, which carries everything the run needs (the scenario's
text, overrides, seed), so nothing is shared with this process and no file is assumed on a worker. Results come
back one at a time as runs finish; the caller writes each at once. Dask re-runs the tasks of a worker lost mid-run
on the others; a run that raises is reported as :class:`Failed` and the sweep goes on.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib.metadata
import logging
import os
import platform
import uuid
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from planner.errors import FuseplanError

log = logging.getLogger(__name__)

EXECUTORS = ("local", "dask", "dask-local")
CLUSTER_EXTRA = "pip install 'fuseplan[cluster]'"
CONNECT_TIMEOUT_S = 10.0  # to reach a scheduler
WORKERS_TIMEOUT_S = 30.0  # for a scheduler with no worker to get one


def default_workers() -> int:
    """Processes of a local pool or workers of a dask-local cluster: the CPU count, at most 8."""
    return max(1, min(os.cpu_count() or 1, 8))


@dataclass(frozen=True)
class ExecutorSpec:
    kind: str = "local"  # one of EXECUTORS
    workers: int | None = None  # local: processes; dask-local: workers (default: default_workers())
    scheduler: str | None = None  # dask: the scheduler's address, e.g. tcp://10.0.0.5:8786

    def check(self) -> None:
        """A user's mistake in the options, as one line."""
        if self.kind not in EXECUTORS:
            raise FuseplanError(f"unknown executor {self.kind!r}; choose from {', '.join(EXECUTORS)}")
        if self.workers is not None and self.workers < 1:
            raise FuseplanError("--workers must be >= 1")
        if self.kind == "dask" and not self.scheduler:
            raise FuseplanError("--executor dask needs --scheduler tcp://HOST:PORT (the address `dask scheduler` "
                                "prints)")
        if self.kind != "dask" and self.scheduler:
            raise FuseplanError(f"--scheduler is for --executor dask, not {self.kind}")
        if self.kind == "dask" and self.workers is not None:
            raise FuseplanError("--workers does not apply to --executor dask: the cluster has the workers it has")
        if self.kind != "local":  # before any run: the extra is imported only for the executor that needs it
            _distributed(self.kind)

    def processes(self, n_tasks: int | None = None) -> int:
        """Local processes or dask-local workers: ``--workers`` (default :func:`default_workers`), at most one per
        task."""
        n = self.workers or default_workers()
        return n if n_tasks is None else max(1, min(n, n_tasks))

    def describe(self) -> str:
        """What will run the sweep, before it starts."""
        if self.kind == "dask":
            return f"the dask cluster at {self.scheduler}"
        n = self.processes()
        if self.kind == "local":
            return f"{n} local process{'es' if n > 1 else ''}"
        return f"a dask LocalCluster of {n} worker{'s' if n > 1 else ''}"


@dataclass(frozen=True)
class Failed:
    """A run that raised (or whose task dask gave up on): what to tell the user."""

    error: str


class Pool(Protocol):
    ran_on: str  # executor and worker count, for the report: "dask-local, 2 workers"
    workers: int

    def run(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        """``(index, fn(items[index]) or Failed)`` as each run finishes."""
        ...


def _error(e: BaseException) -> str:
    return str(e) if isinstance(e, FuseplanError) else f"{type(e).__name__}: {e}"


class _LocalPool:
    def __init__(self, workers: int) -> None:
        self.workers = workers
        self.ran_on = f"local, {workers} process{'es' if workers > 1 else ''}"
        self._pool = ProcessPoolExecutor(max_workers=workers)

    def run(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        pending = {self._pool.submit(fn, item): i for i, item in enumerate(items)}
        while pending:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                i = pending.pop(fut)
                e = fut.exception()
                yield i, (fut.result() if e is None else Failed(_error(e)))

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


@functools.lru_cache(maxsize=1)
def software() -> dict[str, str]:
    """What decides a run's numbers besides its spec: fuseplan's code, the cost kernel, the numeric libraries.
    Every dask worker must match this process, or the records would depend on which worker ran them."""
    from planner import kernel

    root = Path(__file__).resolve().parent.parent  # the planner package
    h = hashlib.sha256()
    for f in sorted(root.rglob("*.py")):
        h.update(f.relative_to(root).as_posix().encode() + b"\0" + f.read_bytes())
    out = {"fuseplan code": h.hexdigest()[:12], "cost kernel": kernel.chosen(),
           "python": ".".join(platform.python_version_tuple()[:2])}  # pickles cross minor versions badly
    for dist in ("numpy", "scipy", "numba"):
        try:
            out[dist] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[dist] = "none"
    return out


def _mismatch(have: dict[str, str], expected: dict[str, str], where: str) -> str:
    """'' when ``have`` is ``expected``, else a one-line reason naming what differs."""
    if have == expected:
        return ""
    diff = ", ".join(f"{k} {have.get(k)} (here {v})" for k, v in expected.items() if have.get(k) != v)
    return (f"{where} runs other software than this machine: {diff}; install the same fuseplan and libraries on "
            f"every worker")


def _on_worker(fn: Callable[[Any], Any], item: Any, expected: dict[str, str]) -> Any:
    """A task on a dask worker: refuse to run on other software than the submitter's (a worker may have joined
    after the check at the start), then run."""
    reason = _mismatch(software(), expected, "a worker")
    if reason:
        raise FuseplanError(reason)
    return fn(item)


class _DaskPool:
    def __init__(self, client: Any, kind: str) -> None:
        self._client = client
        try:  # every worker there now, before any run: a mismatch is one line, not a failure per run
            found = client.run(software)
        except Exception as e:  # a worker without fuseplan cannot even unpickle the check
            raise FuseplanError(f"a dask worker cannot run fuseplan ({type(e).__name__}: {e}); install "
                                f"fuseplan[cluster] on every worker") from None
        for address, have in sorted(found.items()):
            reason = _mismatch(have, software(), f"dask worker {address}")
            if reason:
                raise FuseplanError(reason)
        self.workers = len(found)
        self.ran_on = f"{kind}, {self.workers} worker{'s' if self.workers > 1 else ''}"

    def run(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> Iterator[tuple[int, Any]]:
        from distributed import as_completed

        tag = uuid.uuid4().hex[:8]
        expected = software()
        futures = [self._client.submit(_on_worker, fn, item, expected, key=f"fuseplan-run-{tag}-{i}", pure=False)
                   for i, item in enumerate(items)]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in as_completed(futures):
                i = index[fut.key]
                if fut.status == "finished":
                    yield i, fut.result()
                else:
                    e = fut.exception() if fut.status == "error" else None
                    yield i, Failed(_error(e) if e is not None else f"task {fut.status}")
                fut.release()
        finally:
            self._client.cancel([f for f in futures if not f.done()])


def _distributed(kind: str) -> Any:
    """The dask.distributed module, or a one-line error naming the extra that brings it."""
    try:
        import distributed
    except ImportError:
        raise FuseplanError(f"--executor {kind} needs the cluster extra (dask.distributed): {CLUSTER_EXTRA}") from None
    return distributed


def _dask_client(spec: ExecutorSpec, n_tasks: int) -> tuple[Any, Any]:
    """(client, cluster or None); every failure to get one is a one-line FuseplanError."""
    distributed = _distributed(spec.kind)
    if not log.isEnabledFor(logging.DEBUG):  # dask's own INFO lines (-v shows them); its warnings stay
        logging.getLogger("distributed").setLevel(logging.WARNING)
    if spec.kind == "dask-local":
        n = spec.processes(n_tasks)
        # loopback only, one single-threaded process per worker (a plan is one core's work), any free ports
        try:
            cluster = distributed.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                               scheduler_port=0, dashboard_address="127.0.0.1:0",
                                               silence_logs=logging.WARNING)
        except Exception as e:  # dask's reasons vary (a worker that cannot start, no free port)
            raise FuseplanError(f"cannot start a dask LocalCluster of {n} workers: {type(e).__name__}: {e}") from None
        return distributed.Client(cluster), cluster
    try:
        client = distributed.Client(spec.scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError, ValueError) as e:
        raise FuseplanError(f"cannot reach the dask scheduler at {spec.scheduler}: {e}") from None
    try:
        client.wait_for_workers(1, timeout=WORKERS_TIMEOUT_S)
    except (TimeoutError, OSError):
        client.close()
        raise FuseplanError(f"the dask scheduler at {spec.scheduler} has no worker after {WORKERS_TIMEOUT_S:g} s; "
                            f"start some with `dask worker {spec.scheduler}`") from None
    return client, None


@contextlib.contextmanager
def open_pool(spec: ExecutorSpec, n_tasks: int) -> Iterator[Pool]:
    """The executor ``spec`` names, ready for ``n_tasks`` runs, closed (its unfinished tasks cancelled) on exit."""
    spec.check()
    if spec.kind == "local":
        pool = _LocalPool(spec.processes(n_tasks))
        try:
            yield pool
        finally:
            pool.close()
        return
    client, cluster = _dask_client(spec, n_tasks)
    try:
        yield _DaskPool(client, spec.kind)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
