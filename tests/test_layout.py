"""benchmarks/layout_check.py on small made-up packages: it finds an upward import and a cycle
(of modules, or of parts) wherever the import sits (inside a function too, not under
``if TYPE_CHECKING:``), and fails."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

CHECK = Path(__file__).resolve().parents[1] / "benchmarks" / "layout_check.py"


def _package(root: Path, files: dict[str, str]) -> Path:
    package = root / "balance_opt"
    for name, text in files.items():
        path = package / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    for folder in {package, *(p.parent for p in package.rglob("*.py"))}:
        (folder / "__init__.py").touch()
    return package


def _check(package: Path) -> tuple[int, str]:
    done = subprocess.run(
        [sys.executable, str(CHECK), "--package", str(package)],
        capture_output=True,
        text=True,
        check=False,
    )
    return done.returncode, done.stdout


def test_downward_imports_pass(tmp_path):
    package = _package(
        tmp_path,
        {
            "model/robot.py": "from balance_opt.errors import InputError\n",
            "motion/replay.py": "def f():\n    from balance_opt.model import robot\n",
            "errors.py": "class InputError(Exception):\n    pass\n",
        },
    )
    code, out = _check(package)
    assert code == 0, out
    assert "upward imports: 0" in out and "import cycles: 0 in 0 group(s)" in out


def test_upward_import_inside_a_function_fails(tmp_path):
    package = _package(
        tmp_path,
        {
            "model/capture.py": "def f():\n    from balance_opt.motion.so3 import exp\n",
            "motion/so3.py": "def exp():\n    pass\n",
        },
    )
    code, out = _check(package)
    assert code == 1
    assert "upward imports: 1" in out
    assert "  model.capture (model) -> motion.so3 (motion)" in out


@pytest.mark.parametrize("guarded", [True, False])
def test_cycle_counts_only_imports_that_run(tmp_path, guarded):
    lazy = "def f():\n    from balance_opt.sweep import spec\n"
    typed = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n"
        "    from balance_opt.sweep import spec\n"
    )
    package = _package(
        tmp_path,
        {
            "sweep/spec.py": "from balance_opt.sweep import cases\n",
            "sweep/cases.py": typed if guarded else lazy,
        },
    )
    code, out = _check(package)
    if guarded:
        assert code == 0 and "import cycles: 0 in 0 group(s)" in out
    else:
        assert code == 1 and "import cycles: 1 in 1 group(s)" in out
        assert "    sweep.cases -> sweep.spec -> sweep.cases" in out


def test_a_part_in_no_layer_fails(tmp_path):
    code, out = _check(_package(tmp_path, {"io/task.py": "X = 1\n"}))
    assert code == 1 and "parts in no layer of LAYERS: 'io'" in out


def test_the_package_keeps_its_layers():
    code, out = _check(CHECK.parents[1] / "balance_opt")
    assert "import cycles: 0 in 0 group(s)" in out and "cycles between parts: 0" in out
    upward = [line for line in out.splitlines() if line.startswith("  ") and " -> " in line]
    if (CHECK.parents[1] / "balance_opt" / "optimal" / "start_schedule.py").exists():
        # on its way out of the planner, with its pool of sweep workers
        assert all(line.startswith("  optimal.start_schedule ") for line in upward), out
    else:
        assert code == 0 and not upward, out


def test_two_parts_of_one_layer_importing_each_other_fail(tmp_path, monkeypatch, capsys):
    """No module imports itself back, but part ``motion`` imports part ``result`` and back: the
    cycle a shared layer used to hide."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("layout_check", CHECK)
    layout = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(layout)
    layers = [(n, ("motion", "result") if n == "motion" else p) for n, p in layout.LAYERS]
    monkeypatch.setattr(layout, "LAYERS", tuple(layers))
    package = _package(
        tmp_path,
        {
            "motion/so3.py": "def angle():\n    pass\n",
            "motion/replay.py": "from balance_opt.result import Result\n",
            "result.py": "from balance_opt.motion.so3 import angle\nclass Result:\n    pass\n",
        },
    )
    code = layout.main(["--package", str(package)])
    out = capsys.readouterr().out
    assert "import cycles: 0 in 0 group(s)" in out and "upward imports: 0" in out
    assert code == 1 and "cycles between parts: 1\n  motion -> result -> motion" in out


@pytest.mark.parametrize("sizes", [False, True])
def test_sizes_fail_only_with_the_flag(tmp_path, sizes):
    """A module over 600 lines and a function over 80 are listed always, and fail with
    ``--sizes``."""
    body = "".join(f"    x{i} = {i}\n" for i in range(85))
    package = _package(
        tmp_path,
        {
            "model/big.py": "def long():\n" + body + "".join(f"Y{i} = {i}\n" for i in range(600)),
            "model/small.py": "def short():\n    return 1\n",
        },
    )
    done = subprocess.run(
        [sys.executable, str(CHECK), "--package", str(package), *(["--sizes"] if sizes else [])],
        capture_output=True,
        text=True,
        check=False,
    )
    out = done.stdout
    assert re.search(r"^balance_opt/model/big.py +686 +OVER", out, re.MULTILINE), out
    assert re.search(r"^balance_opt/model/big.py:1 +long +86 +NO", out, re.MULTILINE), out
    if sizes:
        assert done.returncode == 1
        assert "size limits: 1 module(s) over 600 lines, 1 function(s) over 80 lines" in out
    else:
        assert done.returncode == 0 and "size limits" not in out


def test_no_module_over_600_lines_nor_function_over_80_outside_optimal():
    """The size limits hold outside ``optimal/`` (whose restructuring brings it under them; then
    ``--sizes`` in ``.ci/run`` checks the whole package)."""
    _, out = _check(CHECK.parents[1] / "balance_opt")
    rows = [line.split() for line in out.splitlines() if line.startswith("balance_opt/")]
    over = [r[0] for r in rows if r[-1] == "OVER"]  # the modules' table
    long = [r[0] for r in rows if ".py:" in r[0]]  # the functions' table
    assert rows and all(r.startswith("balance_opt/optimal/") for r in over + long), out
