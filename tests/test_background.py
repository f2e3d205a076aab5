"""The run's worker process (app/background.py): simulations while the optimal plan is solved,
figures while the other files are written; the same files as a run in one process, errors
raised as they were, a dead worker's job done here, no worker left after an interruption."""

import json
import os
import signal
import subprocess
from pathlib import Path
from types import SimpleNamespace

import psutil
import pytest
from test_interrupts import SLOW_IPOPT, START_TIMEOUT, _cli, _fast_task

from balance_opt.app import background
from balance_opt.app.background import RunWorker
from balance_opt.cli import main
from balance_opt.errors import InputError

#: Variable naming the test process, so that a function can tell the worker from it.
PARENT = "BALANCE_OPT_TEST_PARENT_PID"


def _in_worker() -> bool:
    return os.getpid() != int(os.environ[PARENT])


def where(task, plan):
    """A stand-in simulation: says which process ran it."""
    return SimpleNamespace(robot=task.robot, plan=plan, worker=_in_worker())


def refuses(task, plan):
    raise InputError(f"simulation option 'kp' needs one value per arm joint (6), got {plan}")


def dies_in_worker(task, plan):
    if _in_worker():
        os._exit(3)
    return where(task, plan)


@pytest.fixture
def fake_task(monkeypatch):
    monkeypatch.setenv(PARENT, str(os.getpid()))
    return SimpleNamespace(name="fake", robot=("the", "robot"))


def test_worker_result_comes_back_with_the_parents_robot(fake_task):
    with RunWorker(fake_task, None) as worker:
        worker.submit_simulation("mission-only", where, [1, 2])
        assert worker.has_simulation("mission-only")
        sim, seconds = worker.simulation("mission-only")
        assert not worker.has_simulation("mission-only")
    assert sim.worker and sim.plan == [1, 2] and seconds >= 0
    assert sim.robot is fake_task.robot  # not a pickled copy


def test_worker_error_is_raised_in_the_parent(fake_task):
    with RunWorker(fake_task, None) as worker:
        worker.submit_simulation("analytic", refuses, 7)
        with pytest.raises(InputError, match=r"one value per arm joint \(6\), got 7"):
            worker.simulation("analytic")


def test_dead_worker_is_replaced_by_a_simulation_here(fake_task, caplog):
    with RunWorker(fake_task, None) as worker:
        worker.submit_simulation("analytic", dies_in_worker, 1)
        sim, _ = worker.simulation("analytic")
    assert not sim.worker and sim.plan == 1
    assert "the worker process died" in caplog.text


def _without_times(metrics):
    """metrics.json without wall times, the verbosity's Ipopt print level and which kernels
    ran (on a fresh cache the first run's are interpreted while the library compiles, a later
    run's compiled: the same numbers)."""
    if isinstance(metrics, dict):
        return {
            k: _without_times(v)
            for k, v in metrics.items()
            if "wall" not in k and not k.endswith("_s") and k not in ("print_level", "kernels")
        }
    if isinstance(metrics, list):
        return [_without_times(v) for v in metrics]
    return metrics


@pytest.mark.slow
def test_compare_in_the_background_writes_what_a_serial_run_writes(tmp_path, monkeypatch, caplog):
    task = _fast_task(tmp_path, intervals=20, outputs="{plots: true, report: true}")
    caplog.set_level("INFO")
    monkeypatch.setenv(background.WORKER_ENV, "1")
    assert main(["compare", str(task), "-o", str(tmp_path / "bg")]) == 0
    assert "forward-dynamics simulation of analytic: done in" in caplog.text
    assert "figures: done in" in caplog.text
    assert caplog.text.count("(worker process)") == 3  # two simulations, the figures
    monkeypatch.setenv(background.WORKER_ENV, "0")
    caplog.clear()
    assert main(["compare", str(task), "-o", str(tmp_path / "serial")]) == 0
    assert "(worker process)" not in caplog.text
    files = sorted(p.name for p in (tmp_path / "bg").iterdir())
    assert "report.html" in files and "attitude_simulated.png" in files
    assert files == sorted(p.name for p in (tmp_path / "serial").iterdir())
    for name in files:
        bg, serial = (tmp_path / where / name for where in ("bg", "serial"))
        if name.endswith((".csv", ".png")):
            assert bg.read_bytes() == serial.read_bytes(), name
    metrics = [json.loads((tmp_path / w / "metrics.json").read_text()) for w in ("bg", "serial")]
    simulated = [m["methods"]["analytic"]["simulation"] for m in metrics]
    assert simulated[0]["max_tracking_error_rad"] > 0
    assert _without_times(metrics[0]) == _without_times(metrics[1])


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_compare_leaves_no_worker(tmp_path, signum):
    task = _fast_task(tmp_path, intervals=40)
    out = tmp_path / "out"
    args = ["compare", str(task), "-o", str(out), "-v"]
    for option in SLOW_IPOPT:
        args += ["--solver-option", option]
    env = {**os.environ, background.WORKER_ENV: "1"}
    proc = subprocess.Popen(
        _cli(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )
    try:
        deadline = psutil.time.monotonic() + START_TIMEOUT
        for line in proc.stdout:  # Ipopt's log: the optimal plan is being solved
            if line.lstrip().startswith("10 ") or psutil.time.monotonic() > deadline:
                break
        workers = psutil.Process(proc.pid).children(recursive=True)
        assert workers, "no worker process during the optimal solve"
        proc.send_signal(signum)
        _, stderr = proc.communicate(timeout=30)
        _gone, alive = psutil.wait_procs(workers, timeout=10)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert stderr.rstrip().splitlines()[-1] == "balance-opt: interrupted"
    assert alive == [], [p.cmdline() for p in alive]
    assert not out.exists() and sorted(p.name for p in Path(tmp_path).iterdir()) == ["task.yaml"]


@pytest.mark.parametrize(
    ("setting", "cpus", "load", "pays"),
    [
        ("", 2, 0.3, True),
        ("", 2, 1.8, True),
        ("", 2, 2.5, False),
        ("", 1, 0.0, False),
        ("", 8, 5.0, True),
        ("0", 8, 0.0, False),
        ("1", 1, 9.0, True),
    ],
)
def test_worker_only_when_a_cpu_is_idle_or_asked_for(monkeypatch, setting, cpus, load, pays):
    monkeypatch.setenv(background.WORKER_ENV, setting)
    monkeypatch.setattr(background, "usable_cpus", lambda: cpus)
    monkeypatch.setattr(os, "getloadavg", lambda: (load, load, load))
    assert background.worker_pays() is pays
