"""Shared fixtures: robots and their maps, built once per test session.

Compiled planner kernels go to a temporary folder of this test session (removed at its end), never
to the user's own cache; set ``BALANCE_OPT_TEST_CACHE`` to a folder to keep them across runs. A
Pinocchio-CasADi bridge already built in the user's cache (``$BALANCE_OPT_CACHE`` or the default
folder) is copied into the temporary one (the user's is only read); without one, the header
says that the tests that need it build one (minutes).
"""

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

from balance_opt.cache import check_record, default_cache_dir
from balance_opt.model.bridge import FOLDER
from balance_opt.optimal.collocation import joint_chain_coefficients


def urdf_task(folder: Path, name: str, urdf: str, body: str, srdf: str | None = None) -> Path:
    """A task file ``NAME.yaml`` in ``folder`` on the URDF text ``urdf`` (written as
    ``NAME.urdf`` beside it), with ``robot.srdf`` if given, and the rest of the task
    ``body`` (YAML: arms, initial, mission)."""
    (folder / f"{name}.urdf").write_text(urdf)
    task = folder / f"{name}.yaml"
    srdf_line = f"  srdf: {srdf}\n" if srdf else ""
    task.write_text(f"name: {name}\nrobot:\n  urdf: {name}.urdf\n{srdf_line}{body}")
    return task


def copy_programs(source_cache: Path, target_cache: Path) -> list[Path]:
    """Copy the bridge programs built in the cache folder ``source_cache`` (those whose bytes
    match their records) into ``target_cache``'s bridge folder, where it has none; the source
    is only read (no lock taken, nothing written): a test session that keeps its own cache
    seeds it from the user's instead of building the bridge again for minutes.

    Returns:
        The programs copied.
    """
    source, target = Path(source_cache) / FOLDER, Path(target_cache) / FOLDER
    copied = []
    for record in sorted(source.glob("pinocchio_casadi_bridge_*.json")):
        program = record.with_suffix("")
        destination = target / program.name
        if destination.exists() or check_record(program)[0] is None:
            continue
        target.mkdir(parents=True, exist_ok=True)
        partial = target / f"{program.name}.copy.tmp"
        shutil.copy2(program, partial)
        os.replace(partial, destination)  # the program before its record: never a record alone
        shutil.copy2(record, target / record.name)
        copied.append(destination)
    return copied


os.environ.setdefault("MPLBACKEND", "Agg")

_KEPT_CACHE = os.environ.get("BALANCE_OPT_TEST_CACHE")
_SESSION_CACHE = _KEPT_CACHE or tempfile.mkdtemp(prefix="balance-opt-test-cache-")
_USER_CACHE = default_cache_dir()  # before the session's cache replaces it
_SEEDED = [] if _KEPT_CACHE else copy_programs(_USER_CACHE, Path(_SESSION_CACHE))
# Set before any balance_opt import reads it; worker processes of the sweep tests inherit it.
os.environ["BALANCE_OPT_CACHE"] = _SESSION_CACHE


def _cache_line() -> str:
    if _KEPT_CACHE:
        return f"balance-opt test cache: {_SESSION_CACHE} (BALANCE_OPT_TEST_CACHE, kept)"
    bridge = (
        f"Pinocchio-CasADi bridge copied from {_USER_CACHE}"
        if _SEEDED
        else f"no Pinocchio-CasADi bridge built in {_USER_CACHE}: the tests that need one "
        "build it in the session's cache (1-6 min)"
    )
    return f"balance-opt test cache: {_SESSION_CACHE} (temporary); {bridge}"


def curve_labels(fig) -> list[list[str]]:
    """The labels of the curves in each panel of a figure (to check what it shows)."""
    return [[line.get_label() for line in ax.get_lines()] for ax in fig.axes]


def pytest_report_header(config):
    return _cache_line()


def pytest_sessionstart(session):
    """Say so even under ``-q`` (which drops the header) when the session builds the bridge."""
    reporter = session.config.pluginmanager.get_plugin("terminalreporter")
    if reporter is not None and not _KEPT_CACHE and not _SEEDED and session.config.option.quiet:
        reporter.write_line(_cache_line())


def pytest_sessionfinish(session, exitstatus):
    if not _KEPT_CACHE:
        shutil.rmtree(_SESSION_CACHE, ignore_errors=True)


@pytest.fixture(scope="session")
def paper():
    from balance_opt.model.library import paper_robot

    return paper_robot()


@pytest.fixture(scope="session")
def baxter():
    from balance_opt.model.library import baxter_floating

    return baxter_floating()


@pytest.fixture(scope="module")
def capture():
    """The capture task's scenario (robot, mission, balance start)."""
    from balance_opt.app.scenarios import capture_task

    return capture_task()


@pytest.fixture(scope="module")
def model(capture):
    """The capture robot's planner model on CasADi's VM (no compiler wait); a test module that
    needs the compiled kernels defines its own ``model``."""
    from balance_opt.optimal.model import PlannerModel

    return PlannerModel(capture.robot, compile=False)


def _inside_hull(nlp, plan) -> None:
    """Every Bernstein coefficient of the plan's joint position, velocity and acceleration on
    every interval is inside the limits: the continuous motion is (convex hull)."""
    sol = plan.solver.solution
    levels = joint_chain_coefficients(
        nlp.transcription, [sol.X[3:6, :-1], sol.X[6:9, :-1]], sol.U, sol.Um, nlp.h
    )
    lim = nlp.limits
    bounds = [
        (lim.lower, lim.upper),
        (-lim.velocity, lim.velocity),
        (-lim.acceleration, lim.acceleration),
    ]
    for level, (low, high) in zip(levels, bounds):
        coefficients = np.stack(level)  # (degree + 1, n_B, N)
        assert np.all(coefficients >= low[None, :, None] - 1e-6)
        assert np.all(coefficients <= high[None, :, None] + 1e-6)


@pytest.fixture
def inside_hull():
    """Assert that a plan's joint motion is inside the limits on the whole continuous motion
    (``inside_hull(nlp, plan)``, see :func:`_inside_hull`)."""
    return _inside_hull
