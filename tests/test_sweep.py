"""Sweeps: sweep files and their cases, the engines (process pool, Dask on loopback), failing
and crashing cases, resume after an interruption, the same table whatever the number of
workers, the report.

The engine mechanics are tested with small case functions defined here (``toy_case``,
imported by name in the worker processes); the end-to-end tests run the real planners on the
paper's task with tiny horizons.
"""

import csv
import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from balance_opt.config.yaml_lines import TaskFileError, format_path
from balance_opt.sweep.engine import (
    STATUS_OK,
    LocalPoolEngine,
    read_result,
    result_path,
    run_cases,
    write_json_atomic,
)
from balance_opt.sweep.report import diagnostics_table, is_timing_column, results_table
from balance_opt.sweep.run import run_sweep
from balance_opt.sweep.spec import (
    apply_overrides,
    case_id_from,
    load_sweep,
    parameter_columns,
    parse_key_path,
    parse_sweep,
)

ROOT = Path(__file__).resolve().parents[1]
PAPER_TASK = ROOT / "examples" / "capture_task.yaml"
TOY_RUNNER = "test_sweep:toy_case"
#: Joint-rate excess within the solver's tolerance [rad/s].
LIMIT_SLACK = 1e-6
#: Seconds a test waits for a subprocess sweep before giving up.
SUBPROCESS_TIMEOUT = 120


def read_table_csv(path) -> tuple[list[str], list[dict[str, str]]]:
    """Columns and rows (as text) of a table the sweep wrote."""
    with Path(path).open(newline="") as f:
        reader = csv.DictReader(f)
        return list(reader.fieldnames or []), list(reader)


# ------------------------------------------------------------------------------ toy case function
def toy_case(case: dict) -> dict:
    """A case function with the runner's contract: ``x`` gives the drift, ``fail`` raises,
    ``crash`` kills the worker process, ``sleep`` [s] takes time."""
    p = case["parameters"]
    if p.get("fail"):
        raise ValueError(f"case {case['index']} was asked to fail")
    if p.get("crash"):
        os._exit(3)
    time.sleep(p.get("sleep", 0.0))
    x = float(p.get("x", 0.0))
    return {
        "status": STATUS_OK,
        "metrics": {
            "max_drift_rad": 1e-3 * (1 + x * x),
            "final_drift_rad": 1e-4 * (1 + x),
            "solver": {"solve_time_s": time.perf_counter()},
        },
        "info": {"pid": os.getpid()},
    }


def toy_cases(n: int, **flags) -> list[dict]:
    """``n`` toy cases; ``flags`` maps a parameter name to the indices where it is set."""
    cases = []
    for i in range(n):
        params = {"x": float(i)}
        params.update({name: True for name, where in flags.items() if i in where})
        cases.append(
            {
                "index": i,
                "case_id": case_id_from("optimal", params, "toy"),
                "method": "optimal",
                "parameters": params,
            }
        )
    return cases


@pytest.fixture
def tests_on_path(monkeypatch):
    """Worker processes import ``test_sweep`` by name: put this folder on their path."""
    here = str(Path(__file__).resolve().parent)
    monkeypatch.setenv(
        "PYTHONPATH", os.pathsep.join(p for p in (here, os.environ.get("PYTHONPATH")) if p)
    )
    if here not in sys.path:
        monkeypatch.syspath_prepend(here)
    return here


# ------------------------------------------------------------------------------ key paths
@pytest.mark.parametrize(
    "text, path",
    [
        ("mission.goal", ("mission", "goal")),
        ("mission.goal[2]", ("mission", "goal", 2)),
        ("limits.balance_joint1.velocity", ("limits", "balance_joint1", "velocity")),
        ("mission.points[1][0]", ("mission", "points", 1, 0)),
    ],
)
def test_key_path_round_trip(text, path):
    assert parse_key_path(text) == path
    assert format_path(path) == text


@pytest.mark.parametrize("text", ["", ".a", "a.", "a..b", "[0]", "a b", "a.[0]", "a[x]"])
def test_bad_key_path(text):
    with pytest.raises(ValueError, match=re.escape(f"'{text}' is not a key path")):
        parse_key_path(text)


def test_apply_overrides_creates_mappings_and_copies():
    base = {"mission": {"goal": [1.0, 2.0, 3.0]}, "limits": {}}
    out = apply_overrides(
        base, {"mission.goal[1]": 9.0, "limits.j1.velocity": 0.5, "initial.balance": [0, 1]}
    )
    assert out == {
        "mission": {"goal": [1.0, 9.0, 3.0]},
        "limits": {"j1": {"velocity": 0.5}},
        "initial": {"balance": [0, 1]},
    }
    assert base == {"mission": {"goal": [1.0, 2.0, 3.0]}, "limits": {}}
    with pytest.raises(
        KeyError, match=re.escape("parameter 'mission.goal[5]': mission.goal has no item [5]")
    ):
        apply_overrides(base, {"mission.goal[5]": 1.0})
    with pytest.raises(
        KeyError, match=re.escape("parameter 'mission.goal.x': mission.goal is not a mapping")
    ):
        apply_overrides(base, {"mission.goal.x": 1.0})


def test_parameter_columns_spread_lists():
    assert parameter_columns({"a.b": [1.0, [2.0, 3.0]], "c": {"d": 4}, "e": "x"}) == {
        "a.b[0]": 1.0,
        "a.b[1][0]": 2.0,
        "a.b[1][1]": 3.0,
        "c.d": 4,
        "e": "x",
    }


# ------------------------------------------------------------------------------ sweep files
SWEEP = f"""\
task: {PAPER_TASK}
name: small
methods: [analytic, optimal]
grid:
  mission.duration: [5.0, 10.0]
cases:
  - {{initial.balance: [0.0, 0.5, -1.0]}}
  - {{initial.balance: [0.3, 0.8, -1.4]}}
random:
  seed: 11
  samples: 3
  parameters:
    mission.goal: {{uniform: [[0.8, 0.5, -1.8], [1.4, 1.1, -1.2]]}}
    limits.balance_joint1.velocity: {{choice: [0.5, 1.0]}}
"""


def test_expansion_order_ids_and_samples(tmp_path):
    sweep = parse_sweep(SWEEP, "small.yaml", tmp_path)
    assert sweep.name == "small"
    assert sweep.varied == (
        "mission.duration",
        "initial.balance",
        "mission.goal",
        "limits.balance_joint1.velocity",
    )
    assert len(sweep.cases) == 2 * 2 * 3 * 2
    assert [c["index"] for c in sweep.cases] == list(range(24))
    # grid outermost, then the list, then the samples, then the methods
    first = sweep.cases[:2]
    assert [c["method"] for c in first] == ["analytic", "optimal"]
    assert first[0]["parameters"] == first[1]["parameters"]
    assert first[0]["parameters"]["mission.duration"] == 5.0
    assert sweep.cases[-1]["parameters"]["mission.duration"] == 10.0
    assert sweep.cases[-1]["parameters"]["initial.balance"] == [0.3, 0.8, -1.4]
    # the parameters are in the case's task
    case = sweep.cases[5]
    assert case["task"]["mission"]["goal"] == case["parameters"]["mission.goal"]
    assert case["task"]["limits"]["balance_joint1"] == {
        "acceleration": 2.0,
        "velocity": case["parameters"]["limits.balance_joint1.velocity"],
    }
    assert case["task"]["limits"]["balance_joint2"] == {"acceleration": 2.0}
    # seeded samples inside their bounds, the same in every grid and list cell
    goals = np.array([c["parameters"]["mission.goal"] for c in sweep.cases])
    assert np.all(goals >= [0.8, 0.5, -1.8]) and np.all(goals <= [1.4, 1.1, -1.2])
    assert len({json.dumps(g) for g in goals.tolist()}) == 3
    rng = np.random.default_rng(11)
    expected_first = rng.uniform([0.8, 0.5, -1.8], [1.4, 1.1, -1.2])
    np.testing.assert_allclose(goals[0], expected_first, rtol=0, atol=0)
    # ids: unique, stable across loads, hash of method + parameters + setup
    ids = [c["case_id"] for c in sweep.cases]
    assert len(set(ids)) == len(ids)
    assert ids == [c["case_id"] for c in parse_sweep(SWEEP, "other-name.yaml", tmp_path).cases]
    assert ids[0] == case_id_from("analytic", sweep.cases[0]["parameters"], sweep.setup_hash)
    # a different seed, the solver options or simulate change the ids
    assert (
        parse_sweep(SWEEP.replace("seed: 11", "seed: 12"), "s.yaml", tmp_path).cases[0]["case_id"]
        != ids[0]
    )
    assert parse_sweep(SWEEP, "s.yaml", tmp_path, {"max_iter": 5}).cases[0]["case_id"] != ids[0]
    assert parse_sweep(SWEEP + "simulate: true\n", "s.yaml", tmp_path).cases[0]["case_id"] != ids[0]


def test_inline_task_and_no_parameters(tmp_path):
    inline = "task:\n" + "".join(f"  {line}\n" for line in PAPER_TASK.read_text().splitlines())
    sweep = parse_sweep(inline + "methods: [optimal]\n", "inline.yaml", tmp_path)
    assert [(c["index"], c["method"], c["parameters"]) for c in sweep.cases] == [(0, "optimal", {})]
    assert sweep.cases[0]["task"]["mission"]["goal"] == [1.2, 0.9, -1.6]


def _line(text: str, fragment: str) -> int:
    return next(i for i, line in enumerate(text.splitlines(), 1) if fragment in line)


BAD_SWEEPS = [
    (
        (
            "random:\n  seed: 1\n  samples: 1000000000\n  parameters:\n"
            "    mission.duration: {uniform: [5, 10]}\n"
        ),
        "^task",
        "(top level): the sweep expands to 2000000000 cases, more than the 1000000 allowed",
    ),
    (
        "grid:\n  mission.duraton: [5.0]\n",
        "mission.duraton",
        (
            "grid.mission.duraton: mission.duraton = 5.0 (case 0): unknown key 'duraton'; "
            "expected one of type, "
            "start, goal, duration, timing; did you mean 'duration'?"
        ),
    ),
    (
        "grid:\n  mission.duration: [5.0, -1.0]\n",
        "mission.duration",
        "grid.mission.duration: mission.duration = -1.0 (case 2): must be greater than 0 s, got -1",
    ),
    (
        "cases:\n  - {initial.balance: [0.1, 0.2]}\n",
        "initial.balance",
        (
            "cases[0].initial.balance: initial.balance = [0.1,0.2] (case 0): "
            "expected 3 values (one per balance "
            "joint: balance_joint1, balance_joint2, balance_joint3), got 2"
        ),
    ),
    (
        "grid:\n  mission..goal: [1]\n",
        "mission..goal",
        "grid.mission..goal: 'mission..goal' is not a key path",
    ),
    (
        "grid:\n  mission.duration: []\n",
        "mission.duration",
        "grid.mission.duration: expected at least one value",
    ),
    (
        "methods: [analytic, optim]\n",
        "methods",
        "methods[1]: expected one of 'analytic', 'optimal', got 'optim'",
    ),
    (
        (
            "random:\n  seed: 1\n  samples: 2\n  parameters:\n"
            "    mission.goal: {uniform: [[0, 0], [1, 1, 1]]}\n"
        ),
        "mission.goal",
        "random.parameters.mission.goal: low has shape (2,) but high has (3,)",
    ),
    (
        "random:\n  seed: 1\n  samples: 2\n  parameters:\n    mission.goal: {uniform: [1, 0]}\n",
        "mission.goal",
        "random.parameters.mission.goal: low must not exceed high",
    ),
    (
        (
            "random:\n  seed: 1\n  samples: 2\n  parameters:\n"
            "    mission.duration: {uniform: [1, 2], choice: [3]}\n"
        ),
        "mission.duration",
        (
            "random.parameters.mission.duration: expected exactly one of uniform, normal, choice, "
            "integers; got uniform, choice"
        ),
    ),
    (
        "cases:\n  - {mission.duration: 3.0}\n  - {mission.duration: 3.0}\n",
        "^task",
        '(top level): case 2 (analytic, {"mission.duration":3.0}) is the same as case 0',
    ),
    (
        "grid:\n  mission.duration: [3.0]\ncases:\n  - {mission.duration: 4.0}\n",
        "mission.duration: [3.0]",
        (
            "grid.mission.duration: parameter 'mission.duration' is varied in more than one of grid, "
            "cases and random"
        ),
    ),
    ("grid:\n  method: [analytic]\n", "method:", "grid.method: the method is not a task parameter"),
    ("gird:\n  mission.duration: [3.0]\n", "gird", "gird: unknown key 'gird'"),
]


@pytest.mark.parametrize(
    "tail, culprit, message", BAD_SWEEPS, ids=[b[1] + str(i) for i, b in enumerate(BAD_SWEEPS)]
)
def test_bad_sweep_files_name_file_line_and_key(tmp_path, tail, culprit, message):
    text = f"task: {PAPER_TASK}\n{tail}"
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    line = 1 if culprit == "^task" else _line(text, culprit)
    with pytest.raises(TaskFileError, match=re.escape(f"{path}:{line}: {message}")):
        load_sweep(path)


def test_bad_base_task_is_located_in_its_file(tmp_path):
    task = tmp_path / "task.yaml"
    task.write_text(PAPER_TASK.read_text().replace("duration: 10.0", "duration: ten"))
    (tmp_path / "s.yaml").write_text("task: task.yaml\n")
    line = _line(task.read_text(), "duration: ten")
    with pytest.raises(
        TaskFileError, match=re.escape(f"{task}:{line}: mission.duration: expected a number")
    ):
        load_sweep(tmp_path / "s.yaml")
    (tmp_path / "s.yaml").write_text("task: nowhere.yaml\n")
    with pytest.raises(
        TaskFileError, match=re.escape(f"{tmp_path / 's.yaml'}:1: task: no task file")
    ):
        load_sweep(tmp_path / "s.yaml")


def test_infeasible_case_is_left_to_fail_when_it_runs(tmp_path):
    """A start outside the limits is a result of the study, not an error of the file."""
    sweep = parse_sweep(
        f"task: {PAPER_TASK}\ncases:\n  - {{initial.balance: [9.0, 0.5, -1.0]}}\n",
        "s.yaml",
        tmp_path,
    )
    assert len(sweep.cases) == 2


# ------------------------------------------------------------------------------ result files
def test_atomic_write_and_read_back(tmp_path):
    record = {"case_id": "abc", "index": 0, "status": STATUS_OK, "x": 0.1 + 0.2}
    write_json_atomic(result_path(tmp_path, "abc"), record)
    assert read_result(tmp_path, "abc") == record
    assert [p.name for p in (tmp_path / "cases").iterdir()] == ["abc.json"]  # no temporary left
    result_path(tmp_path, "torn").write_text('{"case_id": "torn", "sta')  # not a whole record
    assert read_result(tmp_path, "torn") is None
    assert read_result(tmp_path, "missing") is None


# ------------------------------------------------------------------------------ engines (toy cases)
@pytest.mark.slow
def test_pool_records_failing_and_crashing_cases_and_goes_on(tmp_path, tests_on_path):
    cases = toy_cases(7, fail={2}, crash={4})
    run = run_cases(cases, TOY_RUNNER, tmp_path, LocalPoolEngine(2))
    assert [r["index"] for r in run.results] == list(range(7))
    status = {r["index"]: (r["status"], (r["error"] or {}).get("type")) for r in run.results}
    assert status == {
        0: ("ok", None),
        1: ("ok", None),
        2: ("error", "ValueError"),
        3: ("ok", None),
        4: ("error", "WorkerCrashed"),
        5: ("ok", None),
        6: ("ok", None),
    }
    failed = read_result(tmp_path, cases[2]["case_id"])
    assert failed["error"]["message"] == "case 2 was asked to fail"
    assert "ValueError: case 2 was asked to fail" in failed["error"]["traceback"]
    assert failed["metrics"] == {}
    ok = read_result(tmp_path, cases[6]["case_id"])
    assert ok["metrics"]["max_drift_rad"] == pytest.approx(1e-3 * 37, rel=0, abs=1e-15)
    assert ok["timing"]["pid"] != os.getpid()  # ran in a worker process


@pytest.mark.slow
def test_resume_skips_finished_cases_after_an_interruption(tmp_path, tests_on_path):
    """Stop a sweep after three results (as Ctrl-C would), then resume it."""
    cases = toy_cases(8, fail={1})
    seen = []

    def stop_after_three(record, done, total):
        seen.append(record["case_id"])
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_cases(cases, TOY_RUNNER, tmp_path, LocalPoolEngine(2), on_result=stop_after_three)
    on_disk = sorted(p.stem for p in (tmp_path / "cases").glob("*.json"))
    assert on_disk == sorted(seen) and len(seen) == 3
    before = {cid: result_path(tmp_path, cid).read_bytes() for cid in seen}

    run = run_cases(cases, TOY_RUNNER, tmp_path, LocalPoolEngine(2), resume=True)
    assert sorted(run.skipped) == sorted(seen)
    assert sorted(run.ran) == sorted({c["case_id"] for c in cases} - set(seen))
    assert [r["index"] for r in run.results] == list(range(8))
    assert all(result_path(tmp_path, cid).read_bytes() == before[cid] for cid in seen)  # untouched
    # a resume with nothing left runs nothing; --retry-failed runs the failed case again
    again = run_cases(cases, TOY_RUNNER, tmp_path, LocalPoolEngine(1), resume=True)
    assert again.ran == [] and len(again.skipped) == 8
    retry = run_cases(
        cases, TOY_RUNNER, tmp_path, LocalPoolEngine(1), resume=True, retry_failed=True
    )
    assert retry.ran == [cases[1]["case_id"]]


@pytest.mark.slow
def test_resume_after_the_process_is_killed(tmp_path, tests_on_path):
    """Kill a running ``balance-opt sweep`` (parent and workers, SIGKILL), then ``--resume``.
    The cases after the first three wait for a file to go (:func:`held_toy_case`), so the kill
    finds exactly three records however slow the machine is."""
    sweep_file = tmp_path / "toy.yaml"
    sweep_file.write_text(
        f"task: {PAPER_TASK}\nname: toy\nmethods: [optimal]\ngrid:\n"
        f"  mission.duration: [{', '.join(str(1.0 + i) for i in range(10))}]\n"
    )
    out = tmp_path / "out"
    hold = tmp_path / "hold"
    hold.touch()
    cmd = [sys.executable, "-m", "balance_opt.cli", "sweep", str(sweep_file), "-o", str(out)]
    cmd += ["-j", "2", "--runner", "test_sweep:held_toy_case", "--no-plots"]
    proc = subprocess.Popen(
        cmd,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env={**os.environ, HOLD_ENV: str(hold)},
    )
    try:
        deadline = time.monotonic() + SUBPROCESS_TIMEOUT
        while len(list((out / "cases").glob(RECORDS))) < 3:
            assert proc.poll() is None, proc.stderr.read().decode()
            assert time.monotonic() < deadline, "the sweep did not start"
            time.sleep(0.05)
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=SUBPROCESS_TIMEOUT)
    done = {p.stem: p.read_bytes() for p in (out / "cases").glob(RECORDS)}
    assert len(done) == 3
    assert all(json.loads(b)["status"] == STATUS_OK for b in done.values())  # whole records only

    from balance_opt.cli import main

    again = ["sweep", str(sweep_file), "-o", str(out), "-j", "2", "--no-plots"]
    again += ["--runner", "test_sweep:held_toy_case"]  # nothing held in this process
    assert main(again) == 2  # not without --resume
    assert main([*again, "--resume"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    # the finished cases are skipped and kept as they were, the others run
    assert (summary["skipped"], summary["ran"]) == (3, 7)
    assert all((out / "cases" / f"{cid}.json").read_bytes() == b for cid, b in done.items())
    _columns, rows = read_table_csv(out / "results.csv")
    assert [int(r["index"]) for r in rows] == list(range(10))
    assert {r["status"] for r in rows} == {"ok"}


#: The case records of a sweep folder (not a record being written: ``.<id>.<pid>.tmp.json``).
RECORDS = "[!.]*.json"
#: A file whose existence holds :func:`held_toy_case`'s cases after the first three.
HOLD_ENV = "BALANCE_OPT_TEST_HOLD"


def held_toy_case(case: dict) -> dict:
    """``toy_case``; the cases after the first three wait while the file named by
    :data:`HOLD_ENV` exists (at most :data:`SUBPROCESS_TIMEOUT`)."""
    hold = os.environ.get(HOLD_ENV)
    deadline = time.monotonic() + SUBPROCESS_TIMEOUT
    while hold and case["index"] >= 3 and Path(hold).exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    return toy_case(case)


def _deterministic(path):
    columns, rows = read_table_csv(path)
    keep = [c for c in columns if not is_timing_column(c)]
    return keep, [[row[c] for c in keep] for row in rows]


def test_table_order_and_timing_columns():
    results = [
        {
            "index": 1,
            "case_id": "b",
            "method": "optimal",
            "parameters": {"p": [1.0, 2.0]},
            "status": "ok",
            "error": None,
            "metrics": {"max_drift_rad": 0.1, "solver": {"solve_time_s": 3.0, "iterations": 7}},
            "timing": {"case_s": 1.0, "pid": 5},
        },
        {
            "index": 0,
            "case_id": "a",
            "method": "analytic",
            "parameters": {"p": [0.0, 2.0]},
            "status": "error",
            "error": {"type": "X", "message": "m"},
            "metrics": {},
            "timing": {"case_s": 1.0, "pid": 6},
        },
    ]
    columns, rows = results_table(results)
    assert columns == [
        "index",
        "case_id",
        "method",
        "status",
        "param.p[0]",
        "param.p[1]",
        "max_drift_rad",
        "solver.iterations",
        "mission_only.max_drift_rad",
        "mission_only.final_drift_rad",
        "mission_only.max_base_rate_rad_s",
        "error_type",
        "error_message",
        "time.case_s",
        "time.cpu_s",
        "time.plan_s",
        "time.baseline_s",
    ]
    assert [r["case_id"] for r in rows] == ["a", "b"]
    assert [c for c in columns if is_timing_column(c)] == [
        "time.case_s",
        "time.cpu_s",
        "time.plan_s",
        "time.baseline_s",
    ]
    columns, rows = diagnostics_table(results)
    assert columns == [
        "index",
        "case_id",
        "method",
        "error_traceback",
        "time.pid",  # first seen in case a (index 0)
        "solver.solve_time_s",
    ]
    assert [(r["case_id"], r["time.pid"]) for r in rows] == [("a", 6), ("b", 5)]


def test_the_two_tables_hold_every_recorded_value_once():
    """Every metric, error and timing value of a record is in exactly one of the two tables."""
    record = {
        "index": 0,
        "case_id": "c",
        "method": "optimal",
        "parameters": {"mission.goal": [1.0, 0.5, -1.5]},
        "status": "ok",
        "error": {"type": "T", "message": "m", "traceback": "tb"},
        "metrics": {
            "method": "optimal",
            "max_drift_rad": 0.02,
            "limit_margins": {"j1": {"position": 0.3}},
            "solver": {"iterations": 9, "wall_time_s": {"solve": 0.4}},
            "details": {"kernels": {"library": "/x.so"}},
        },
        "info": {"mission_only": {"max_drift_rad": 0.09, "final_drift_rad": 0.08}},
        "timing": {"case_s": 1.0, "cpu_s": 0.9, "plan_s": 0.8, "pid": 7, "planner_solve_s": 0.4},
    }
    (_, (tidy,)), (_, (diag,)) = results_table([record]), diagnostics_table([record])
    shared = {"index", "case_id", "method"}
    assert not (set(tidy) & set(diag)) - shared
    metrics = parameter_columns(record["metrics"], lists=False)
    del metrics["method"]
    for name, value in metrics.items():
        assert (tidy.get(name), diag.get(name)).count(value) == 1, name
    assert (
        tidy["mission_only.max_drift_rad"] == 0.09
        and tidy["mission_only.max_base_rate_rad_s"] is None
    )
    assert (tidy["error_type"], tidy["error_message"], diag["error_traceback"]) == ("T", "m", "tb")
    assert (tidy["time.plan_s"], diag["time.pid"], diag["time.planner_solve_s"]) == (0.8, 7, 0.4)
    assert diag["details.kernels.library"] == "/x.so"
    assert tidy["param.mission.goal[2]"] == -1.5


def test_mission_only_baseline_is_the_mission_only_plan():
    """The sweep's cheap baseline (200 RK4 steps) against ``plan --method mission-only``
    (the task's adaptive integrator, 1e-10)."""
    from balance_opt.app.pipeline import plan
    from balance_opt.sweep.runner import mission_only_baseline
    from balance_opt.tasks.task import load_task

    task = load_task(PAPER_TASK)
    reference = plan(task, "mission-only").summary()
    baseline = mission_only_baseline(task)
    assert baseline["max_drift_rad"] > 0.05  # the paper task's mission turns the base
    for key in ("max_drift_rad", "final_drift_rad"):
        assert baseline[key] == pytest.approx(reference[key], rel=1e-8), key
    # the peak rate is sampled every 0.05 s instead of every 0.01 s
    assert baseline["max_base_rate_rad_s"] == pytest.approx(reference["max_base_rate_rad_s"], 1e-4)


# ------------------------------------------------------------------------- real cases, end to end
#: The capture task, short and coarse: a few optimal cases solve in well under a second each.
REAL_SWEEP = f"""\
task: {PAPER_TASK}
name: e2e
methods: [analytic, optimal]
grid:
  optimal.intervals: [12]
cases:
  - {{initial.balance: [0.0, 0.5, -1.0]}}
  - {{initial.balance: [9.0, 0.5, -1.0]}}   # outside the limits of balance_joint1: fails
  - {{initial.balance: [0.3, 0.8, -1.4]}}
"""
#: Longest a Dask sweep of the tests may take [s].
DASK_TIMEOUT = 120


@pytest.fixture(scope="module")
def real_sweep(tmp_path_factory):
    path = tmp_path_factory.mktemp("real") / "e2e.yaml"
    path.write_text(REAL_SWEEP)
    return path


@pytest.fixture(scope="module")
def pool_run(real_sweep):
    """The real sweep through the command line, on a pool of 2 worker processes."""
    from balance_opt.cli import main

    out = real_sweep.parent / "pool2"
    code = main(["sweep", str(real_sweep), "-o", str(out), "--jobs", "2"])
    return code, out


@pytest.mark.slow
def test_pool_end_to_end_through_the_cli(pool_run):
    code, out = pool_run
    assert code == 1  # some cases failed: their errors are in the table
    manifest = json.loads((out / "sweep.json").read_text())
    assert [c["index"] for c in manifest["cases"]] == list(range(6))
    _columns, rows = read_table_csv(out / "results.csv")
    assert [int(r["index"]) for r in rows] == list(range(6))
    assert [r["method"] for r in rows] == ["analytic", "optimal"] * 3
    assert [r["case_id"] for r in rows] == [c["case_id"] for c in manifest["cases"]]
    for r in rows:
        assert (out / "cases" / f"{r['case_id']}.json").is_file()
    failed = [r for r in rows if r["param.initial.balance[0]"] == "9.0"]
    assert [r["status"] for r in failed] == ["error", "error"]
    assert {r["error_type"] for r in failed} == {"TaskLimitsError"}
    assert all(
        "balance joint 'balance_joint1' starts at 9 rad, outside its position limits"
        in r["error_message"]
        for r in failed
    )
    good = [r for r in rows if r not in failed]
    assert all(r["status"] == "ok" for r in good), [(r["status"], r["error_message"]) for r in good]
    for r in good:  # the metrics of metrics.json, per case
        assert 0 <= float(r["final_drift_rad"]) <= float(r["max_drift_rad"]) < 1.0
        assert float(r["duration_s"]) == pytest.approx(10.0, rel=0, abs=1e-9)
        assert int(r["limit_violations"]) >= 0
        assert float(r["time.case_s"]) > 0
    for a, b in zip(good[::2], good[1::2]):  # analytic and optimal of one set: one baseline
        assert a["mission_only.max_drift_rad"] == b["mission_only.max_drift_rad"] != ""
    optimal = [r for r in good if r["method"] == "optimal"]
    assert all(int(r["solver.iterations"]) > 0 for r in optimal)
    for r in optimal:  # the optimal plan ends far stiller than the mission arm alone
        assert float(r["final_drift_rad"]) < 0.5 * float(r["mission_only.final_drift_rad"])
    _columns, diagnostics = read_table_csv(out / "diagnostics.csv")
    assert [d["case_id"] for d in diagnostics] == [r["case_id"] for r in rows]
    assert all(d["time.pid"] for d in diagnostics)
    assert all(d["details.kernels.library"] for d, r in zip(diagnostics, rows) if r in optimal)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["cases"] == 6 and summary["status"] == {"error": 2, "ok": 4}
    assert summary["ran"] == 6 and summary["skipped"] == 0 and summary["workers"] == 2
    plots = sorted(p.name for p in (out / "plots").glob("*.png"))
    assert plots == [
        "drift_distribution.png",
        "drift_vs_initial.balance.png",
        "drift_vs_optimal.intervals.png",
    ]


@pytest.mark.slow
def test_same_table_with_one_worker(pool_run, real_sweep):
    """Same results whatever the number of workers (timing columns aside)."""
    _, out2 = pool_run
    out1 = real_sweep.parent / "pool1"
    outcome = run_sweep(load_sweep(real_sweep), out1, jobs=1, plots=False)
    assert outcome.run.workers == 1
    assert len({r["timing"]["pid"] for r in outcome.run.results if r["timing"]["pid"]}) == 1
    assert _deterministic(out1 / "results.csv") == _deterministic(out2 / "results.csv")


@pytest.mark.slow
def test_dask_local_cluster_on_loopback(pool_run, real_sweep):
    """A real Dask cluster (2 worker processes on 127.0.0.1), started and stopped by the sweep."""
    import psutil

    from balance_opt.sweep.engine import DaskEngine

    _, out2 = pool_run
    out = real_sweep.parent / "dask"
    engine = DaskEngine(None, workers=2, host="127.0.0.1", timeout=DASK_TIMEOUT)
    outcome = run_sweep(load_sweep(real_sweep), out, engine=engine, plots=False)
    assert outcome.summary["engine"] == "Dask (local cluster on 127.0.0.1), 2 worker(s)"
    assert outcome.run.workers == 2 and len(outcome.run.ran) == 6
    assert _deterministic(out / "results.csv") == _deterministic(out2 / "results.csv")
    # the cluster is gone: no worker process left behind (multiprocessing's resource tracker
    # lives as long as this process, by design)
    assert engine._cluster is None and engine._client is None

    def workers_left():
        return [
            p
            for p in psutil.Process().children(recursive=True)
            if "resource_tracker" not in " ".join(p.cmdline())
        ]

    deadline = time.monotonic() + 30
    while workers_left() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert workers_left() == []


@pytest.mark.slow
def test_dask_forgets_a_case_once_its_record_is_taken():
    """Dask keeps a result as long as a future refers to it, and computes it again when the
    worker holding it dies: the engine holds no future of a case whose record it has handed on
    (only the current one, until the next is asked for)."""
    from balance_opt.sweep.engine import DaskEngine

    cases = toy_cases(4)
    held = []
    with DaskEngine(None, workers=1, timeout=DASK_TIMEOUT) as engine:
        for k, _ in enumerate(engine.imap_unordered(TOY_RUNNER, cases)):
            deadline = time.monotonic() + 10  # a released future leaves the client's table soon
            while len(engine._client.futures) > len(cases) - k and time.monotonic() < deadline:
                time.sleep(0.05)
            held.append(len(engine._client.futures))
    assert held == [4, 3, 2, 1]


def test_a_urdfs_warnings_are_shown_once_per_sweep_not_per_case(tmp_path, caplog):
    """Every case of a sweep builds its robot from the one URDF: its implausible values are
    logged when the sweep is loaded, not again for each case checked and run."""
    urdf = (ROOT / "urdf" / "paper_robot.urdf").read_text()
    moments = 'ixx="0.1062" ixy="0" ixz="0" iyy="0.1062" iyz="0" izz="0.16"'
    assert moments in urdf
    (tmp_path / "robot.urdf").write_text(urdf.replace(moments, moments.replace("0.16", "0.25"), 1))
    task = PAPER_TASK.read_text().replace("shipped: paper_robot.urdf", "urdf: robot.urdf")
    (tmp_path / "task.yaml").write_text(task)
    (tmp_path / "sweep.yaml").write_text(
        "task: task.yaml\nmethods: [analytic]\ngrid:\n  mission.duration: [4.0, 5.0, 6.0]\n"
    )
    with caplog.at_level("WARNING", logger="balance_opt"):
        outcome = run_sweep(load_sweep(tmp_path / "sweep.yaml"), tmp_path / "out", jobs=0)
    assert len(outcome.run.ran) == 3
    warned = [r for r in caplog.records if "triangle inequality" in r.getMessage()]
    assert len(warned) == 1, [r.getMessage() for r in warned]


def test_model_cache_key_is_the_kinematics_not_the_limits():
    """Robots that differ only in their limits share a planner model; other locked positions
    (another inertia of the locked chain) or another robot do not."""
    from balance_opt import baxter_floating, paper_robot
    from balance_opt.app.models import kinematics_key

    tight = paper_robot(limits={"balance_joint1": {"velocity": 0.3}})
    assert kinematics_key(paper_robot()) == kinematics_key(tight)
    assert kinematics_key(paper_robot()) != kinematics_key(baxter_floating())
    assert kinematics_key(baxter_floating()) != kinematics_key(
        baxter_floating(locked={"head_pan": 0.5})
    )


def test_plan_dispatch_rejects_an_unknown_method():
    from balance_opt.app.pipeline import plan
    from balance_opt.errors import InputError
    from balance_opt.tasks.task import load_task

    with pytest.raises(InputError, match=r"unknown method 'exact'; expected analytic or optimal"):
        plan(load_task(PAPER_TASK), "exact")


@pytest.mark.slow
def test_worker_reuses_the_model_and_the_nlp_across_cases(tmp_path):
    """In one process, cases that vary limits, weights and the start share one planner model
    and one compiled NLP; each case's limits still hold in its plan."""
    from balance_opt.app.models import ModelCache
    from balance_opt.sweep import runner as sweep_runner
    from balance_opt.tasks.task import task_from_dict

    text = (
        f"task: {PAPER_TASK}\nmethods: [optimal]\n"
        "grid:\n  optimal.intervals: [12]\n  limits.balance_joint1.velocity: [0.3, 1.0]\n"
        "  optimal.weights.omega: [100.0, 10.0]\n"
    )
    sweep = parse_sweep(text, "cache.yaml", tmp_path)
    models = ModelCache()
    results = [sweep_runner.run_task_case(case, models) for case in sweep.cases]
    assert [r["status"] for r in results] == ["ok"] * 4
    builds = [r["timing"]["planner_build_s"] for r in results]
    assert all(b == 0.0 for b in builds[1:]), builds  # only the first case may build
    robots = [task_from_dict(c["task"], Path(c["base_dir"])).robot for c in sweep.cases]
    assert len(models) == 1  # limits are not part of the model's key
    assert all(robot in models for robot in robots)
    # each case meets its own limit, and the loose cases use more than the tight limit of the
    # robot the cached model was built with (the first case's)
    peaks = [r["metrics"]["peak_joint_rates_rad_s"]["balance_joint1"] for r in results]
    limits = [c["parameters"]["limits.balance_joint1.velocity"] for c in sweep.cases]
    assert limits == [0.3, 0.3, 1.0, 1.0]
    assert all(peak <= limit + LIMIT_SLACK for peak, limit in zip(peaks, limits)), peaks
    np.testing.assert_allclose(peaks[:2], 0.3, rtol=0, atol=LIMIT_SLACK)  # the tight limit binds
    assert min(peaks[2:]) > 0.3 + 0.1, peaks


def test_case_effort_holds_the_task_momentum(tmp_path):
    """A case's joint torques (its ``effort`` block) are those of the task's own momentum: the
    same as a run of that task writes to metrics.json, and not those of a system at rest."""
    from balance_opt.app.pipeline import run_task
    from balance_opt.sweep import runner as sweep_runner
    from balance_opt.tasks.task import task_from_dict

    text = (
        f"task: {PAPER_TASK}\nmethods: [analytic]\n"
        "grid:\n  initial.momentum: [[0.0, 0.0, 0.0, 0.0, 0.0, 0.5]]\n"
    )
    sweep = parse_sweep(text, "momentum.yaml", tmp_path)
    (case,) = sweep.cases
    record = sweep_runner.run_task_case(case)
    task = task_from_dict(case["task"], Path(case["base_dir"]))
    assert task.h0[5] == 0.5
    run = run_task(task, methods=("analytic",), output_dir=tmp_path / "run")
    expected = run.metrics["methods"]["analytic"]["effort"]["joints"]
    got = record["metrics"]["effort"]["joints"]
    for joint, entry in expected.items():
        assert got[joint]["peak_Nm"] == pytest.approx(entry["peak_Nm"], rel=1e-12), joint
    at_rest = task_from_dict(
        {**case["task"], "initial": {"balance": [0.0, 0.5, -1.0]}}, Path(case["base_dir"])
    )
    rest = run_task(at_rest, methods=("analytic",), output_dir=tmp_path / "rest")
    rest_peaks = [
        e["peak_Nm"] for e in rest.metrics["methods"]["analytic"]["effort"]["joints"].values()
    ]
    assert max(abs(g["peak_Nm"] - r) for g, r in zip(got.values(), rest_peaks)) > 1e-3
