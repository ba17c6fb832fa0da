"""Terminal output: rich bars and tables on a terminal, plain text on a pipe or in a log, nothing with -q."""

from __future__ import annotations

import io

from planner import console


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_run_progress_on_a_pipe_prints_one_line_per_tenth() -> None:
    out = io.StringIO()
    with console.run_progress("runs", stream=out) as advance:
        for done in range(1, 21):
            advance(done, 20)
    lines = out.getvalue().splitlines()
    assert lines == [f"  runs: {d}/20" for d in range(2, 21, 2)]
    assert "\x1b[" not in out.getvalue()


def test_quiet_means_no_callback_and_no_output() -> None:
    out = _Tty()
    with console.run_progress("runs", quiet=True, stream=out) as advance, \
            console.iteration_progress(quiet=True, stream=out) as show:
        assert advance is None and show is None
    assert out.getvalue() == ""


def test_iteration_progress_is_silent_off_a_terminal() -> None:
    with console.iteration_progress(stream=io.StringIO()) as show:
        assert show is None


def test_on_a_terminal_the_bar_is_drawn_with_the_count() -> None:
    out = _Tty()
    with console.run_progress("runs", stream=out) as advance:
        for done in range(1, 5):
            advance(done, 4)
    assert "4/4" in out.getvalue() and "runs" in out.getvalue()
    with console.iteration_progress(stream=out) as show:
        show(50, 200, 1234.5)
    assert "1234.5" in out.getvalue()


def test_markdown_is_passed_through_off_a_terminal_and_drawn_on_one() -> None:
    md = "| algorithm | cost |\n|---|---|\n| spso | 1.0 |"
    plain, tty = io.StringIO(), _Tty()
    console.show_markdown(md, stream=plain)
    console.show_markdown(md, stream=tty)
    assert plain.getvalue() == md + "\n"
    assert "|---|" not in tty.getvalue() and "spso" in tty.getvalue() and "───" in tty.getvalue()


def test_say_colours_only_on_a_terminal() -> None:
    plain, tty = io.StringIO(), _Tty()
    console.say("CONFLICT with X", "bold red", stream=plain)
    console.say("CONFLICT with X", "bold red", stream=tty)
    assert plain.getvalue() == "CONFLICT with X\n"
    assert "\x1b[" in tty.getvalue() and "CONFLICT with X" in tty.getvalue()
