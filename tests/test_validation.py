"""Validation is complete: whatever ``plan`` would refuse or choke on is refused when the task is
loaded (``balance-opt validate``), with the file, the line and the key, before anything is
computed: Ipopt options, URDF physics, problem size, time grids, non-finite and absurd numbers,
the task's name, and what the optimal planner cannot do. A simulation that diverges is a failure.
"""

import dataclasses
import logging
import re
import subprocess
import sys
from pathlib import Path

import pytest

from balance_opt.cli import main
from balance_opt.config.yaml_lines import TaskFileError
from balance_opt.errors import ArmError, URDFLoadError
from balance_opt.model.robot import FloatingRobot
from balance_opt.tasks.task import load_task

ROOT = Path(__file__).resolve().parents[1]
PAPER = (ROOT / "examples" / "capture_task.yaml").read_text()


def _line_of(text: str, fragment: str) -> int:
    """1-based number of the first line of ``text`` that contains ``fragment``."""
    return next(i for i, line in enumerate(text.splitlines(), 1) if fragment in line)


def _task(tmp_path: Path, *edits: tuple[str, str], extra: str = "", name="task.yaml") -> Path:
    """The capture task with ``edits`` (old, new) and ``extra`` keys appended, written to a file."""
    text = PAPER
    for old, new in edits:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / name
    path.write_text(text + extra)
    return path


def _refused(path: Path, fragment: str, message: str) -> None:
    """Loading ``path`` fails with exactly ``FILE:LINE: message``, the line holding
    ``fragment``."""
    line = _line_of(path.read_text(), fragment)
    with pytest.raises(TaskFileError) as info:
        load_task(path)
    assert str(info.value) == f"{path}:{line}: {message}"


def _cli(args, capsys) -> tuple[int, str]:
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err


# ------------------------------------------------------------------ Ipopt options (defect 5)
IPOPT_CASES = {
    "unknown name": (
        "tolx: 1.0e-3",
        "optimal.ipopt.tolx: unknown Ipopt option 'tolx'; did you mean 'tol'?",
    ),
    "integer option given a fraction": (
        "max_iter: 10.5",
        (
            "optimal.ipopt.max_iter: Ipopt option 'max_iter' takes an integer, got 10.5; expected an "
            "integer >= 0"
        ),
    ),
    "out of range": (
        "tol: 0",
        (
            "optimal.ipopt.tol: Ipopt option 'tol' is out of range, got 0; expected a finite "
            "number > 0"
        ),
    ),
    "not a number": ("tol: .nan", "optimal.ipopt.tol: expected a number, got NaN"),
    "wrong type": (
        "mu_strategy: 3",
        (
            "optimal.ipopt.mu_strategy: Ipopt option 'mu_strategy' takes a string, got 3; expected "
            "one of 'monotone', 'adaptive'"
        ),
    ),
    "value Ipopt does not know": (
        "hessian_approximation: bfgs",
        (
            "optimal.ipopt.hessian_approximation: Ipopt option 'hessian_approximation' does not "
            "accept 'bfgs'; expected one of 'exact', 'limited-memory'"
        ),
    ),
    "linear solver not installed": (
        "linear_solver: ma57",
        (
            "optimal.ipopt.linear_solver: Ipopt cannot load linear solver 'ma57' (not in this "
            "installation: the HSL solvers need a separately installed library); 'mumps' is always "
            "available"
        ),
    ),
}


@pytest.mark.parametrize("case", sorted(IPOPT_CASES))
def test_bad_ipopt_option_in_the_task_is_refused_at_its_key(tmp_path, case):
    option, message = IPOPT_CASES[case]
    path = _task(tmp_path, extra=f"optimal:\n  ipopt:\n    {option}\n")
    _refused(path, option.split(":")[0] + ":", message)


def test_ipopt_values_are_cleaned_to_ipopts_types(tmp_path):
    path = _task(tmp_path, extra="optimal:\n  ipopt: {max_iter: 500.0, tol: 1.0e-7}\n")
    ipopt = load_task(path).planner_options().ipopt
    assert ipopt == {"max_iter": 500, "tol": 1e-7} and type(ipopt["max_iter"]) is int


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ("tolx=1e-3", "--solver-option tolx: unknown Ipopt option 'tolx'; did you mean 'tol'?"),
        ("tol=nan", "--solver-option tol: Ipopt option 'tol' must be finite, got nan"),
        ("max_iter=-1", "--solver-option max_iter: Ipopt option 'max_iter' is out of range"),
    ],
)
def test_bad_solver_option_is_refused_before_planning(tmp_path, capsys, option, message):
    out = tmp_path / "out"
    code, err = _cli(
        ["plan", _task(tmp_path), "--method", "analytic", "-o", out, "--solver-option", option],
        capsys,
    )
    assert code == 2 and message in err and "Traceback" not in err
    assert not out.exists()  # refused before anything was computed or written


def test_checking_ipopt_options_asks_no_ipopt_once_the_list_is_cached(tmp_path, monkeypatch):
    from balance_opt.solvers import ipopt_options

    monkeypatch.setenv("BALANCE_OPT_CACHE", str(tmp_path / "cache"))
    ipopt_options.option_catalog()  # asks Ipopt once, writes the cache
    path = _task(tmp_path, extra="optimal:\n  ipopt: {max_iter: 50, mu_strategy: adaptive}\n")
    code = (
        "from balance_opt.solvers import ipopt_options\n"
        "def asked():\n"
        "    raise AssertionError('Ipopt asked for its options')\n"
        "ipopt_options._documentation_from_ipopt = asked\n"
        "from balance_opt.tasks.task import load_task\n"
        f"task = load_task({str(path)!r})\n"
        "print(task.planner_options().ipopt)"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout
    assert out.strip() == "{'max_iter': 50, 'mu_strategy': 'adaptive'}"


# ------------------------------------------------------------------ URDF (defects 6 and 15)
def _link(name: str, mass=1.0, inertia=(0.1, 0.1, 0.05)) -> str:
    ixx, iyy, izz = inertia
    return (
        f'<link name="{name}"><inertial><mass value="{mass}"/><inertia ixx="{ixx}" ixy="0" '
        f'ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial></link>'
    )


def _joint(name, parent, child, axis="0 0 1", lower=-2, upper=2) -> str:
    return (
        f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="0.2 0 0"/><axis xyz="{axis}"/><limit lower="{lower}" upper="{upper}" '
        'effort="10" velocity="1"/></joint>'
    )


def _robot(links=None, joints=None) -> str:
    """A base with a 2-joint mission arm (m1, m2) and a 2-joint balance arm (b1, b2); ``links``
    and ``joints`` replace elements by name (``None``: leave the element out)."""
    all_links = {
        "base": _link("base", 50.0, (5.0, 5.0, 5.0)),
        **{n: _link(n) for n in ("ml1", "ml2", "bl1", "bl2")},
    }
    all_joints = {
        "m1": _joint("m1", "base", "ml1"),
        "m2": _joint("m2", "ml1", "ml2", axis="0 1 0"),
        "b1": _joint("b1", "base", "bl1"),
        "b2": _joint("b2", "bl1", "bl2", axis="0 1 0"),
    }
    all_links.update(links or {})
    all_joints.update(joints or {})
    parts = [v for v in (*all_links.values(), *all_joints.values()) if v is not None]
    return '<robot name="r">' + "".join(parts) + "</robot>"


def _load(text: str) -> FloatingRobot:
    return FloatingRobot(text, ["m1", "m2"], ["b1", "b2"])


URDF_CASES = {
    "negative mass": ({"bl1": _link("bl1", mass=-2)}, {}, "link 'bl1': mass -2 kg is negative"),
    "inertia not positive semi-definite": (
        {"ml2": _link("ml2", inertia=(0.1, -0.1, 0.05))},
        {},
        (
            "link 'ml2': inertia is not positive semi-definite (principal moments -0.1, 0.05, "
            "0.1 kg m^2)"
        ),
    ),
    "axis of zero length": (
        {},
        {"b2": _joint("b2", "bl1", "bl2", axis="0 0 0")},
        "joint 'b2': axis is of zero length",
    ),
    "link with two parents": (
        {},
        {"m2": _joint("m2", "ml1", "bl2")},
        "link 'bl2' is the child of two joints ('m2' and 'b2'); a URDF is a tree",
    ),
    "two roots": ({}, {"b1": None}, "a URDF has one root link, this one has 2: 'base', 'bl1'"),
    "missing child link": (
        {"bl2": None},
        {},
        "joint 'b2': its child link 'bl2' is not a <link> of the file",
    ),
    "limits inverted in the URDF": (
        {},
        {"b1": _joint("b1", "base", "bl1", lower=1, upper=-1)},
        "joint 'b1': <limit> has lower 1 above upper -1",
    ),
}


@pytest.mark.parametrize("case", sorted(URDF_CASES))
def test_non_physical_urdf_is_refused_naming_the_link_or_joint(case):
    links, joints, message = URDF_CASES[case]
    with pytest.raises(
        URDFLoadError, match=re.escape(f"cannot load URDF <URDF string>: {message}")
    ):
        _load(_robot(links, joints))


def test_urdf_error_in_a_task_is_located_at_the_urdf_key(tmp_path):
    (tmp_path / "r.urdf").write_text(_robot({"bl1": _link("bl1", mass=-2)}))
    path = _task(
        tmp_path,
        ("shipped: paper_robot.urdf", "urdf: r.urdf"),
        ("mission: [mission_joint1, mission_joint2, mission_joint3]", "mission: [m1, m2]"),
        ("balance: [balance_joint1, balance_joint2, balance_joint3]", "balance: [b1, b2]"),
    )
    _refused(
        path,
        "urdf: r.urdf",
        f"robot.urdf: cannot load URDF {tmp_path / 'r.urdf'}: link 'bl1': mass -2 kg is negative",
    )


def test_urdfdoms_reason_is_in_the_message_not_on_the_terminal(capfd):
    no_limits = '<joint name="b2" type="revolute"><parent link="bl1"/><child link="bl2"/></joint>'
    with pytest.raises(URDFLoadError) as info:
        _load(_robot(joints={"b2": no_limits}))
    assert (
        "Pinocchio could not build a model: The XML stream does not contain a valid URDF model. "
        "(urdfdom: Joint [b2] is of type REVOLUTE but it does not specify limits; joint xml is "
        "not initialized correctly)"
    ) in str(info.value)
    assert capfd.readouterr().err == ""


def test_implausible_inertias_are_warned_about_once_by_link(caplog):
    text = _robot({"bl2": _link("bl2", inertia=(0.01, 0.01, 0.05)), "ml1": _link("ml1", mass=0)})
    with caplog.at_level(logging.WARNING, logger="balance_opt.model.robot"):
        _load(text)
    messages = [r.getMessage() for r in caplog.records]
    assert messages == [
        "URDF <URDF string>: link 'ml1' has zero mass but a non-zero inertia",
        (
            "URDF <URDF string>: link 'bl2': principal moments 0.01, 0.01, 0.05 kg m^2 break the "
            "triangle inequality (no rigid body has them; are some given about a joint instead of "
            "the centre of mass?)"
        ),
    ]


def test_a_massless_base_is_refused_and_a_base_lighter_than_its_links_warned(caplog):
    """A spacecraft whose file forgot its mass: refused when the base weighs nothing, warned
    about when it weighs less than a link it carries."""
    with pytest.raises(URDFLoadError) as info:
        _load(_robot({"base": '<link name="base"/>'}))
    assert str(info.value) == (
        "cannot load URDF <URDF string>: the base (link base, with the links fixed to it and the "
        "locked joints' links) has no mass: a free-floating spacecraft needs its own; give link "
        "base an <inertial> with its mass and inertia"
    )
    mount = _link("mount", 2.0, (0.01, 0.01, 0.01))
    fixed = '<joint name="fix" type="fixed"><parent link="base"/><child link="mount"/></joint>'
    light = _robot({"base": '<link name="base"/>', "mount": mount}, {"fix": fixed})
    heavy = light.replace(
        'name="bl1"><inertial><mass value="1.0"', 'name="bl1"><inertial><mass value="3.0"'
    )
    with caplog.at_level(logging.WARNING, logger="balance_opt.model.robot"):
        assert _load(light).model.inertias[1].mass == pytest.approx(2.0)  # no link heavier
        assert not caplog.records
        _load(heavy)
    assert [r.getMessage() for r in caplog.records] == [
        "URDF <URDF string>: the base (link base and the links fixed to it) weighs 2 kg, less "
        "than the link of joint b1 it carries (3 kg): is the spacecraft's <inertial> missing?"
    ]


def test_massless_balance_arm_is_refused():
    massless = {n: f'<link name="{n}"/>' for n in ("bl1", "bl2")}
    with pytest.raises(ArmError) as info:
        _load(_robot(massless))
    assert str(info.value) == (
        "arm 'balance' of <URDF string>: moves no mass: the links below its joints (b1, b2) "
        "weigh 0 kg (of 52 kg); a massless balance arm cannot balance anything (check their "
        "<inertial> elements)"
    )
    # a light arm is an arm: 1 g of 50 kg
    light = {n: _link(n, mass=0.001, inertia=(1e-7, 1e-7, 1e-7)) for n in ("bl1", "bl2")}
    assert _load(_robot(light)).balance_arms[0].joints == ("b1", "b2")


# ------------------------------------------------------------------ numbers (defects 7, 10, 11, 14)
def test_huge_duration_is_refused_at_its_key_without_a_traceback(tmp_path, capsys):
    path = _task(tmp_path, ("duration: 10.0", "duration: 1.0e308"))
    code, err = _cli(["validate", path], capsys)
    line = _line_of(path.read_text(), "duration: 1.0e308")
    assert code == 2 and "Traceback" not in err
    assert err == (
        f"balance-opt: error: {path}:{line}: mission.duration: 1e+308 s sampled every 0.01 s "
        "(analytic.output_step: the analytic plan's outputs) is over 1e308 samples; a plan may "
        "hold at most 1e+06: at that step the longest is 1e+04 s\n"
    )


@pytest.mark.parametrize(
    ("extra", "fragment", "message"),
    [
        (
            "optimal: {resample_step: 1.0e-9}\n",
            "resample_step",
            (
                "optimal.resample_step: 1e-09 s over 10 s (the re-simulation of the optimal plan) is "
                "1e+10 samples; a plan may hold at most 1e+06: over 10 s the step must be at least "
                "1e-05 s"
            ),
        ),
        (
            "optimal: {horizon: 1.0e300}\n",
            "horizon",
            (
                "optimal.horizon: 1e+300 s sampled every 0.01 s (optimal.resample_step: the "
                "re-simulation of the optimal plan) is 1e+302 samples; a plan may hold at most "
                "1e+06: at that step the longest is 1e+04 s"
            ),
        ),
    ],
)
def test_time_grids_are_bounded(tmp_path, extra, fragment, message):
    _refused(_task(tmp_path, extra=extra), fragment, message)


def test_simulation_step_longer_than_the_motion_is_refused(tmp_path, capsys):
    path = _task(tmp_path, extra="simulation: {dt: 20}\n")
    code, err = _cli(["validate", path], capsys)
    assert code == 2
    assert err.endswith(
        f"{path}:{_line_of(path.read_text(), 'dt: 20')}: simulation.dt: the simulation's rk4 step "
        "of 20 s does not resolve the 10 s mission: it must be at most 1/100 of it, 0.1 s\n"
    )


def test_analytic_rk4_step_is_checked_too(tmp_path):
    path = _task(tmp_path, extra="analytic: {integrator: rk4, output_step: 0.5}\n")
    _refused(
        path,
        "output_step",
        "analytic.output_step: the analytic rk4 step of 0.5 s does not resolve the 10 s mission: "
        "it must be at most 1/100 of it, 0.1 s",
    )


@pytest.mark.parametrize(
    ("objective", "estimate"),
    [
        (
            "integral",
            (
                "15.7 GiB of memory (3 balance joints: 2.4e+06 variables, 4.17e+07 "
                "non-zeros in Ipopt's KKT matrix)"
            ),
        ),
        (
            "peak",
            (
                "21.8 GiB of memory (3 balance joints: 2.4e+06 variables, 5.81e+07 non-zeros "
                "in the KKT matrices of the 8 NLPs the plan builds)"
            ),
        ),
    ],
)
def test_too_many_intervals_are_refused_with_the_largest_that_fits(
    tmp_path, monkeypatch, objective, estimate
):
    from balance_opt.optimal import budget

    monkeypatch.setattr(budget, "memory_budget", lambda: 4 * 2**30)
    path = _task(tmp_path, extra=f"optimal: {{intervals: 100000, objective: {objective}}}\n")
    line = _line_of(path.read_text(), "intervals")
    with pytest.raises(TaskFileError) as info:
        load_task(path)
    message = str(info.value)
    assert message.startswith(
        f"{path}:{line}: optimal.intervals: 100000 intervals would need about {estimate}"
    )
    largest = int(re.search(r"at most (\d+) intervals fit$", message).group(1))
    fits = f"optimal: {{intervals: {largest}, objective: {objective}}}\n"
    task = load_task(_task(tmp_path, extra=fits, name="ok.yaml"))
    options, limits = task.spec.optimal.planner, task.robot.limits.subset([3, 4, 5])
    assert budget.problem_size(options, limits).memory_bytes <= 4 * 2**30
    bigger = dataclasses.replace(options, intervals=largest + 1)
    assert budget.problem_size(bigger, limits).memory_bytes > 4 * 2**30


@pytest.mark.parametrize("transcription", ["hermite-simpson", "trapezoidal"])
def test_the_largest_intervals_that_fit_are_the_largest(tmp_path, transcription):
    """The N offered in place of too many intervals fits and N + 1 does not, also where a fine
    peak plan's coarser grids (Stage.grids) make the size per interval change with N."""
    from balance_opt.optimal import budget

    task = load_task(_task(tmp_path, extra=f"optimal: {{transcription: {transcription}}}\n"))
    limits = task.robot.limits.subset([3, 4, 5])

    def size(n: int) -> float:
        options = dataclasses.replace(task.spec.optimal.planner, intervals=n)
        return budget.problem_size(options, limits).memory_bytes

    for asked, fits in ((2000, 1600), (1001, 800), (100000, 30000)):
        options = dataclasses.replace(task.spec.optimal.planner, intervals=asked)
        largest = budget.largest_intervals(options, limits, size(fits))
        assert largest >= fits and size(largest) <= size(fits) < size(largest + 1)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("transcription", "control", "torque", "acceleration", "objective", "jerk"),
    [
        ("hermite-simpson", "acceleration", False, 2.0, "peak", None),
        ("hermite-simpson", "jerk", False, None, "integral", None),
        ("trapezoidal", "jerk", True, None, "integral", None),
        ("trapezoidal", "acceleration", True, 2.0, "peak", None),
        ("hermite-simpson", "acceleration", False, 2.0, "peak", 10.0),
        ("hermite-simpson", "jerk", False, None, "integral", 10.0),
        ("trapezoidal", "jerk", False, None, "peak", 10.0),
    ],
)
def test_size_estimate_counts_the_planners_own_problem(
    paper, transcription, control, torque, acceleration, objective, jerk
):
    # The estimate (no CasADi) against the NLP the planner builds: sizes exact, non-zeros close.
    import numpy as np

    from balance_opt.model.library import PAPER_BALANCE_JOINTS, PAPER_MISSION_JOINTS, shipped_urdf
    from balance_opt.motion.trajectories import PointToPoint
    from balance_opt.optimal import budget
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.options import PlannerOptions
    from balance_opt.optimal.solve import build_balance_nlp

    limits = {j: {"acceleration": acceleration} for j in PAPER_BALANCE_JOINTS if acceleration}
    for j in PAPER_BALANCE_JOINTS if jerk else ():
        limits.setdefault(j, {})["jerk"] = jerk
    robot = FloatingRobot(shipped_urdf(), PAPER_MISSION_JOINTS, PAPER_BALANCE_JOINTS, limits=limits)
    model = PlannerModel(paper, compile=False)
    mission = PointToPoint(np.zeros(3), np.full(3, 0.1), 2.0)
    balance_limits = robot.limits.subset(robot.balance_indices)

    def size(st):
        jac = st.solver.get_function("nlp_jac_g").sparsity_out(1).nnz()
        hess = st.solver.get_function("nlp_hess_l").sparsity_out(0).nnz()
        return np.array(
            [st.variables.size, st.rows.size, jac + hess + st.variables.size + st.rows.size]
        )

    counts, inner_counts = [], []
    for N in (4, 6):  # below the inner stages' smallest grid: they have the plan's intervals
        options = PlannerOptions(
            intervals=N,
            transcription=transcription,
            control=control,
            torque_limits=torque,
            path_attitude_bound=0.1 if torque else None,
            objective=objective,
            collision_avoidance=False,  # not counted by the estimate (budget's docstring)
        )
        nlp = build_balance_nlp(model, mission, np.array([0.0, 0.5, -1.0]), options, robot=robot)
        counts.append(size(nlp.structure))
        inner_counts.append(size(nlp.stage("integral").structure))
    per_interval = (counts[1] - counts[0]) / 2
    n_w, n_g, nonzeros = budget._per_interval(options, balance_limits)
    assert (n_w, n_g) == tuple(per_interval[:2])
    assert nonzeros == pytest.approx(per_interval[2], rel=0.05)
    # the first stage, which every plan through the peak problem builds on its coarser grid
    inner = dataclasses.replace(options, objective="integral", **budget._INNER)
    inner = dataclasses.replace(inner, path_attitude_bound=None, terminal_attitude_bound=None)
    per_interval = (inner_counts[1] - inner_counts[0]) / 2
    n_w, n_g, nonzeros = budget._per_interval(inner, balance_limits)
    assert (n_w, n_g) == tuple(per_interval[:2])
    assert nonzeros == pytest.approx(per_interval[2], rel=0.05)


NUMBER_CASES = {
    "infinite momentum": (
        [("momentum: [0, 0, 0, 0, 0, 0]", "momentum: [0, 0, 0, 0, 0, .inf]")],
        "",
        "momentum:",
        "initial.momentum[5]: expected a finite number, got inf",
    ),
    "weight not a number": (
        [],
        "optimal:\n  weights: {omega: .nan}\n",
        "omega",
        "optimal.weights.omega: expected a number, got NaN",
    ),
    "infinite gain": (
        [],
        "simulation: {kp: .inf}\n",
        "kp:",
        "simulation.kp: expected a finite number, got inf",
    ),
    "lower limit of +inf": (
        [("balance_joint1: {acceleration: 2.0}", "balance_joint1: {lower: .inf}")],
        "",
        "lower: .inf",
        (
            "limits.balance_joint1.lower: joint 'balance_joint1' in {urdf}: lower limit inf is above "
            "upper limit 2.9671 (upper limit from the URDF)"
        ),
    ),
    "absurd goal": (
        [("goal: [1.2, 0.9, -1.6]", "goal: [1.2, 1.0e300, -1.6]")],
        "",
        "goal:",
        (
            "mission.goal[1]: the mission trajectory leaves the limits of the mission arm, which "
            "follows it as given: mission_joint2: position limit exceeded by up to 1e+300 rad from "
            "t = 0.005 s to 10.000 s (limit from URDF); no plan can meet them"
        ),
    ),
}


@pytest.mark.parametrize("case", sorted(NUMBER_CASES))
def test_non_finite_and_absurd_numbers_are_located_at_their_key(tmp_path, case):
    from balance_opt.model.library import shipped_urdf

    edits, extra, fragment, message = NUMBER_CASES[case]
    path = _task(tmp_path, *edits, extra=extra)
    _refused(path, fragment, message.format(urdf=shipped_urdf()))


@pytest.mark.slow
def test_diverged_simulation_is_a_failure_not_a_result(tmp_path):
    from balance_opt.app.pipeline import run_task

    path = _task(
        tmp_path,
        ("duration: 10.0", "duration: 2.0"),
        ("goal: [1.2, 0.9, -1.6]", "goal: [0.3, 0.4, -0.7]"),
    )
    task = load_task(path)
    # a step the loader refuses (20 s over 2 s), given through the Python API
    simulation = dataclasses.replace(task.spec.simulation, dt=20.0, output_dt=None)
    task = dataclasses.replace(task, spec=dataclasses.replace(task.spec, simulation=simulation))
    run = run_task(task, methods=("analytic",), simulate=True, output_dir=tmp_path / "out")
    assert "analytic" not in run.simulations
    failure = run.failures["simulation of analytic"]
    assert re.fullmatch(
        r"the forward-dynamics simulation of the analytic plan diverged \(stopped at t = 2 s: "
        r"joint mission_joint3 \S+ rad outside its range and its plan\); try a smaller "
        r"simulation\.dt \(now 20 s\) or the dopri5 integrator",
        failure,
    ), failure
    import json

    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    assert metrics["failures"]["simulation of analytic"] == failure


# ------------------------------------------------------------------ messages (defects 13, 16)
def test_empty_balance_arm_says_so(tmp_path):
    path = _task(
        tmp_path, ("balance: [balance_joint1, balance_joint2, balance_joint3]", "balance: []")
    )
    _refused(path, "balance: []", "arms.balance: must name at least one joint, got an empty list")


@pytest.mark.parametrize("name", ["../../x", ".hidden", "a/b", "my task", "x" * 101])
def test_task_name_that_is_not_a_plain_folder_name_is_refused(tmp_path, name):
    path = _task(tmp_path, ("name: capture_task", f"name: {name!r}"))
    _refused(
        path,
        "name: ",
        f"name: {name!r} is not allowed here: use letters, digits, '.', '_' and '-', starting "
        "with a letter or a digit, at most 100 characters",
    )


def test_plain_task_name_is_accepted(tmp_path):
    path = _task(tmp_path, ("name: capture_task", "name: Capture-2.v1_b"))
    assert load_task(path).name == "Capture-2.v1_b"


# ------------------------------------------------------------------ what plan needs (issue 12)
def test_validate_accepts_a_momentum_for_both_methods(tmp_path, capsys):
    """The optimal planner plans with a non-zero initial momentum (issue 16)."""
    path = _task(tmp_path, ("momentum: [0, 0, 0, 0, 0, 0]", "momentum: [0, 0, 0, 0, 0, 0.5]"))
    assert _cli(["validate", path], capsys)[0] == 0


def _prismatic_task(tmp_path: Path, extra: str, backend: str = "auto") -> Path:
    """A task on the small robot whose balance joint b2 is prismatic."""
    slide = (
        '<joint name="b2" type="prismatic"><parent link="bl1"/><child link="bl2"/>'
        '<axis xyz="1 0 0"/><limit lower="-0.1" upper="0.1" effort="10" velocity="1"/></joint>'
    )
    (tmp_path / "r.urdf").write_text(_robot(joints={"b2": slide}))
    return _task(
        tmp_path,
        ("shipped: paper_robot.urdf", f"urdf: r.urdf\n  backend: {backend}"),
        ("mission: [mission_joint1, mission_joint2, mission_joint3]", "mission: [m1, m2]"),
        ("balance: [balance_joint1, balance_joint2, balance_joint3]", "balance: [b1, b2]"),
        ("  balance: [0.0, 0.5, -1.0]", "  balance: [0.0, 0.0]"),
        ("start: [0.0, 0.3, -0.6]", "start: [0.0, 0.3]"),
        ("goal: [1.2, 0.9, -1.6]", "goal: [0.5, 0.6]"),
        ("mission_joint1: {acceleration: 2.0}\n", "m1: {acceleration: 2.0}\n"),
        ("  mission_joint2: {acceleration: 2.0}\n", "  m2: {acceleration: 2.0}\n"),
        ("  mission_joint3: {acceleration: 2.0}\n", ""),
        ("balance_joint1: {acceleration: 2.0}", "b1: {acceleration: 2.0}"),
        ("  balance_joint2: {acceleration: 2.0}\n", ""),
        ("  balance_joint3: {acceleration: 2.0}\n", ""),
        extra=extra,
    )


def test_torque_limits_with_a_prismatic_joint_are_refused(tmp_path, capsys):
    path = _prismatic_task(tmp_path, "optimal:\n  constraints: {torque_limits: true}\n")
    line = _line_of(path.read_text(), "torque_limits")
    code, err = _cli(["validate", path], capsys)
    assert code == 2
    assert err == (
        f"balance-opt: error: {path}:{line}: optimal.constraints.torque_limits: torque limits "
        "are computed with adam-robotics, which cannot handle the prismatic joint 'b2'; turn "
        "them off, lock the joint, or plan with --method analytic\n"
    )
    assert _cli(["validate", "--method", "analytic", path], capsys)[0] == 0


def test_prismatic_joint_with_the_adam_backend_is_refused(tmp_path):
    path = _prismatic_task(tmp_path, "", backend="adam")
    task = load_task(path)  # the analytic law takes it
    from balance_opt.tasks.task import check_methods

    line = _line_of(path.read_text(), "balance: [b1, b2]")
    with pytest.raises(TaskFileError) as info:
        check_methods(task, ("analytic", "optimal"))
    assert str(info.value) == (
        f"{path}:{line}: arms.balance[1]: joint 'b2' is prismatic, which the adam backend "
        "(robot.backend) cannot handle; lock it, use the pinocchio backend, or plan with "
        "--method analytic"
    )


@pytest.mark.filterwarnings("ignore::RuntimeWarning")  # scipy on the blown-up step
def test_integration_that_fails_in_its_first_step_reports_it():
    # An absurd initial momentum (1e300 N m s) made the attitude integration fail at once, and
    # the empty output of the integrator crashed instead of reporting the failure.
    import numpy as np

    from balance_opt.motion.integration import integrate
    from balance_opt.motion.options import IntegrationOptions

    y0 = np.array([0.0, 0.0, 0.0, 1.0])
    Y, _, message = integrate(
        lambda t, y: np.full(4, 1e300) * (1.0 + t),
        y0,
        np.linspace(0.0, 1.0, 11),
        IntegrationOptions(),
    )
    assert Y.tolist() == [y0.tolist()] and message is not None and "(at t = 0 s)" in message


@pytest.mark.parametrize("method", ["adaptive", "rk4"])
def test_integrated_attitude_of_a_constant_body_rate_is_exact(method):
    # q(t) = q0 * exp(omega t / 2) for a constant body rate: both integrators reach it to
    # their tolerance, the adaptive one (SciPy's DOP853) to its rtol, over many turns.
    import numpy as np

    from balance_opt.motion.integration import integrate
    from balance_opt.motion.options import IntegrationOptions
    from balance_opt.motion.so3 import (
        quaternion_from_rotvec,
        quaternion_multiply,
        quaternion_rate,
        relative_rotation,
        rotation_angle,
    )

    omega = np.array([0.3, -0.2, 0.5])
    q0 = quaternion_from_rotvec(np.array([0.1, 0.2, -0.3]))
    t = np.linspace(0.0, 20.0, 201)
    step = None if method == "adaptive" else 0.01
    options = IntegrationOptions(method=method, rtol=1e-10, atol=1e-12, step=step)
    Y, stats, message = integrate(lambda t, y: quaternion_rate(y, omega), q0, t, options)
    exact = quaternion_multiply(q0, quaternion_from_rotvec(np.outer(t, omega)))
    assert message is None and stats["method"] == method
    error = rotation_angle(relative_rotation(exact, Y))
    assert error.max() < (1e-8 if method == "adaptive" else 1e-7)
    np.testing.assert_allclose(np.linalg.norm(Y, axis=1), 1.0, atol=1e-15)
