"""The progress line: silent unless turned on; one line per stage in a file; an updating line
on a terminal, removed before a log message; the constraint violation measured against the
bounds of the solve."""

import io
import logging

import numpy as np
import pytest

from balance_opt import progress

CLEAR = "\r\x1b[K"


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture(autouse=True)
def _off_afterwards():
    yield
    progress.configure(False)


def _solve(violations):
    """A solve whose iterate ``k`` has the constraint g = [violation_k + 1, 0] against
    bounds [-1, 1] x [0, 0]: violation_k is what the line must show."""
    with progress.solving([-1.0, 0.0], [1.0, 0.0], "Ipopt (N = 4)"):
        for k, v in enumerate(violations):
            progress.iteration(10.0 - k, np.array([1.0 + v, 0.0]))


def test_silent_unless_configured():
    stream = io.StringIO()
    progress.configure(False, stream)
    progress.status("compiling")
    _solve([0.5, 0.0])
    assert stream.getvalue() == "" and not progress._STATE.enabled


def test_a_file_gets_one_line_per_stage_and_per_solve(monkeypatch):
    stream = io.StringIO()
    progress.configure(True, stream)
    progress.status("compiling the planner's kernels ...")
    _solve([0.5, 0.25, 0.0])
    lines = stream.getvalue().splitlines()
    assert lines[0] == "compiling the planner's kernels ..."
    assert len(lines) == 2
    assert lines[1].startswith(
        "Ipopt (N = 4): 2 iterations, objective 8, constraint violation 0.00e+00 in "
    )


def test_a_terminal_gets_an_updating_line_cleared_before_log_messages(monkeypatch):
    stream = Terminal()
    progress.configure(True, stream)
    monkeypatch.setattr(progress, "REFRESH_S", 0.0)
    logger = logging.getLogger("balance_opt.test_progress")
    handler = progress.LogHandler(stream)
    handler.setFormatter(logging.Formatter("%(message)s"))
    logger.addHandler(handler)
    try:
        progress.status("compiling")
        logger.warning("a warning")
        with progress.solving([-1.0], [1.0], "Ipopt"):
            progress.iteration(3.0, np.array([1.5]))
            assert stream.getvalue().endswith(
                f"{CLEAR}Ipopt: iteration 0, objective 3, constraint violation 5.00e-01"
            )
    finally:
        logger.removeHandler(handler)
    text = stream.getvalue()
    # the live line, then a clear before the log message, which starts on a clean line
    assert text.startswith(f"{CLEAR}compiling{CLEAR}a warning\n")
    assert "Ipopt: 0 iterations, objective 3, constraint violation 5.00e-01 in " in text
    assert text.endswith(" s\n")


def test_a_closed_stream_turns_progress_off():
    stream = io.StringIO()
    progress.configure(True, stream)
    stream.close()
    progress.status("anything")  # no exception
    assert not progress._STATE.enabled


def test_the_ipopt_callback_follows_the_solve_and_stops_it_on_an_interrupt(monkeypatch):
    """On a small NLP: one call per Ipopt iteration (0 included), the violation of the bounds
    given to ``solving``; an interrupt (KeyboardInterrupt) inside the callback stops Ipopt at
    that iteration instead of being swallowed."""
    cs = pytest.importorskip("casadi")
    n = 30
    x = cs.MX.sym("x", n)
    solver = progress.nlpsol(  # as the planner's NLP
        "toy",
        {"x": x, "f": cs.sumsqr(x - 1), "g": x[1:] - x[:-1]},
        {"ipopt": {"print_level": 0, "sb": "yes"}, "print_time": False},
    )
    x0 = np.linspace(0.0, 29.0, n)  # steps of 1 against bounds of +-0.1: violation 0.9
    stream = io.StringIO()
    progress.configure(True, stream)
    with progress.solving(np.full(n - 1, -0.1), np.full(n - 1, 0.1), "toy"):
        solver(x0=x0, lbg=-0.1, ubg=0.1)
    stats = solver.stats()
    assert stats["return_status"] == "Solve_Succeeded"
    assert stream.getvalue().startswith(f"toy: {stats['iter_count']} iterations, objective ")
    seen = []
    real = progress.iteration

    def interrupted_at_2(objective, g):
        real(objective, g)
        seen.append(progress._STATE.solve["violation"])
        if len(seen) == 3:
            raise KeyboardInterrupt

    monkeypatch.setattr(progress, "iteration", interrupted_at_2)
    with progress.solving(np.full(n - 1, -0.1), np.full(n - 1, 0.1), "toy"):
        solver(x0=x0, lbg=-0.1, ubg=0.1)
    assert solver.stats()["return_status"] == "User_Requested_Stop"
    assert solver.stats()["iter_count"] == 2 and len(seen) == 3
    assert seen[0] == pytest.approx(0.9)

    def broken(objective, g):
        raise ValueError("a bug in the progress code")

    monkeypatch.setattr(progress, "iteration", broken)  # must not end the solve
    with progress.solving(np.full(n - 1, -0.1), np.full(n - 1, 0.1), "toy"):
        solver(x0=x0, lbg=-0.1, ubg=0.1)
    assert solver.stats()["return_status"] == "Solve_Succeeded"
