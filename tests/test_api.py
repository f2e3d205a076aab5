"""The notebook API: the top-level names, a short ``repr``, value equality, ``to_dataframe``
against the CSV a run writes, ``plot`` on axes without files, and ``run_task`` reusing the plans
it is given and checking its output folder before computing anything."""

import copy
import inspect
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import balance_opt as bo
from balance_opt.app import pipeline
from balance_opt.errors import InputError
from balance_opt.motion.result import REPR_LINES, BalanceResult, LimitViolation
from balance_opt.report.output_dir import OutputFolder, OutputFolderError
from balance_opt.report.outputs import write_trajectory_csv

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
API = (
    "load_task",
    "plan_mission_only",
    "plan_analytic",
    "plan_optimal",
    "simulate",
    "run_task",
    "BalanceResult",
    "TaskRun",
)


@pytest.fixture(scope="module")
def task(tmp_path_factory):
    """The capture task made short and coarse (3 s, outputs every 0.05 s)."""
    text = (EXAMPLES / "capture_task.yaml").read_text()
    text = text.replace("goal: [1.2, 0.9, -1.6]", "goal: [0.6, 0.6, -1.1]")
    text = text.replace("duration: 10.0", "duration: 3.0")
    path = tmp_path_factory.mktemp("api") / "fast.yaml"
    path.write_text(text + "analytic: {output_step: 0.05}\n")
    return bo.load_task(path)


@pytest.fixture(scope="module")
def plans(task):
    return {"mission-only": bo.plan_mission_only(task), "analytic": bo.plan_analytic(task)}


def _forbid_planning(monkeypatch):
    """Every planner of the pipeline raises: a test using this computes no plan."""

    def refuse(*args, **kwargs):
        raise AssertionError("a plan was computed")

    for name in ("plan_mission_only", "plan_analytic", "plan_optimal"):
        monkeypatch.setattr(pipeline, name, refuse)


# ----------------------------------------------------------------------------------- the package
def test_import_is_light_and_every_name_resolves():
    """``import balance_opt`` loads no CasADi, pandas or matplotlib; the API names are the
    pipeline's own objects once touched."""
    code = "import sys, balance_opt; print(*[m in sys.modules for m in ('casadi', 'pandas', 'matplotlib')])"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout
    assert out == "False False False\n"
    assert all(getattr(bo, name) is not None for name in bo.__all__)
    assert bo.run_task is pipeline.run_task and bo.BalanceResult is BalanceResult
    assert set(API) <= set(bo.__all__) <= set(dir(bo))
    with pytest.raises(AttributeError, match="module 'balance_opt' has no attribute 'nope'"):
        bo.nope  # noqa: B018


def test_version_license_and_citation_agree_with_the_project():
    import yaml

    tomllib = pytest.importorskip("tomllib")  # Python 3.11+

    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert bo.__version__ == project["version"]
    assert any(d.startswith("pandas>=") for d in project["dependencies"])
    citation = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    assert (citation["title"], citation["version"]) == ("balance-opt", project["version"])
    assert citation["license"] == project["license"] == "BSD-3-Clause"
    paper = citation["references"][0]
    assert paper["title"] == "Dynamic Balance Control of Multi-arm Free-Floating Space Robots"
    assert [a["family-names"] for a in paper["authors"]] == ["Huang", "Xu", "Liang"]
    license_text = (ROOT / "LICENSE").read_text()
    assert license_text.startswith("BSD 3-Clause License\n\nCopyright (c) 2026, balance-opt")
    assert "Neither the name of the copyright holder nor the names of its" in license_text


@pytest.mark.parametrize("name", API)
def test_public_names_have_docstrings_and_type_hints(name):
    obj = getattr(bo, name)
    assert (obj.__doc__ or "").strip(), name
    functions = [obj] if inspect.isfunction(obj) else []
    if inspect.isclass(obj):
        functions = [
            f
            for n, f in vars(obj).items()
            if inspect.isfunction(f) and not n.startswith("_") and f.__doc__ is not None
        ]
        public = [n for n, f in vars(obj).items() if inspect.isfunction(f) and n[0] != "_"]
        assert len(functions) == len(public), f"{name}: a public method without a docstring"
    for f in functions:
        sig = inspect.signature(f)
        for p in sig.parameters.values():
            if p.name not in ("self", "cls"):
                assert p.annotation is not inspect.Parameter.empty, f"{f.__qualname__}({p.name})"
        assert sig.return_annotation is not inspect.Signature.empty, f.__qualname__


# ----------------------------------------------------------------------------------- BalanceResult
def _synthetic(method="optimal", n_balance=7, violations=0) -> BalanceResult:
    """A result with many joints and violations: what could make a repr long."""
    t = np.linspace(0.0, 2.0, 201)
    T = t.size
    quat = np.zeros((T, 4))
    quat[:, 2], quat[:, 3] = np.sin(0.05 * t), np.cos(0.05 * t)  # yaw 0.1 t rad
    balance = tuple(f"right_arm_joint_{i}" for i in range(n_balance))
    return BalanceResult(
        method=method,
        t=t,
        mission_joints=tuple(f"left_arm_joint_{i}" for i in range(7)),
        balance_joints=balance,
        q_M=np.zeros((T, 7)),
        q_dot_M=np.zeros((T, 7)),
        q_ddot_M=np.zeros((T, 7)),
        q_B=np.ones((T, n_balance)),
        q_dot_B=np.full((T, n_balance), 0.5),
        q_ddot_B=np.zeros((T, n_balance)),
        quaternion=quat,
        omega=np.zeros((T, 3)),
        momentum_residual=np.zeros(T),
        sigma_min=np.ones(T),
        violations=[
            LimitViolation(balance[0], "velocity", 0.1 * k, 0.1 * k + 0.05, 0.01)
            for k in range(violations)
        ],
        info={"status": "Solve_Succeeded", "history": {"obj": list(range(50_000))}},
    )


def test_repr_is_short_and_says_what_matters():
    res = _synthetic(violations=40)
    text = repr(res)
    lines = text.split("\n")
    assert len(lines) <= REPR_LINES and len(text) < 1200
    assert lines[0] == "BalanceResult(method='optimal', status='Solve_Succeeded')"
    assert "2 s, 201 samples" in lines[1]
    assert "(7 joints)" in lines[2] and "(7 joints)" in lines[3]
    assert "peak 0.2 rad (11.5 deg), final 0.2 rad (11.5 deg)" in text  # yaw 0.1 t at t = 2
    assert "40 violation(s), first: right_arm_joint_0: velocity limit" in text
    assert "all met" in repr(_synthetic(violations=0))


def test_repr_of_a_task_is_one_line(task):
    assert repr(task) == (
        f"Task(name='capture_task', source={task.source!r}, robot paper_robot (mission 3 "
        "joints; balance 3 joints), mission ptp 3 s)"
    )


def test_repr_of_real_plans(plans):
    for res in plans.values():
        lines = repr(res).split("\n")
        assert 5 <= len(lines) <= REPR_LINES
        assert f"final {res.final_drift:.4g} rad" in lines[4]


def test_equality_is_by_value_and_never_raises():
    a = _synthetic()
    b = copy.deepcopy(a)
    b.info = {"status": "Solve_Succeeded", "wall_time_s": 3.0}  # info is not compared
    assert a == b
    assert not a != b  # noqa: SIM202 (__ne__ follows __eq__)
    c = copy.deepcopy(a)
    c.q_B[100, 2] += 1e-12
    assert a != c
    assert a != _synthetic(method="analytic")
    assert a != _synthetic(n_balance=6)  # other shapes: unequal, no broadcasting error
    assert a != _synthetic(violations=1)
    assert (a == "optimal") is False and a != None
    d, e = copy.deepcopy(a), copy.deepcopy(a)
    d.sigma_min[5] = e.sigma_min[5] = np.nan
    assert d == e  # NaN at the same sample: the same motion
    assert a in [b] and [a] == [b]
    with pytest.raises(TypeError):
        hash(a)


def test_dataframe_is_the_csv(plans, tmp_path):
    pd = pytest.importorskip("pandas")
    for name, res in plans.items():
        df = res.to_dataframe()
        written = pd.read_csv(write_trajectory_csv(tmp_path / f"{name}.csv", res), index_col="time")
        assert list(df.columns) == list(written.columns)
        assert df.index.name == "time"
        # the CSV holds every double exactly (repr): the values are the same bits
        assert np.array_equal(df.index.to_numpy(), written.index.to_numpy())
        assert np.array_equal(df.to_numpy(), written.to_numpy())
        assert df.attrs["units"]["time"] == "s" and df.attrs["units"]["base_angle"] == "rad"
        assert set(df.attrs["units"]) == {"time", *df.columns}
        np.testing.assert_array_equal(df["base_angle"].to_numpy(), res.angle)


def test_plot_returns_axes_and_writes_nothing(plans, tmp_path, monkeypatch):
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)
    fig, ax = plt.subplots()
    try:
        assert bo.plot_result(plans["mission-only"], ax=ax) is ax
        assert bo.plot_result(plans["analytic"], ax) is ax
        assert len(ax.lines) == 2
        np.testing.assert_allclose(ax.lines[1].get_ydata(), np.degrees(plans["analytic"].angle))
        assert ax.get_ylabel() == "base rotation from start [deg]"
        new = bo.plot_result(plans["analytic"], kind="balance")
        assert new is not ax and len(new.lines) == len(plans["analytic"].balance_joints)
        plt.close(new.figure)
        with pytest.raises(ValueError, match="kind must be one of attitude, balance, got 'x'"):
            bo.plot_result(plans["analytic"], ax, kind="x")
    finally:
        plt.close(fig)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------- run_task
def test_run_task_reuses_the_plans_it_is_given(task, plans, monkeypatch):
    _forbid_planning(monkeypatch)
    run = bo.run_task(task, methods=("analytic",), plans=plans)
    assert run.results["analytic"] is plans["analytic"]
    assert run.results["mission-only"] is plans["mission-only"]
    assert run.ok
    text = repr(run)
    assert text.split("\n")[0] == "TaskRun(task='capture_task', ok=True)"
    assert len(text.split("\n")) == 3 and len(text) < 400


def test_run_task_warm_starts_the_optimal_plan_from_a_given_analytic_one(task, plans, monkeypatch):
    """Only the optimal plan is computed, from the given analytic plan."""
    _forbid_planning(monkeypatch)
    seen = {}

    def fake_optimal(task, solver_options=None, warm_start=None, models=None, executor=None):
        seen["warm_start"] = warm_start
        res = copy.deepcopy(warm_start)
        res.method = "optimal"
        res.info = {"status": "Maximum_Iterations_Exceeded", "success": False}
        return res

    monkeypatch.setattr(pipeline, "plan_optimal", fake_optimal)
    run = bo.run_task(task, plans=plans)
    assert seen["warm_start"] is plans["analytic"]
    assert set(run.results) == {"mission-only", "analytic", "optimal"}
    # a given failed plan is a failure of the run
    again = bo.run_task(task, plans={**plans, "optimal": run.results["optimal"]})
    assert again.failures == {"optimal": "given plan: solver status Maximum_Iterations_Exceeded"}
    assert "(failed)" in repr(again)


def test_run_task_refuses_plans_of_something_else(task, plans, monkeypatch):
    _forbid_planning(monkeypatch)
    with pytest.raises(InputError) as err:
        bo.run_task(task, methods=("analytic",), plans={"optimal": plans["analytic"]})
    assert str(err.value) == (
        "run_task: plans['optimal']: not among the methods of this run (mission-only, analytic)"
    )
    with pytest.raises(InputError, match=r"plans\['optimal'\]: is a plan of method 'analytic'"):
        bo.run_task(task, plans={"optimal": plans["analytic"]})
    short = copy.deepcopy(plans["analytic"])
    short.t = short.t / 2
    with pytest.raises(InputError, match=r"lasts 1.5 s, the task's mission 3 s"):
        bo.run_task(task, plans={"analytic": short})
    other = _synthetic(method="analytic")
    with pytest.raises(InputError, match="its joints are not this task's arms"):
        bo.run_task(task, plans={"analytic": other})


def test_run_task_checks_the_output_folder_before_computing(task, tmp_path, monkeypatch):
    _forbid_planning(monkeypatch)
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    with pytest.raises(OutputFolderError, match=f"output folder {out} exists and is not empty"):
        bo.run_task(task, output_dir=out)
    assert [p.name for p in out.iterdir()] == ["mine.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no lock or staging left


@pytest.mark.slow
def test_a_folder_opened_by_the_caller_is_written_when_its_block_ends(task, plans, tmp_path):
    """``with OutputFolder(...)`` around planning and ``run_task``: checked first, written at
    the end of the outer block, not written at all if the block fails after ``run_task``."""
    out = tmp_path / "out"
    with OutputFolder(out) as folder:
        run = bo.run_task(task, methods=("analytic",), output_dir=folder, plans=plans)
        assert not out.exists()  # run_task does not commit a folder it did not open
    assert run.report == out / "report.html" and run.report.is_file()
    assert all(p.is_file() for p in run.files)
    failed = tmp_path / "failed"
    with pytest.raises(RuntimeError, match="after run_task"), OutputFolder(failed) as folder:
        bo.run_task(task, methods=("analytic",), output_dir=folder, plans=plans)
        raise RuntimeError("after run_task")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


# ------------------------------------------------------------------------ issue 26: misuse
def test_a_path_is_taken_where_a_task_is_expected(task, plans):
    by_path = bo.plan_analytic(task.source)
    assert by_path == plans["analytic"]
    assert bo.plan_mission_only(Path(task.source)) == plans["mission-only"]


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda t, p: bo.plan_analytic(3), "task: expected a Task .* or a task file path, got int"),
        (lambda t, p: bo.simulate(t, "x"), "plan: expected a BalanceResult .*, got str"),
        (lambda t, p: bo.simulate({"name": "x"}, p), "task: expected a Task .*, got dict"),
        (lambda t, p: bo.plan_optimal(t, warm_start="x"), "plan: expected a BalanceResult"),
    ],
)
def test_a_wrong_argument_type_is_a_type_error_naming_the_type(task, plans, call, message):
    with pytest.raises(TypeError, match=message):
        call(task, plans["analytic"])


@pytest.mark.slow
def test_repr_of_a_simulation_is_short(task, plans):
    sim = bo.simulate(task, plans["analytic"])
    lines = repr(sim).split("\n")
    assert len(lines) == 6
    assert lines[0] == "SimulationResult(robot='paper_robot', 6 joints)"
    assert f"peak {float(sim.angle.max()):.4g} rad" in lines[2]
