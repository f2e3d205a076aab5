"""Reliability: bad input refused before any work, with the option, key or file named."""

import math
import os
import subprocess
import sys

import pytest

from balance_opt.solvers import ipopt_options


@pytest.fixture(scope="module")
def catalog():
    return ipopt_options.option_catalog()


def test_catalog_is_ipopts_own_list(catalog):
    # Types and ranges as Ipopt documents them, read from the bundled library.
    assert (
        catalog["tol"].type == "real" and catalog["tol"].lower == 0 and catalog["tol"].lower_strict
    )
    assert catalog["max_iter"].type == "integer" and catalog["max_iter"].lower == 0
    assert catalog["print_level"].upper == 12 and not catalog["print_level"].upper_strict
    assert {"mumps", "ma57"} <= set(catalog["linear_solver"].values)
    assert catalog["mu_superlinear_decrease_power"].upper_strict
    assert len(catalog) > 200


@pytest.mark.parametrize(
    ("name", "value", "message"),
    [
        ("tolx", 1e-3, "unknown Ipopt option 'tolx'; did you mean 'tol'?"),
        (
            "tol",
            math.nan,
            "Ipopt option 'tol' must be finite, got nan; expected a finite number > 0",
        ),
        ("tol", 0.0, "Ipopt option 'tol' is out of range, got 0.0; expected a finite number > 0"),
        (
            "max_iter",
            10.5,
            "Ipopt option 'max_iter' takes an integer, got 10.5; expected an integer >= 0",
        ),
        ("max_iter", "many", "Ipopt option 'max_iter' takes a number, got 'many'"),
        ("max_iter", True, "Ipopt option 'max_iter' takes a number, got True"),
        ("print_level", 13, "out of range, got 13; expected an integer >= 0 and <= 12"),
        (
            "hessian_approximation",
            "bfgs",
            "does not accept 'bfgs'; expected one of 'exact', 'limited-memory'",
        ),
        ("linear_solver", "ma57", "Ipopt cannot load linear solver 'ma57'"),
        ("mu_strategy", 3, "Ipopt option 'mu_strategy' takes a string, got 3"),
    ],
)
def test_bad_ipopt_option_is_named(catalog, name, value, message):
    problem = ipopt_options.option_problem(name, value, catalog)
    assert problem is not None and message in problem


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("tol", 1e-6),
        ("max_iter", 500),
        ("max_iter", 500.0),
        ("print_level", 12),
        ("sb", "yes"),
        ("linear_solver", "mumps"),
        ("hessian_approximation", "limited-memory"),
    ],
)
def test_good_ipopt_option_passes(catalog, name, value):
    assert ipopt_options.option_problem(name, value, catalog) is None


def test_probing_linear_solvers_leaves_ipopt_usable():
    """The probe runs in this process: a refused ``ma97`` (no HSL library) would make the next
    Ipopt solve of the process crash, so the probes and a solve after them run in a child."""
    code = (
        "import casadi as cs\n"
        "from balance_opt.solvers.ipopt_options import linear_solver_loads\n"
        "found = [linear_solver_loads(n) for n in ('ma97', 'ma57', 'pardiso', 'mumps')]\n"
        "x = cs.SX.sym('x')\n"
        "opts = {'ipopt.print_level': 0, 'ipopt.sb': 'yes', 'print_time': 0}\n"
        "solver = cs.nlpsol('s', 'ipopt', {'x': x, 'f': (x - 2) ** 2}, opts)\n"
        "print(found[-1], float(solver(x0=0)['x']))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["True", "2.0"]


def test_an_hsl_library_without_the_solver_is_refused_not_a_crash(tmp_path):
    """A ``libhsl`` that loads but lacks the solver's functions (a partial HSL build; here an
    empty library) makes Ipopt crash on ``ma97``: the probe refuses it before Ipopt tries. Run
    in a child, with the library on the loader's path as an installed one would be."""
    from balance_opt.solvers.codegen import find_compiler

    compiler = find_compiler()
    if compiler is None:
        pytest.skip("no C compiler")
    (tmp_path / "empty.c").write_text("int balance_opt_nothing;\n")
    library = tmp_path / "libhsl.so"
    subprocess.run([compiler, "-shared", "-fPIC", "-o", library, tmp_path / "empty.c"], check=True)
    code = (
        "from balance_opt.solvers.ipopt_options import option_catalog, option_problem\n"
        "catalog = option_catalog()\n"
        "for solver in ('ma97', 'ma27'):\n"
        "    print(option_problem('linear_solver', solver, catalog))\n"
        f"print(option_problem('linear_solver', 'ma97', catalog, {{'hsllib': '{library}'}}))\n"
    )
    env = {**os.environ, "LD_LIBRARY_PATH": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=False, env=env
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert len(lines) == 3
    for line, solver in zip(lines, ("ma97", "ma27", "ma97")):
        assert line.startswith(f"Ipopt cannot load linear solver '{solver}'")


def test_catalog_cached_on_disk_is_reused(tmp_path, monkeypatch, catalog):
    monkeypatch.setenv("BALANCE_OPT_CACHE", str(tmp_path))
    first = ipopt_options.option_catalog()
    files = list(tmp_path.glob("ipopt-options-*.json"))
    assert len(files) == 1 and first == catalog
    # A second process reads the file: asking Ipopt again would be a failure here.
    monkeypatch.setattr(ipopt_options, "_documentation_from_ipopt", lambda: pytest.fail("re-read"))
    assert ipopt_options.option_catalog() == catalog


# ---------------------------------------------------------------------------- output folders
def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def test_output_folder_replaces_whole_run_only_when_complete(tmp_path):
    from balance_opt.report.output_dir import OutputFolder

    target = tmp_path / "run"
    target.mkdir()
    (target / "optimal.csv").write_text("old")
    (target / "metrics.json").write_text("old")
    with OutputFolder(target, force=True) as out:
        (out.staging / "metrics.json").write_text("new")
        # While the run writes, the old results are intact.
        assert (target / "optimal.csv").read_text() == "old"
    assert _files(target) == ["metrics.json"]  # no file of the earlier run is left
    assert (target / "metrics.json").read_text() == "new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no staging, no lock left


def test_output_folder_interrupted_run_leaves_previous_results(tmp_path):
    from balance_opt.report.output_dir import OutputFolder

    target = tmp_path / "run"
    target.mkdir()
    (target / "metrics.json").write_text("old")
    with pytest.raises(KeyboardInterrupt), OutputFolder(target, force=True) as out:
        (out.staging / "metrics.json").write_text("half")
        raise KeyboardInterrupt
    assert _files(target) == ["metrics.json"] and (target / "metrics.json").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_output_folder_refuses_non_empty_without_force(tmp_path):
    from balance_opt.report.output_dir import OutputFolder, OutputFolderError

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "x.txt").write_text("keep")
    with pytest.raises(OutputFolderError, match=r"exists and is not empty; use --force"):
        OutputFolder(tmp_path / "run").open()
    assert (tmp_path / "run" / "x.txt").read_text() == "keep"


@pytest.mark.parametrize("where", ["file-parent", "proc"])
def test_output_folder_not_creatable_fails_at_once(tmp_path, where):
    from balance_opt.report.output_dir import OutputFolder, OutputFolderError

    if where == "file-parent":
        (tmp_path / "plain").write_text("")
        target = tmp_path / "plain" / "run"
    else:
        target = "/proc/balance-opt-run"
    with pytest.raises(OutputFolderError, match=r"cannot (create|write in) output folder"):
        OutputFolder(target).open()


def test_output_folder_lock_refuses_second_run_and_dies_with_its_holder(tmp_path):
    import signal
    import subprocess
    import sys

    from balance_opt.report.output_dir import OutputFolder, OutputFolderError

    target = tmp_path / "run"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            (
                "import sys, time\n"
                "from balance_opt.report.output_dir import OutputFolder\n"
                f"out = OutputFolder({str(target)!r}); out.open(); print('ready', flush=True)\n"
                "time.sleep(60)\n"
            ),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "ready"
        with pytest.raises(
            OutputFolderError,
            match=rf"being written by another balance-opt run \(process {holder.pid}\)",
        ):
            OutputFolder(target).open()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    # The kernel released the lock; the killed run's staging folder is cleaned up.
    with OutputFolder(target) as out:
        (out.staging / "a.txt").write_text("x")
    assert _files(target) == ["a.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


# ---------------------------------------------------------------------------- URDF physics
_LINK = '<link name="{n}"><inertial><mass value="{m}"/><inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial></link>'
_JOINT = '<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><axis xyz="{axis}"/><limit lower="-1" upper="1" effort="1" velocity="1"/></joint>'


def _urdf(links=None, joints=None):
    import xml.etree.ElementTree as ET

    links = links or [
        {"n": "base", "m": 10, "ixx": 1, "iyy": 1, "izz": 1},
        {"n": "arm", "m": 1, "ixx": 0.1, "iyy": 0.1, "izz": 0.05},
    ]
    joints = (
        joints if joints is not None else [{"n": "j1", "p": "base", "c": "arm", "axis": "0 0 1"}]
    )
    text = "<robot name='r'>" + "".join(_LINK.format(**lk) for lk in links)
    text += "".join(_JOINT.format(**j) for j in joints) + "</robot>"
    return ET.fromstring(text)


def test_physical_urdf_passes_without_warnings():
    from balance_opt.model.urdf_checks import check_urdf_physics

    assert check_urdf_physics(_urdf(), "r.urdf") == []


@pytest.mark.parametrize(
    ("links", "joints", "message"),
    [
        (
            [
                {"n": "base", "m": 10, "ixx": 1, "iyy": 1, "izz": 1},
                {"n": "arm", "m": -1, "ixx": 0.1, "iyy": 0.1, "izz": 0.05},
            ],
            None,
            "r.urdf: link 'arm': mass -1 kg is negative",
        ),
        (
            [
                {"n": "base", "m": 10, "ixx": 1, "iyy": 1, "izz": 1},
                {"n": "arm", "m": 1, "ixx": 0.1, "iyy": -0.1, "izz": 0.05},
            ],
            None,
            "link 'arm': inertia is not positive semi-definite",
        ),
        (
            [
                {"n": "base", "m": 10, "ixx": 1, "iyy": 1, "izz": 1},
                {"n": "arm", "m": "nan", "ixx": 0.1, "iyy": 0.1, "izz": 0.05},
            ],
            None,
            "link 'arm': <inertial> <mass value=...> is 'nan', not a finite number",
        ),
        (
            None,
            [{"n": "j1", "p": "base", "c": "arm", "axis": "0 0 0"}],
            "joint 'j1': axis is of zero length",
        ),
        (
            None,
            [
                {"n": "j1", "p": "base", "c": "arm", "axis": "0 0 1"},
                {"n": "j2", "p": "base", "c": "arm", "axis": "0 0 1"},
            ],
            "link 'arm' is the child of two joints ('j1' and 'j2')",
        ),
        (
            None,
            [{"n": "j1", "p": "base", "c": "hand", "axis": "0 0 1"}],
            "joint 'j1': its child link 'hand' is not a <link>",
        ),
        (None, [], "a URDF has one root link, this one has 2: 'base', 'arm'"),
    ],
)
def test_non_physical_urdf_refused_naming_link_or_joint(links, joints, message):
    from balance_opt.errors import URDFLoadError
    from balance_opt.model.urdf_checks import check_urdf_physics

    with pytest.raises(URDFLoadError) as info:
        check_urdf_physics(_urdf(links, joints), "r.urdf")
    assert message in str(info.value)


def test_implausible_inertias_are_warned_by_link():
    from balance_opt.model.urdf_checks import check_urdf_physics

    links = [
        {"n": "base", "m": 10, "ixx": 1, "iyy": 1, "izz": 1},
        {"n": "arm", "m": 1, "ixx": 0.01, "iyy": 0.01, "izz": 0.05},  # 0.01 + 0.01 < 0.05
        {"n": "tip", "m": 0, "ixx": 0.1, "iyy": 0.1, "izz": 0.1},
    ]
    joints = [
        {"n": "j1", "p": "base", "c": "arm", "axis": "0 0 1"},
        {"n": "j2", "p": "arm", "c": "tip", "axis": "0 1 0"},
    ]
    warnings = check_urdf_physics(_urdf(links, joints), "r.urdf")
    assert len(warnings) == 2
    assert (
        "link 'arm': principal moments 0.01, 0.01, 0.05 kg m^2 break the triangle inequality"
        in warnings[0]
    )
    assert warnings[1] == "link 'tip' has zero mass but a non-zero inertia"


# ---------------------------------------------------------------------------- outputs of commands
_EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[1] / "examples"


def _task_file(tmp_path, extra=""):
    """The capture task made fast (short move, few intervals, coarse output grids)."""
    text = (_EXAMPLES / "capture_task.yaml").read_text()
    text = text.replace("goal: [1.2, 0.9, -1.6]", "goal: [0.6, 0.6, -1.1]")
    text = text.replace("duration: 10.0", "duration: 3.0")
    text += (
        "analytic: {output_step: 0.05}\noptimal: {intervals: 12}\n"
        "simulation: {dt: 0.002, output_dt: 0.05}\n" + extra
    )
    path = tmp_path / "task.yaml"
    path.write_text(text)
    return path


@pytest.mark.slow
def test_force_leaves_no_file_of_the_earlier_run(tmp_path):
    from balance_opt.cli import main

    task = _task_file(tmp_path)
    out, fresh = tmp_path / "out", tmp_path / "fresh"
    assert main(["compare", str(task), "-o", str(out), "-q"]) == 0
    assert {"optimal.csv", "optimal.npz", "reaction_torque.png"} <= set(_files(out))
    assert main(["plan", str(task), "-m", "analytic", "-o", str(out), "--force", "-q"]) == 0
    assert main(["plan", str(task), "-m", "analytic", "-o", str(fresh), "-q"]) == 0
    assert _files(out) == _files(fresh)  # exactly the files of an analytic plan
    assert not any("optimal" in name for name in _files(out))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fresh", "out", "task.yaml"]


@pytest.mark.parametrize("where", ["file-parent", "in-use", "not-empty"])
def test_output_folder_checked_before_the_task_is_loaded(tmp_path, capsys, monkeypatch, where):
    from balance_opt.cli import main
    from balance_opt.report.output_dir import FolderLock
    from balance_opt.tasks import task as task_module

    monkeypatch.setattr(task_module, "load_task", lambda path: pytest.fail("task loaded"))
    out = tmp_path / "out"
    lock = FolderLock(out)
    if where == "file-parent":
        (tmp_path / "plain").write_text("")
        out = tmp_path / "plain" / "out"
        message = f"cannot create output folder {out}: {tmp_path / 'plain'} is a file"
        before = ["plain"]
    elif where == "in-use":
        lock.acquire()  # another run (an open file description of its own) holds the lock
        message = f"output folder {out} is being written by another balance-opt run"
        before = []
    else:
        out.mkdir()
        (out / "mine.txt").write_text("mine")
        message = f"output folder {out} exists and is not empty; use --force"
        before = ["out", "out/mine.txt"]
    try:
        assert main(["plan", "task.yaml", "-o", str(out)]) == 2
    finally:
        lock.release()
    assert f"balance-opt: error: {message}" in capsys.readouterr().err
    assert _files(tmp_path) == before  # nothing written, nothing left beside


def test_default_output_folder_checked_before_any_computation(tmp_path, capsys, monkeypatch):
    from balance_opt.app import pipeline
    from balance_opt.cli import main

    task = _task_file(tmp_path)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "results").write_text("a file where the results folder goes")
    monkeypatch.setattr(pipeline, "_plan_into", lambda *a: pytest.fail("planning started"))
    assert main(["plan", str(task)]) == 2
    err = capsys.readouterr().err
    results = tmp_path / "results"
    assert f"cannot create output folder {results / 'capture_task'}: {results} is a file" in err


@pytest.mark.parametrize(
    ("name", "folder"),
    [
        ("capture_task", "capture_task"),
        ("../../x", "_.._x"),
        ("/etc/passwd", "_etc_passwd"),
        (".hidden", "hidden"),
        ("..", "unnamed"),
        ("capture run 2", "capture_run_2"),
        ("capture\\run", "capture_run"),
    ],
)
def test_default_output_folder_name_is_sanitised(name, folder):
    from pathlib import Path

    from balance_opt.commands.common import default_output_folder

    assert default_output_folder(name) == Path("results") / folder


def test_task_name_cannot_write_outside_results(tmp_path, monkeypatch):
    from balance_opt.cli import main
    from balance_opt.tasks.task import Task

    task = _task_file(tmp_path, "outputs: {plots: false, report: false}\n")
    work = tmp_path / "a" / "b"
    work.mkdir(parents=True)
    monkeypatch.chdir(work)
    monkeypatch.setattr(Task, "name", property(lambda self: "../../x"))
    assert main(["plan", str(task), "-m", "analytic", "-q"]) == 0
    assert (work / "results" / "_.._x" / "metrics.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "task.yaml"]
    assert sorted(p.name for p in (work / "results").iterdir()) == ["_.._x"]


def test_validate_reports_every_file(tmp_path, capsys):
    from balance_opt.cli import main

    good = _task_file(tmp_path)
    no_robot = tmp_path / "no_robot.yaml"
    no_robot.write_text("name: x\n")
    missing = tmp_path / "missing.yaml"
    code = main(["validate", str(no_robot), str(good), str(missing), str(_EXAMPLES / "x.yaml")])
    captured = capsys.readouterr()
    err = captured.err
    assert code == 2
    errors = [line for line in err.splitlines() if line.startswith("balance-opt: error: ")]
    assert [e.split(": ")[2].split(":")[0] for e in errors] == [
        str(no_robot),
        str(missing),
        str(_EXAMPLES / "x.yaml"),
    ]
    assert "missing required key 'robot'" in errors[0]
    assert f"{good}: ok" in captured.out and "3 of 4 task files failed" in captured.out
    assert main(["validate", str(good), str(_EXAMPLES / "baxter_floating.yaml")]) == 0


def test_sweep_into_a_folder_in_use_is_refused(tmp_path, capsys):
    from balance_opt.cli import main
    from balance_opt.report.output_dir import FolderLock

    sweep = tmp_path / "s.yaml"
    sweep.write_text(
        f"task: {_EXAMPLES / 'capture_task.yaml'}\nname: s\nmethods: [analytic]\n"
        "grid:\n  mission.duration: [1.0, 2.0]\n"
    )
    out = tmp_path / "out"
    with FolderLock(out):
        assert main(["sweep", str(sweep), "-o", str(out), "-j", "0"]) == 2
    assert f"output folder {out} is being written by another" in capsys.readouterr().err
    assert not out.exists()


def test_replaced_atomically_keeps_the_old_file_on_error(tmp_path):
    from balance_opt.report.output_dir import replaced_atomically

    path = tmp_path / "summary.json"
    path.write_text("old")
    with pytest.raises(KeyboardInterrupt), replaced_atomically(path) as tmp:
        tmp.write_text("half")
        raise KeyboardInterrupt
    assert path.read_text() == "old" and _files(tmp_path) == ["summary.json"]
    with replaced_atomically(path) as tmp:
        tmp.write_text("new")
    assert path.read_text() == "new" and _files(tmp_path) == ["summary.json"]
