"""Reliability: bad input refused before any work, with the option, key or file named."""

import math

import pytest

from balance_opt.optimal import ipopt_options


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


def test_catalog_cached_on_disk_is_reused(tmp_path, monkeypatch, catalog):
    monkeypatch.setenv("BALANCE_OPT_CACHE", str(tmp_path))
    monkeypatch.setattr(ipopt_options, "_CATALOG", None)
    first = ipopt_options.option_catalog()
    files = list(tmp_path.glob("ipopt-options-*.json"))
    assert len(files) == 1 and first == catalog
    # A second process reads the file: asking Ipopt again would be a failure here.
    monkeypatch.setattr(ipopt_options, "_CATALOG", None)
    monkeypatch.setattr(ipopt_options, "_documentation_from_ipopt", lambda: pytest.fail("re-read"))
    assert ipopt_options.option_catalog() == catalog


# ---------------------------------------------------------------------------- output folders
def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def test_output_folder_replaces_whole_run_only_when_complete(tmp_path):
    from balance_opt.io.output_dir import OutputFolder

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
    from balance_opt.io.output_dir import OutputFolder

    target = tmp_path / "run"
    target.mkdir()
    (target / "metrics.json").write_text("old")
    with pytest.raises(KeyboardInterrupt), OutputFolder(target, force=True) as out:
        (out.staging / "metrics.json").write_text("half")
        raise KeyboardInterrupt
    assert _files(target) == ["metrics.json"] and (target / "metrics.json").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_output_folder_refuses_non_empty_without_force(tmp_path):
    from balance_opt.io.output_dir import OutputFolder, OutputFolderError

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "x.txt").write_text("keep")
    with pytest.raises(OutputFolderError, match=r"exists and is not empty; use --force"):
        OutputFolder(tmp_path / "run").open()
    assert (tmp_path / "run" / "x.txt").read_text() == "keep"


@pytest.mark.parametrize("where", ["file-parent", "proc"])
def test_output_folder_not_creatable_fails_at_once(tmp_path, where):
    from balance_opt.io.output_dir import OutputFolder, OutputFolderError

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

    from balance_opt.io.output_dir import OutputFolder, OutputFolderError

    target = tmp_path / "run"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            (
                "import sys, time\n"
                "from balance_opt.io.output_dir import OutputFolder\n"
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
