"""Shared fixtures: robots and their maps, built once per test session.

Compiled planner kernels go to a temporary folder of this test session (removed at its end), never
to the user's own cache; set ``BALANCE_OPT_TEST_CACHE`` to a folder to keep them across runs.
"""

import os
import shutil
import tempfile

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

_KEPT_CACHE = os.environ.get("BALANCE_OPT_TEST_CACHE")
_SESSION_CACHE = _KEPT_CACHE or tempfile.mkdtemp(prefix="balance-opt-test-cache-")
# Set before any balance_opt import reads it; worker processes of the sweep tests inherit it.
os.environ["BALANCE_OPT_CACHE"] = _SESSION_CACHE


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
