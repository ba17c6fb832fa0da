"""What a person at the terminal sees: progress bars, tables and live lines drawn with rich on an interactive
terminal; plain text on a pipe, in a log or in CI (and nothing extra with ``-q``), so files and logs stay clean.

Library code never prints (it takes a progress callback); the command line picks one of these.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO

from rich.console import Console
from rich.markdown import Markdown
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

Advance = Callable[..., None]  # (done, total[, failed]): failed runs are among the done ones


def interactive(stream: TextIO) -> bool:
    """True on a terminal a person watches (not a pipe, a file or a CI log)."""
    return stream.isatty()


def _rich_bar(console: Console, *fields: TextColumn) -> Progress:
    return Progress(TextColumn("  {task.description}"), BarColumn(), MofNCompleteColumn(), *fields,
                    TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), console=console, transient=False)


@contextmanager
def run_progress(label: str, quiet: bool = False, stream: TextIO | None = None) -> Iterator[Advance | None]:
    """A ``(done, total[, failed])`` callback for work done in runs: a live bar on a terminal, one line per tenth
    of the work (and at each failure) on a pipe or log, None with ``quiet``."""
    stream = stream or sys.stderr
    if quiet:
        yield None
        return
    if not interactive(stream):
        seen = [0]

        def line(done: int, total: int, failed: int = 0) -> None:
            if done == total or done * 10 // total != (done - 1) * 10 // total or failed > seen[0]:
                print(f"  {label}: {done}/{total}" + (f", {failed} failed" if failed else ""), file=stream,
                      flush=True)
            seen[0] = failed
        yield line
        return
    with _rich_bar(Console(file=stream), TextColumn("[red]{task.fields[failed]}")) as bar:
        task = bar.add_task(label, total=None, failed="")

        def advance(done: int, total: int, failed: int = 0) -> None:
            bar.update(task, completed=done, total=total, failed=f"{failed} failed" if failed else "")
        yield advance


@contextmanager
def iteration_progress(quiet: bool = False, stream: TextIO | None = None,
                       ) -> Iterator[Callable[[int, int, float], None] | None]:
    """An ``(iteration, budget, best cost)`` callback for one search: a live bar on a terminal; nothing on a pipe,
    in a log or with ``quiet`` (the summary lines that follow say it all)."""
    stream = stream or sys.stderr
    if quiet or not interactive(stream):
        yield None
        return
    with _rich_bar(Console(file=stream), TextColumn("best cost {task.fields[cost]:>12.1f}")) as bar:
        task = bar.add_task("iteration", total=None, cost=float("nan"))

        def show(it: int, total: int, cost: float) -> None:
            bar.update(task, completed=it, total=total, cost=cost)
        yield show


def show_markdown(text: str, stream: TextIO | None = None) -> None:
    """A Markdown report or table: rendered (tables drawn) on a terminal, the Markdown itself elsewhere."""
    stream = stream or sys.stdout
    if interactive(stream):
        Console(file=stream).print(Markdown(text))
    else:
        print(text, file=stream)


def say(text: str, style: str | None = None, stream: TextIO | None = None) -> None:
    """One live line (a flight event, say): coloured by ``style`` on a terminal, plain elsewhere."""
    stream = stream or sys.stdout
    if style and interactive(stream):
        Console(file=stream, highlight=False).print(text, style=style, markup=False, soft_wrap=True)
    else:
        print(text, file=stream, flush=True)
