"""Interrupts and worker processes: Ctrl-C, SIGTERM and SIGHUP before, inside and after the Ipopt solve,
and while the files are written (exit 130, "interrupted", the previous results untouched, no
staging folder left); a sweep's workers end with their parent, even after ``kill -9``, and
Ctrl-C on a sweep returns within seconds.

The long runs are ``balance-opt`` subprocesses: the optimal planner made slow on purpose (a
quasi-Newton Hessian and a tolerance it cannot reach), and sweeps of a case function that
sleeps (``sleepy_case``, imported by name in the worker processes).
"""

import errno
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil
import pytest

from balance_opt import interrupts
from balance_opt.cli import main

TESTS = Path(__file__).resolve().parent
PAPER_TASK = TESTS.parent / "examples" / "capture_task.yaml"
#: Ipopt options that keep the solve going for tens of seconds on the fast test task.
SLOW_IPOPT = (
    "hessian_approximation=limited-memory",
    "tol=1e-300",
    "acceptable_iter=1000000",
    "max_iter=100000",
)
#: Longest wait for a subprocess to reach a given point [s] (a loaded machine compiles slowly).
START_TIMEOUT = 180
#: An Ipopt iteration line of the verbose log (``iter objective inf_pr ...``).
IPOPT_ITERATION = re.compile(r"^\s*(\d+)r?\s+[-+]?\d\.\d+e[-+]\d+\s")


def _fast_task(tmp_path: Path, intervals: int = 12, outputs: str = "{plots: false, report: false}"):
    """The capture task made fast: a short move, coarse grids, by default no figures."""
    text = PAPER_TASK.read_text()
    text = text.replace("goal: [1.2, 0.9, -1.6]", "goal: [0.6, 0.6, -1.1]")
    text = text.replace("duration: 10.0", "duration: 3.0")
    text += (
        f"analytic: {{output_step: 0.05}}\noptimal: {{intervals: {intervals}}}\n"
        f"simulation: {{dt: 0.002, output_dt: 0.05}}\noutputs: {outputs}\n"
    )
    path = tmp_path / "task.yaml"
    path.write_text(text)
    return path


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in folder.rglob("*")}


def _previous_run(tmp_path: Path, task: Path) -> tuple[Path, dict[str, bytes]]:
    """A folder holding a finished analytic run, and its content."""
    out = tmp_path / "out"
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out), "-q"]) == 0
    return out, _snapshot(out)


def _only_the_folder_beside(out: Path, *others: str) -> None:
    """Nothing but ``out`` (and the given files) in its parent: no staging folder, no lock."""
    assert sorted(p.name for p in out.parent.iterdir()) == sorted([out.name, *others])


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "balance_opt.cli", *args]


# ------------------------------------------------------------------------------ the mechanism
def test_signal_inside_the_block_is_raised_and_recorded():
    with interrupts.handling_signals():
        with pytest.raises(interrupts.Interrupted) as info:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises at the next bytecode
        assert info.value.signum == signal.SIGTERM
        assert isinstance(info.value, KeyboardInterrupt)
        assert interrupts._received[:1] == [signal.SIGTERM]
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert not interrupts._received


def test_interrupt_swallowed_by_a_library_is_raised_again():
    """What CasADi does with Ctrl-C inside Ipopt: the handler's exception is caught."""
    with interrupts.handling_signals():
        interrupts.raise_if_interrupted()  # nothing recorded: nothing raised
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        except KeyboardInterrupt:
            pass  # the library's catch
        with interrupts.handling_signals(), pytest.raises(interrupts.Interrupted):
            interrupts.raise_if_interrupted()  # in a nested block: the record is shared
    interrupts.raise_if_interrupted()  # cleared when the outermost block ends


def test_handlers_of_the_caller_are_kept():
    def mine(signum, frame):
        raise RuntimeError("mine")

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        with interrupts.handling_signals():
            assert signal.getsignal(signal.SIGTERM) is mine
            assert signal.getsignal(signal.SIGINT) is not signal.default_int_handler
        assert signal.getsignal(signal.SIGTERM) is mine
    finally:
        signal.signal(signal.SIGTERM, previous)


# ------------------------------------------------------------------------------ plan, in process
def test_interrupt_before_the_solve_keeps_the_previous_results(tmp_path, capsys, monkeypatch):
    from balance_opt.app import pipeline

    task = _fast_task(tmp_path)
    out, before = _previous_run(tmp_path, task)
    planned = []

    def ctrl_c(task):  # a real SIGINT while the reference is planned
        planned.append(task.name)
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5)
        pytest.fail("SIGINT did not interrupt the run")

    monkeypatch.setattr(pipeline, "plan_mission_only", ctrl_c)
    capsys.readouterr()
    assert main(["plan", str(task), "-m", "optimal", "-o", str(out), "--force"]) == 130
    assert planned and capsys.readouterr().err.splitlines()[-1] == "balance-opt: interrupted"
    assert _snapshot(out) == before
    _only_the_folder_beside(out, "task.yaml")


def test_interrupt_while_writing_keeps_the_previous_results(tmp_path, capsys, monkeypatch):
    from balance_opt.report import outputs

    task = _fast_task(tmp_path)
    out, before = _previous_run(tmp_path, task)
    real = outputs.write_trajectory_npz

    def torn(path, result, *args):  # a file half written when Ctrl-C comes
        real(path, result, *args)
        Path(path).write_bytes(Path(path).read_bytes()[:100])
        raise KeyboardInterrupt

    monkeypatch.setattr(outputs, "write_trajectory_npz", torn)
    capsys.readouterr()
    assert main(["simulate", str(task), "-m", "analytic", "-o", str(out), "--force"]) == 130
    assert "balance-opt: interrupted" in capsys.readouterr().err
    assert _snapshot(out) == before
    _only_the_folder_beside(out, "task.yaml")


def test_api_run_is_all_or_nothing(tmp_path, monkeypatch):
    from balance_opt.app.pipeline import run_task
    from balance_opt.report import outputs
    from balance_opt.tasks.task import load_task

    task = load_task(_fast_task(tmp_path))
    out = tmp_path / "api"

    def disk_full(path, metrics):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(outputs, "write_metrics", disk_full)
    with pytest.raises(OSError, match="No space left"):
        run_task(task, methods=("analytic",), output_dir=out)
    assert not out.exists()  # nothing half written
    monkeypatch.undo()
    run = run_task(task, methods=("analytic",), output_dir=out)
    assert run.report is None and all(p.parent == out for p in run.files)
    assert {p.name for p in out.iterdir()} == {p.name for p in run.files}
    from balance_opt.report.output_dir import OutputFolderError

    with pytest.raises(OutputFolderError, match="exists and is not empty; use --force"):
        run_task(task, methods=("analytic",), output_dir=out)
    run_task(task, methods=("analytic",), output_dir=out, force=True)


# ------------------------------------------------------------------------------ inside Ipopt
def _start_slow_solve(task: Path, out: Path) -> tuple[subprocess.Popen, list[str]]:
    """``balance-opt plan -m optimal`` started and inside Ipopt (a few iterations logged)."""
    args = ["plan", str(task), "-m", "optimal", "-o", str(out), "--force", "-v"]
    for option in SLOW_IPOPT:
        args += ["--solver-option", option]
    proc = subprocess.Popen(
        _cli(*args),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        bufsize=1,
        # SIGHUP as a terminal's command gets it: a test run under nohup would pass it on ignored
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL),
    )
    seen: list[str] = []
    deadline = time.monotonic() + START_TIMEOUT
    for line in proc.stdout:
        seen.append(line)
        match = IPOPT_ITERATION.match(line)
        if match and int(match.group(1)) >= 3:
            return proc, seen
        if time.monotonic() > deadline:
            break
    proc.kill()
    pytest.fail(f"Ipopt did not start: {''.join(seen[-20:])}{proc.stderr.read()}")


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_interrupt_inside_ipopt_exits_130_and_writes_nothing(tmp_path, signum):
    task = _fast_task(tmp_path, intervals=40)
    out, before = _previous_run(tmp_path, task)
    proc, _ = _start_slow_solve(task, out)
    try:
        proc.send_signal(signum)
        _, stderr = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert stderr.rstrip().splitlines()[-1] == "balance-opt: interrupted"
    assert "solver failure" not in stderr and "Traceback" not in stderr
    assert _snapshot(out) == before  # the half-converged iterate is not presented as a plan
    _only_the_folder_beside(out, "task.yaml")


@pytest.mark.slow
def test_second_run_into_the_same_folder_is_refused(tmp_path):
    task = _fast_task(tmp_path, intervals=40)
    out, before = _previous_run(tmp_path, task)
    first, _ = _start_slow_solve(task, out)
    try:
        second = subprocess.run(
            _cli("plan", str(task), "-m", "analytic", "-o", str(out), "--force"),
            capture_output=True,
            text=True,
            timeout=START_TIMEOUT,
            check=False,
        )
        assert second.returncode == 2
        assert (
            f"balance-opt: error: output folder {out} is being written by another balance-opt "
            f"run (process {first.pid}); wait for it to finish or choose another --output"
        ) in second.stderr
        assert _snapshot(out) == before
    finally:
        first.send_signal(signal.SIGINT)
        first.communicate(timeout=30)
    assert first.returncode == 130 and _snapshot(out) == before


# ------------------------------------------------------------------------------ sweep workers
def sleepy_case(case: dict) -> dict:
    """A case function that says it started (a file named by its process id in
    ``$SLEEPY_DIR``), then sleeps far longer than any test waits."""
    Path(os.environ["SLEEPY_DIR"], str(os.getpid())).write_text(str(case["index"]))
    time.sleep(600)
    return {"status": "ok", "metrics": {}}


def compiling_case(case: dict) -> dict:
    """A sleepy case that waits on a child command run as the kernels' compilers are (in a
    session of its own, which a signal to the sweep does not reach); the child writes its
    process id to ``$SLEEPY_DIR/child-<worker pid>``."""
    from balance_opt.cache import run_commands

    Path(os.environ["SLEEPY_DIR"], str(os.getpid())).write_text(str(case["index"]))
    child = Path(os.environ["SLEEPY_DIR"]).parent / f"child-{os.getpid()}"
    run_commands([["sh", "-c", f'echo $$ > "{child}"; exec sleep 600']])
    return {"status": "ok", "metrics": {}}


def _start_sleepy_sweep(tmp_path: Path, stdout=subprocess.DEVNULL, case="sleepy_case"):
    """A sweep of 6 sleepy cases on 2 workers, started in a session of its own; returns once
    both workers run a case, with the process and every descendant of it."""
    sweep = tmp_path / "sleepy.yaml"
    sweep.write_text(
        f"task: {PAPER_TASK}\nname: sleepy\nmethods: [analytic]\n"
        "grid:\n  mission.duration: [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]\n"
    )
    started = tmp_path / "started"
    started.mkdir()
    env = {
        **os.environ,
        "SLEEPY_DIR": str(started),
        "PYTHONPATH": os.pathsep.join(filter(None, [str(TESTS), os.environ.get("PYTHONPATH")])),
    }
    args = ["sweep", str(sweep), "-o", str(tmp_path / "out"), "-j", "2", "--no-plots"]
    proc = subprocess.Popen(
        _cli(*args, "--runner", f"test_interrupts:{case}"),
        stdout=stdout,
        stderr=subprocess.PIPE,
        env=env,
        start_new_session=True,
    )
    deadline = time.monotonic() + START_TIMEOUT
    while len(list(started.iterdir())) < 2:
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "the sweep did not start its cases"
        time.sleep(0.05)
    descendants = psutil.Process(proc.pid).children(recursive=True)
    workers = {int(p.name) for p in started.iterdir()}
    assert workers <= {p.pid for p in descendants}
    return proc, descendants


def _end_all(proc, descendants):
    for p in [*descendants]:
        try:
            p.kill()
        except psutil.NoSuchProcess:
            pass
    if proc.poll() is None:
        proc.kill()
    proc.wait()


@pytest.mark.slow
def test_sweep_workers_end_when_the_parent_is_killed(tmp_path):
    proc, descendants = _start_sleepy_sweep(tmp_path, stdout=subprocess.PIPE)
    eof = threading.Event()
    reader = threading.Thread(target=lambda: (proc.stdout.read(), eof.set()), daemon=True)
    reader.start()
    try:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        _gone, alive = psutil.wait_procs(descendants, timeout=10)
        assert alive == [], [p.cmdline() for p in alive]  # workers and resource tracker
        assert eof.wait(timeout=10), "a reader of the sweep's stdout (| tee) still waits"
    finally:
        _end_all(proc, descendants)


@pytest.mark.slow
@pytest.mark.parametrize("how", ["ctrl-c", "sigterm"])
def test_interrupted_sweep_returns_at_once_without_orphans(tmp_path, how):
    import json

    proc, descendants = _start_sleepy_sweep(tmp_path)
    try:
        if how == "ctrl-c":  # a terminal sends SIGINT to the whole process group
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        start = time.monotonic()
        code = proc.wait(timeout=30)
        took = time.monotonic() - start
        stderr = proc.stderr.read().decode()
        assert code == 130, stderr
        assert took < 5, f"returned after {took:.1f} s"
        assert stderr.rstrip().splitlines()[-1] == "balance-opt: interrupted"
        _gone, alive = psutil.wait_procs(descendants, timeout=10)
        assert alive == [], [p.cmdline() for p in alive]
        summary = json.loads((tmp_path / "out" / "summary.json").read_text())
        assert summary["interrupted"] is True and summary["cases"] == 0
    finally:
        _end_all(proc, descendants)


@pytest.mark.slow
def test_an_interrupted_sweep_ends_the_compilers_of_its_cases(tmp_path):
    """The workers' cases unwind on the sweep's SIGTERM: what they run in sessions of their own
    (the kernels' compilers, the bridge build) ends with them."""
    proc, descendants = _start_sleepy_sweep(tmp_path, case="compiling_case")
    commands = []
    try:
        deadline = time.monotonic() + START_TIMEOUT
        while len(children := list(tmp_path.glob("child-*"))) < 2 or not all(
            c.read_text().strip() for c in children
        ):
            assert time.monotonic() < deadline, "the cases did not start their commands"
            time.sleep(0.05)
        commands = [psutil.Process(int(c.read_text())) for c in children]
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=30) == 130
        _gone, alive = psutil.wait_procs(commands, timeout=10)
        assert alive == [], [p.cmdline() for p in alive]
    finally:
        _end_all(proc, descendants + [p for p in commands if p.is_running()])
