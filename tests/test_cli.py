"""The command line end to end through ``main([...])``: both examples with fast settings (files,
metrics, exit codes), a table of bad inputs (exit 2, the culprit named), no overwrite without
``--force``, and a solver failure (exit 1, outputs still written)."""

import argparse
import csv
import hashlib
import html
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import balance_opt
from balance_opt.cli import main
from balance_opt.commands.common import parse_solver_option
from balance_opt.model.library import shipped_urdf
from balance_opt.report.outputs import read_npz_result
from balance_opt.tasks.task_spec import task_json_schema

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

#: Fast settings appended to the test copies of the examples: short moves, few intervals,
#: coarse output grids.
FAST_OPTIONS = """
analytic: {output_step: 0.05}
optimal: {intervals: 12}
simulation: {dt: 0.002, output_dt: 0.05}
"""
PLAN_FILES = {
    f"{m}.{ext}" for m in ("mission-only", "analytic", "optimal") for ext in ("csv", "npz")
}
FIGURES = {"attitude_plans.png", "balance_joints.png", "clearance.png"}
SIMULATION_FIGURES = {"attitude_simulated.png", "reaction_torque.png"}
#: ``compare`` studies the drift under model error by default, ``plan`` does not.
MODEL_ERROR_FIGURE = {"attitude_model_error.png"}
REPORT_FILES = {"metrics.json", "report.html", "scene.html"}


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _fast_paper(tmp_path: Path, extra: str = "") -> Path:
    text = (EXAMPLES / "capture_task.yaml").read_text()
    text = text.replace("goal: [1.2, 0.9, -1.6]", "goal: [0.6, 0.6, -1.1]").replace(
        "duration: 10.0", "duration: 3.0"
    )
    return _write(tmp_path / "paper_fast.yaml", text + FAST_OPTIONS + extra)


def _fast_baxter(tmp_path: Path) -> Path:
    text = (EXAMPLES / "baxter_floating.yaml").read_text()
    text = text.replace(
        "goal: [-0.6, -0.2, -0.5, 1.3, 0.4, 0.6, 0.3]",
        "goal: [-0.2, -0.4, -0.2, 0.9, 0.1, 1.1, 0.1]",
    )
    text = text.replace("duration: 8.0", "duration: 2.0")
    return _write(
        tmp_path / "baxter_fast.yaml", text + FAST_OPTIONS.replace("intervals: 12", "intervals: 8")
    )


def _metrics(out: Path) -> dict:
    return json.loads((out / "metrics.json").read_text())


def _check_csv(path: Path, joints) -> np.ndarray:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    header = rows[0]
    assert header == [
        "time",
        *joints,
        "base_qx",
        "base_qy",
        "base_qz",
        "base_qw",
        "base_roll",
        "base_pitch",
        "base_yaw",
        "base_angle",
    ]
    data = np.array(rows[1:], dtype=float)
    assert data[0, 0] == 0.0 and np.all(np.diff(data[:, 0]) > 0)
    np.testing.assert_allclose(np.linalg.norm(data[:, -8:-4], axis=1), 1.0, rtol=0, atol=1e-12)
    return data


# ----------------------------------------------------------------------------------- small commands
def test_validate_both_examples(capsys):
    assert (
        main(
            [
                "validate",
                str(EXAMPLES / "capture_task.yaml"),
                str(EXAMPLES / "baxter_floating.yaml"),
            ]
        )
        == 0
    )
    err = capsys.readouterr().out  # results on stdout
    assert re.search(
        r"capture_task\.yaml: ok \(robot paper_robot, mission 3 joints; balance 3 joints; "
        r"mission ptp, 10 s\)",
        err,
    )
    assert "baxter_floating.yaml: ok (robot baxter, mission 7 joints; balance 7 joints" in err


@pytest.mark.parametrize("argv", [["validate", "--schema"], ["schema"]])
def test_schema_is_printed(capsys, argv):
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(task_json_schema()))


def test_inspect_without_and_with_a_task(capsys):
    assert main(["inspect"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("robot paper_robot") and "coupling at q = [0, 0, 0, 0, 0, 0]" in out
    assert main(["inspect", str(EXAMPLES / "capture_task.yaml")]) == 0
    out = capsys.readouterr().out
    assert (
        out.startswith("task capture_task (")
        and "coupling at q = [0, 0.3, -0.6, 0, 0.5, -1]" in out
    )


def test_solver_option_values_are_typed():
    assert parse_solver_option("max_iter=100") == ("max_iter", 100)
    assert parse_solver_option("tol=1e-6") == ("tol", 1e-6)
    assert parse_solver_option("mu_strategy = monotone") == ("mu_strategy", "monotone")


def test_importing_the_package_does_not_load_casadi():
    """``import balance_opt`` stays light: CasADi is loaded by the stages that need it."""
    code = "import sys, balance_opt; print(balance_opt.__version__, 'casadi' in sys.modules)"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout.split()
    assert out == [balance_opt.__version__, "False"]


def test_usage_error_is_exit_2(capsys):
    assert main(["plan"]) == 2
    assert "the following arguments are required: task" in capsys.readouterr().err


# ----------------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_plan_paper_both_methods_simulated(tmp_path, capsys):
    task = _fast_paper(tmp_path)
    out = tmp_path / "out"
    assert main(["plan", str(task), "--method", "both", "--simulate", "--output", str(out)]) == 0
    captured = capsys.readouterr()
    assert "optimal plan (N = 12, hermite-simpson, Ipopt) ..." in captured.err  # progress
    assert f"report: {out / 'report.html'}" in captured.out  # results
    files = {p.name for p in out.iterdir()}
    assert files == PLAN_FILES | FIGURES | SIMULATION_FIGURES | REPORT_FILES

    joints = [
        "mission_joint1",
        "mission_joint2",
        "mission_joint3",
        "balance_joint1",
        "balance_joint2",
        "balance_joint3",
    ]
    data = _check_csv(out / "optimal.csv", joints)
    npz = read_npz_result(out / "optimal.npz")
    np.testing.assert_allclose(data[:, 1:7], np.hstack([npz.q_M, npz.q_B]), rtol=0, atol=0)
    np.testing.assert_allclose(data[:, -1], npz.angle, rtol=0, atol=1e-15)

    m = _metrics(out)
    assert m["task"] == {
        "file": str(task),
        "name": "capture_task",
        "sha256": hashlib.sha256(task.read_bytes()).hexdigest(),
    }
    assert set(m["versions"]) >= {"balance-opt", "pinocchio", "casadi", "ipopt"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", m["versions"]["ipopt"])
    assert m["failures"] == {}
    ref, analytic, optimal = (m["methods"][k] for k in ("mission-only", "analytic", "optimal"))
    assert ref["peak_balance_rate_rad_s"] == 0.0  # Phase I: the balance arm is held
    assert optimal["solver"]["status"] == "Solve_Succeeded" and optimal["solver"]["iterations"] > 0
    assert optimal["solver"]["solve_time_s"] > 0
    assert analytic["solver"]["iterations"] is None
    assert optimal["limit_violations"] == 0 and optimal["violations"] == []
    assert min(optimal["balance_limit_margin"].values()) > -1e-6
    # the optimal plan keeps the base stiller than the mission arm alone would leave it
    assert optimal["max_drift_rad"] < ref["max_drift_rad"]
    assert optimal["final_drift_rad"] < ref["final_drift_rad"]
    # the clearance of every plan and simulation on the continuous motion, checked with coal
    assert optimal["clearance"]["collision_free"] and optimal["simulation"]["clearance"]
    assert optimal["clearance"]["min_distance_m"] >= 0.03 - 1e-3  # the default margin
    assert ref["clearance"]["pairs_checked"] == optimal["clearance"]["pairs_checked"] > 0
    # smoothness figures of every balance joint; no model-error study in `plan` by default
    assert set(optimal["smoothness"]) == set(joints[3:])
    assert all(v["acceleration_reversals"] >= 0 for v in optimal["smoothness"].values())
    assert "robustness" not in m and "robustness" not in optimal
    for method in (ref, analytic, optimal):  # relative; finite-difference floor ~1e-8 at 10 ms
        assert method["max_momentum_residual"] < 1e-6
        sim = method["simulation"]
        assert sim["max_relative_momentum_residual"] < 1e-6
        # the simulated drift is the plan's, up to what the tracking error allows
        assert abs(sim["max_drift_rad"] - method["max_drift_rad"]) < 0.1 * method["max_drift_rad"]
        assert set(sim["peak_reaction_torque_Nm"]) == {"mission", "balance", "total"}
    report = (out / "report.html").read_text()
    assert report.count("data:image/png;base64,") == 5  # with the clearance figure
    assert re.search(r"analytic law</th><th>.*?optimal plan</th>", report)


@pytest.mark.slow
def test_compare_baxter(tmp_path, capsys):
    task = _fast_baxter(tmp_path)
    out = tmp_path / "bax"
    assert main(["compare", str(task), "-o", str(out)]) == 0
    files = {p.name for p in out.iterdir()}
    assert files == PLAN_FILES | FIGURES | SIMULATION_FIGURES | REPORT_FILES | MODEL_ERROR_FIGURE
    _check_csv(
        out / "analytic.csv",
        [
            *(f"left_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")),
            *(f"right_{j}" for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")),
        ],
    )
    m = _metrics(out)
    ref, analytic, optimal = (m["methods"][k] for k in ("mission-only", "analytic", "optimal"))
    # a redundant, well-conditioned balance arm: the exact law cancels the rotation ...
    assert analytic["max_drift_rad"] < 1e-9 < ref["max_drift_rad"]
    # ... and the balance arm cancels the mission arm's torque on the base in the simulation
    torque = analytic["simulation"]["peak_reaction_torque_Nm"]
    assert torque["total"] < 0.2 * torque["mission"]
    # ... but it breaks the acceleration limits of this fast move, which the optimal plan meets
    assert analytic["limit_violations"] > 0 and analytic["balance_limit_margin"]["acceleration"] < 0
    assert optimal["limit_violations"] == 0
    assert optimal["max_drift_rad"] < 0.5 * ref["max_drift_rad"]
    assert "left_s0" in optimal["peak_joint_rates_rad_s"]
    # compare studies the drift under model error: the exact law's zero drift does not survive it
    assert m["robustness"]["samples"] == 50 and m["robustness"]["perturbation"] == 0.1
    spread = analytic["robustness"]["max_drift"]
    assert analytic["max_drift_rad"] < spread["median_rad"] <= spread["p95_rad"] <= spread["largest_rad"]


# ----------------------------------------------------------------------------------- bad input
def _paper_text() -> str:
    return (EXAMPLES / "capture_task.yaml").read_text()


def _sub(old: str, new: str):
    def edit(text: str, tmp_path: Path) -> str:
        assert old in text, old
        return text.replace(old, new, 1)

    return edit


def _csv_mission(text: str, tmp_path: Path) -> str:
    (tmp_path / "mission.csv").write_text(
        "time,mission_joint1,mission_joint2,mission_joint3\n0,0,0.3,-0.6\n1,0.1,oops,-0.6\n"
    )
    return re.sub(
        r"mission:\n  type: ptp\n.*?\n\n",
        "mission:\n  type: csv\n  file: mission.csv\n\n",
        text,
        flags=re.DOTALL,
    )


#: (case, edit of the paper example, regex of the line the error names, message after "FILE:LINE: ")
BAD_INPUTS = [
    (
        "wrong type",
        _sub("duration: 10.0", "duration: long"),
        r"  duration: long",
        "mission.duration: expected a number, got 'long' (a string)",
    ),
    (
        "unknown key",
        _sub("initial:\n", "initial:\n  velocity: [0, 0, 0]\n"),
        r"  velocity:",
        "initial.velocity: unknown key 'velocity'; expected one of balance, momentum",
    ),
    (
        "missing file",
        _sub("shipped: paper_robot.urdf", "urdf: robots/none.urdf"),
        r"  urdf:",
        "robot.urdf: no such URDF file: {dir}/robots/none.urdf",
    ),
    (
        "unknown joint",
        _sub("mission: [mission_joint1,", "mission: [mission_jiont1,"),
        r"  mission: \[",
        (
            "arms.mission[0]: joint 'mission_jiont1' in {urdf}: no such joint in the URDF (arm 'mission'); "
            "did you mean 'mission_joint1'"
        ),
    ),
    (
        "negative duration",
        _sub("duration: 10.0", "duration: -10.0"),
        r"  duration:",
        "mission.duration: must be greater than 0 s, got -10",
    ),
    (
        "limits no plan can meet",
        _sub(
            "balance_joint3: {acceleration: 2.0}",
            "balance_joint3: {acceleration: 2.0, lower: -0.5}",
        ),
        r"  balance: \[0.0",
        (
            "initial.balance[2]: balance joint 'balance_joint3' starts at -1 rad, outside its position limits "
            "[-0.5, 2.5] rad (lower limit from limits.balance_joint3.lower); no plan can meet them"
        ),
    ),
    (
        "final configuration outside the limits",
        _sub("limits:", "optimal:\n  constraints: {final_configuration: [0, 0, 3]}\nlimits:"),
        r"  constraints:",
        (
            "optimal.constraints.final_configuration[2]: balance joint 'balance_joint3' must end "
            "at 3 rad, outside its position limits [-2.5, 2.5] rad; no plan can meet them"
        ),
    ),
    (
        "malformed CSV",
        _csv_mission,
        r"  file: mission.csv",
        "mission.file: {dir}/mission.csv: line 3, column 'mission_joint2': not a number: 'oops'",
    ),
]


@pytest.mark.parametrize(
    "edit, line_pattern, message", [c[1:] for c in BAD_INPUTS], ids=[c[0] for c in BAD_INPUTS]
)
def test_bad_input_is_exit_2_naming_the_culprit(tmp_path, capsys, edit, line_pattern, message):
    text = edit(_paper_text(), tmp_path)
    task = _write(tmp_path / "task.yaml", text)
    line = next(i for i, s in enumerate(text.splitlines(), 1) if re.match(line_pattern, s))
    out = tmp_path / "out"
    assert main(["plan", str(task), "-o", str(out)]) == 2
    expected = f"balance-opt: error: {task}:{line}: " + message.format(
        dir=tmp_path, urdf=shipped_urdf()
    )
    err = capsys.readouterr().err
    assert expected in err, err
    assert not out.exists()  # checked before anything is computed or written


def test_bad_solver_option_is_exit_2(tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(["plan", str(_fast_paper(tmp_path)), "-o", str(out), "--solver-option", "max_iter"])
        == 2
    )
    assert "--solver-option 'max_iter': expected KEY=VALUE" in capsys.readouterr().err
    assert not out.exists()


def test_existing_output_is_not_overwritten_without_force(tmp_path, capsys):
    task = _fast_paper(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    keep = _write(out / "notes.txt", "mine")
    old_metrics = _write(out / "metrics.json", "{}")
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out)]) == 2
    assert (
        f"balance-opt: error: output folder {out} exists and is not empty; use --force to "
        "replace it" in capsys.readouterr().err
    )
    assert {p.name for p in out.iterdir()} == {"notes.txt", "metrics.json"}
    assert old_metrics.read_text() == "{}" and keep.read_text() == "mine"
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out), "--force"]) == 0
    # --force replaces the whole folder: no file of before is left, nothing beside it either
    assert not keep.exists()
    assert set(_metrics(out)["methods"]) == {"mission-only", "analytic"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "paper_fast.yaml"]


@pytest.mark.slow
def test_solver_failure_is_exit_1_and_still_written(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(
        [
            "plan",
            str(_fast_paper(tmp_path)),
            "-m",
            "optimal",
            "-o",
            str(out),
            "--solver-option",
            "max_iter=1",
        ]
    )
    assert code == 1
    out_text, err = capsys.readouterr()
    # the summary on stdout says so too, under the method's line (``compare > log`` keeps it)
    summary = out_text.splitlines()
    k = next(i for i, line in enumerate(summary) if line.startswith("  optimal "))
    assert summary[k + 1] == f"  {'':<13s} FAILED: the solver's last iterate, not a plan"
    assert not any("FAILED" in line for line in summary[:k])
    assert re.search(
        r"balance-opt: solver failure \(optimal\): Ipopt stopped with status "
        r"'Maximum_Iterations_Exceeded' after 1 iterations; largest constraint violation: ",
        err,
    )
    m = _metrics(out)
    assert set(m["failures"]) == {"optimal"}
    assert m["methods"]["optimal"]["solver"]["status"] == "Maximum_Iterations_Exceeded"
    assert m["methods"]["optimal"]["details"]["options"]["ipopt"] == {"max_iter": 1}
    assert {"optimal.csv", "optimal.npz", "report.html"} <= {p.name for p in out.iterdir()}
    assert "Maximum_Iterations_Exceeded" in (out / "report.html").read_text()


def test_quiet_prints_errors_only(tmp_path, capsys):
    out = tmp_path / "out"
    assert (
        main(["plan", str(_fast_paper(tmp_path)), "-m", "analytic", "-o", str(out), "--quiet"]) == 0
    )
    assert capsys.readouterr().err == ""
    assert (out / "report.html").is_file()


def test_outputs_can_be_switched_off(tmp_path):
    task = _fast_paper(tmp_path, "outputs: {csv: false, npz: false, plots: false}\n")
    out = tmp_path / "out"
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out), "-q"]) == 0
    assert {p.name for p in out.iterdir()} == REPORT_FILES
    # the attitude, the balance joints and the clearance
    assert (out / "report.html").read_text().count("data:image/png;base64,") == 3


@pytest.mark.slow
def test_simulate_one_method(tmp_path):
    out = tmp_path / "out"
    assert (
        main(["simulate", str(_fast_paper(tmp_path)), "-m", "analytic", "-o", str(out), "-q"]) == 0
    )
    files = {p.name for p in out.iterdir()}
    assert {"attitude_simulated.png", "reaction_torque.png"} <= files and "optimal.csv" not in files
    sim = _metrics(out)["methods"]["analytic"]["simulation"]
    assert (
        sim["max_relative_momentum_residual"] < 1e-6 and sim["peak_reaction_torque_Nm"]["total"] > 0
    )


@pytest.mark.slow
def test_paper_figures_with_fast_options(tmp_path):
    out = tmp_path / "figs"
    assert main(["paper-figures", "--task", str(_fast_paper(tmp_path)), "-o", str(out), "-q"]) == 0
    stems = (
        "fig2_attitude_mission_arm",
        "fig3_attitude_balance_arm",
        "fig4_reaction_torque",
        "fig5_attitude_balanced",
    )
    # --task: that task alone (its robot, mission and options), in a folder of its name
    assert {p.name for p in out.iterdir()} == {"capture_task", "study.json"}
    assert {p.name for p in (out / "capture_task").iterdir()} == {
        f"{s}.{e}" for s in stems for e in ("png", "pdf")
    } | {"study.json"}
    study = json.loads((out / "study.json").read_text())
    assert set(study) == {"capture_task"}
    assert set(study["capture_task"]["plans"]) == {"analytic", "optimal"}


@pytest.mark.slow
def test_api_example_runs_headless(tmp_path):
    import os

    out = tmp_path / "api"
    task = _fast_paper(tmp_path)

    def example():
        return subprocess.run(
            [sys.executable, str(EXAMPLES / "compare_api.py"), str(task), str(out)],
            capture_output=True,
            text=True,
            env={**os.environ, "MPLBACKEND": "Agg"},
            timeout=300,
            check=False,
        )

    proc = example()
    assert proc.returncode == 0, proc.stderr
    assert re.search(r"^optimal +[0-9.e-]+ +[0-9.e-]+ +0$", proc.stdout, re.MULTILINE)
    assert f"report: {out / 'report.html'}; solver failures: none" in proc.stdout
    assert {"metrics.json", "report.html", "optimal.csv"} <= {p.name for p in out.iterdir()}
    # each plan computed once: run_task writes the plans and simulations it is given
    for name in ("mission-only", "analytic", "optimal"):
        assert f"{name} plan given, not planned again" in proc.stderr
    assert (
        "optimal plan (N =" not in proc.stderr and "forward-dynamics simulation" not in proc.stderr
    )
    # the folder is checked before planning: a second run is refused at once
    again = example()
    assert again.returncode == 1 and again.stdout.count("\n") == 1  # the task line only
    assert f"compare_api: output folder {out} exists and is not empty" in again.stderr


def test_verbose_shows_the_ipopt_iterations(tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["plan", str(_fast_paper(tmp_path)), "-m", "optimal", "-o", str(out), "-v"]) == 0
    captured = capsys.readouterr()
    assert re.search(
        r"^iter +objective +inf_pr", captured.out, re.MULTILINE
    )  # Ipopt's log, as progress
    assert " DEBUG " in captured.err


# ----------------------------------------------------------------------------------- version, pipes, help
def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out == f"balance-opt {balance_opt.__version__}\n"
    out = subprocess.run(
        [sys.executable, "-m", "balance_opt.cli", "--version"],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    )
    assert (out.stdout, out.stderr) == ("balance-opt 0.1.0\n", "")


def test_a_closed_output_pipe_ends_quietly():
    """``balance-opt validate --schema | head -1``: the reader leaves after one line; the
    writer ends with 141 (128 + SIGPIPE, what a shell shows for ``cat``) and no traceback. The
    pipe is made one page small so that the schema (~30 KB) cannot fit in it before the reader
    leaves."""
    import fcntl
    import os

    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, 1031, 4096)  # F_SETPIPE_SZ
    proc = subprocess.Popen(
        [sys.executable, "-m", "balance_opt.cli", "validate", "--schema"],
        stdout=write_end,
        stderr=subprocess.PIPE,
        cwd=ROOT,
    )
    os.close(write_end)
    with os.fdopen(read_end, "rb") as reader:
        assert reader.readline() == b"{\n"
    _, err = proc.communicate(timeout=60)
    assert err.decode() == ""
    assert proc.returncode == 141


def test_head_in_a_shell_pipe_gets_the_first_line():
    out = subprocess.run(
        f"'{sys.executable}' -m balance_opt.cli validate --schema | head -1",
        shell=True,
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=60,
        check=False,
    )
    assert (out.stdout, out.stderr, out.returncode) == ("{\n", "", 0)


@pytest.mark.parametrize(
    ("command", "default"),
    [
        (["plan", "TASK", "-m", "analytic"], "results/<task name>"),
        (["compare", "TASK"], "results/<task name>"),
        (["paper-figures", "--task", "TASK"], "results/paper_figures"),
    ],
)
def test_the_default_output_folder_is_the_one_the_help_states(
    command, default, tmp_path, capsys, monkeypatch
):
    """The folder named in ``--help`` is the one the command writes to: made non-empty, it is
    refused (exit 2, before anything is computed)."""
    assert main([command[0], "--help"]) == 0
    assert f"output directory (default: {default})" in " ".join(capsys.readouterr().out.split())
    task = _fast_paper(tmp_path)
    monkeypatch.chdir(tmp_path)
    folder = Path(default.replace("<task name>", "capture_task"))
    folder.mkdir(parents=True)
    (folder / "old.txt").write_text("old")
    argv = [str(task) if a == "TASK" else a for a in command]
    assert main(argv) == 2
    assert f"output folder {tmp_path / folder} exists and is not empty" in capsys.readouterr().err


def test_backend_is_taken_by_sweep_and_paper_figures(tmp_path, monkeypatch):
    from balance_opt.app import study as paper_figures
    from balance_opt.sweep import run as sweep_run

    seen = {}

    class Stop(Exception):
        pass

    def fake_sweep(sweep, *args, **kwargs):
        seen["sweep"] = {case["task"]["robot"]["backend"] for case in sweep.cases}
        raise Stop

    def fake_figures(folder, **kwargs):
        seen["figures"] = kwargs["backend"]
        raise Stop

    monkeypatch.setattr(sweep_run, "run_sweep", fake_sweep)
    monkeypatch.setattr(paper_figures, "paper_figures", fake_figures)
    sweep = _write(
        tmp_path / "s.yaml",
        f"task: {EXAMPLES / 'capture_task.yaml'}\nmethods: [optimal]\n"
        "grid: {mission.duration: [2.0, 3.0]}\n",
    )
    with pytest.raises(Stop):
        main(["sweep", str(sweep), "-o", str(tmp_path / "s"), "--backend", "adam", "-q"])
    with pytest.raises(Stop):
        main(["paper-figures", "-o", str(tmp_path / "f"), "--backend", "adam", "-q"])
    assert seen == {"sweep": {"adam"}, "figures": "adam"}


# ----------------------------------------------------------------------------------- progress
def test_optimal_plan_shows_its_ipopt_progress_unless_quiet(tmp_path, capsys):
    task = str(_fast_paper(tmp_path))
    assert main(["plan", task, "-m", "optimal", "-o", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    line = re.compile(
        r"^Ipopt \(N = (\d+), (integral|smooth|peak) stage\): (\d+) iterations, objective \S+, "
        r"constraint violation "
        r"(\S+) in [0-9.]+ s$",
        re.MULTILINE,
    )
    found = line.findall(err)
    assert found, err
    # one line per Ipopt solve (the peak objective's stages, the inner ones on their coarser
    # grid): metrics count them all
    assert [(n, stage) for n, stage, _, _ in found] == [
        ("10", "integral"),
        ("10", "smooth"),
        ("12", "peak"),
    ]
    iterations = _metrics(tmp_path / "a")["methods"]["optimal"]["solver"]["iterations"]
    assert sum(int(n) for _, _, n, _ in found) == iterations
    assert float(found[-1][3]) < 1e-6
    assert "\r" not in err  # not a terminal: no live line
    assert main(["plan", task, "-m", "optimal", "-o", str(tmp_path / "b"), "-q"]) == 0
    assert capsys.readouterr().err == ""


def test_the_readme_lists_every_subcommand():
    from balance_opt.cli import build_parser

    readme = (ROOT / "README.md").read_text()
    listing = readme[readme.index("## Command line") : readme.index("Every command that computes")]
    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    missing = [name for name in sub.choices if f"    balance-opt {name}" not in listing]
    assert missing == []
    assert "balance-opt --version" in listing


def test_an_hsl_solver_without_hsl_is_an_input_error_not_a_crash(tmp_path, capsys):
    """``ma97`` crashes CasADi's Ipopt without the HSL library: it is refused before planning
    (exit 2, nothing written) instead of ending the process with a segmentation fault."""
    out = tmp_path / "out"
    task = _fast_paper(tmp_path)
    code = main(
        ["plan", str(task), "-m", "optimal", "-o", str(out)]
        + ["--solver-option", "linear_solver=ma97"]
    )
    assert code == 2
    assert "Ipopt cannot load linear solver 'ma97'" in capsys.readouterr().err
    assert not out.exists()


# ------------------------------------------------------------------------ issue 26: results
#: The capture task's law with hardly any damping near its singular balance arm, integrated by
#: RK4 on the 10 ms output grid: the rates run away between the samples, which then no longer
#: conserve momentum.
RUNAWAY_LAW = """
analytic: {damping_threshold: 1.0e-3, max_damping: 1.0e-4, integrator: rk4, output_step: 0.01}
outputs: {plots: false, animation: false}
"""


def test_untrustworthy_plan_is_flagged_and_results_go_to_stdout(tmp_path, capsys):
    text = (EXAMPLES / "capture_task.yaml").read_text()
    text = text.replace("balance: [0.0, 0.5, -1.0]", "balance: [0.0, 0.5, -0.95]")
    task = _write(tmp_path / "runaway.yaml", text + RUNAWAY_LAW)
    out = tmp_path / "out"
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    m = _metrics(out)["methods"]["analytic"]
    assert m["max_momentum_residual"] > 0.1
    assert len(m["warnings"]) == 1
    assert re.match(r"untrustworthy: relative momentum residual 0\.\d+ > 0\.001", m["warnings"][0])
    # one count of the violations everywhere, split by kind
    kinds = m["limit_violations_by_kind"]
    assert sum(kinds.values()) == m["limit_violations"] == len(m["violations"]) > 0
    kinematic = kinds["position"] + kinds["velocity"] + kinds["acceleration"]
    collision = f", {kinds['collision']} collision" if kinds["collision"] else ""
    count = (
        f"{m['limit_violations']} ({kinematic} position/velocity/acceleration, "
        f"{kinds['effort']} effort{collision}) limit violations"
    )
    assert f"analytic      max drift {m['max_drift_rad']:.3g} rad" in captured.out
    assert count in captured.out
    assert f"WARNING: {m['warnings'][0]}" in captured.out
    assert f"report: {out / 'report.html'}" in captured.out
    assert "report:" not in captured.err and "WARNING: untrustworthy" not in captured.out.split(
        "analytic      max drift"
    )[0]
    report = html.unescape((out / "report.html").read_text())
    assert re.search(rf"WARNING: [^<:]+: {re.escape(m['warnings'][0])}", report)
    assert count.removesuffix(" limit violations") in report
    assert re.search(r'<td class="broken">0\.\d+</td>', report)  # the residual's cell


def test_validate_on_a_sweep_file_points_to_the_sweep_command(capsys):
    sweep = EXAMPLES / "sweep_paper.yaml"
    line = next(i for i, s in enumerate(sweep.read_text().splitlines(), 1) if s.startswith("task:"))
    assert main(["validate", str(sweep)]) == 2
    assert (
        f"balance-opt: error: {sweep}:{line}: task: this is a sweep file, not a task file: "
        "use balance-opt sweep"
    ) in capsys.readouterr().err


def test_plan_mission_only_writes_the_reference_alone(tmp_path, capsys):
    out = tmp_path / "out"
    task = _fast_paper(tmp_path, "outputs: {plots: false, animation: false}\n")
    assert main(["plan", str(task), "-m", "mission-only", "-o", str(out), "-q"]) == 0
    assert set(_metrics(out)["methods"]) == {"mission-only"}
    assert {"mission-only.csv", "mission-only.npz"} <= {p.name for p in out.iterdir()}
    assert "  mission-only  max drift" in capsys.readouterr().out


def test_cartesian_goal_where_the_end_effector_is_and_the_joint_goal(tmp_path, capsys):
    from balance_opt.model.summary import end_effector_poses
    from balance_opt.tasks.task import load_task

    task = _write(
        tmp_path / "cart.yaml",
        "name: cart\nrobot: {shipped: paper_robot.urdf}\n"
        "arms:\n  mission: [mission_joint1, mission_joint2, mission_joint3]\n"
        "  balance: [balance_joint1, balance_joint2, balance_joint3]\n"
        "initial: {balance: [0.0, 0.5, -1.0]}\n"
        "mission: {type: cartesian, start: [0.0, 0.3, -0.6], position: [0.9, 0.4, 1.2], "
        "duration: 3}\n"
        "analytic: {output_step: 0.05}\noutputs: {plots: false, animation: false}\n",
    )
    loaded = load_task(task)
    assert main(["inspect", str(task)]) == 0
    out = capsys.readouterr().out
    poses = end_effector_poses(loaded.robot, loaded.q0)
    for arm, (position, _) in poses.items():
        where = "[" + ", ".join(f"{x:.4g}" for x in position) + "] m"
        assert f"  {arm} arm: 3 joints" in out
        assert f"    end effector at {where}, roll-pitch-yaw [" in out
    goal = dict(zip(loaded.robot.mission.joints, loaded.mission.qf))
    line = "mission goal found by inverse kinematics: " + ", ".join(
        f"{j} {v:.6g}" for j, v in goal.items()
    )
    assert line in out
    out_dir = tmp_path / "out"
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out_dir), "-q"]) == 0
    assert line in capsys.readouterr().out
    assert _metrics(out_dir)["task"]["cartesian_goal_rad"] == pytest.approx(goal, abs=1e-12)
