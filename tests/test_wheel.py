"""The wheel a user installs (issue 34): every subpackage of ``balance_opt/`` and the data files
the package reads at run time (shipped URDFs, the bridge's C++ source, the scene's player). ``.ci/run`` installs the
same wheel into a fresh venv and plans from outside the checkout."""

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
#: What a checkout holds beside its tracked files (.gitignore), left out of the copy built.
UNTRACKED = (".git", ".venv", "build", "dist", "*.egg-info", "__pycache__", "out", "results")


@pytest.mark.slow
def test_the_wheel_holds_every_module_and_the_data_files(tmp_path):
    # built from a copy: a build writes build/ and *.egg-info into the tree it builds
    source = tmp_path / "src"
    shutil.copytree(ROOT, source, ignore=shutil.ignore_patterns(".pytest_cache", *UNTRACKED))
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", tmp_path, source],
        check=True,
        capture_output=True,
    )
    [wheel] = tmp_path.glob("balance_opt-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    package = ROOT / "balance_opt"
    modules = {
        f"balance_opt/{p.relative_to(package).as_posix()}"
        for p in package.rglob("*.py")
        if "__pycache__" not in p.parts
    }
    modules |= {f"balance_opt/urdf/{p.name}" for p in (ROOT / "urdf").glob("*.py")}  # mapped
    subpackages = {Path(m).parent.as_posix() for m in modules if m.endswith("/__init__.py")}
    assert "balance_opt/geometry" in subpackages  # the one a hand-kept list left out
    assert {m for m in names if m.endswith(".py")} == modules
    data = {f"balance_opt/urdf/{p.name}" for p in (ROOT / "urdf").glob("*.*") if p.suffix != ".py"}
    data |= {f"balance_opt/model/cpp/{p.name}" for p in (package / "model" / "cpp").glob("*.cpp")}
    data |= {
        f"balance_opt/report/assets/{p.name}" for p in (package / "report" / "assets").glob("*")
    }
    assert len(data) >= 7 and data <= names
    assert {
        "balance_opt/report/assets/scene_player.js",
        "balance_opt/report/assets/scene.css",
    } <= names
    assert "balance_opt/urdf/paper_robot.urdf" in names
    entry = zipfile.ZipFile(wheel).read(
        next(n for n in names if n.endswith(".dist-info/entry_points.txt"))
    )
    assert b"balance-opt = balance_opt.cli:main" in entry
