"""Shared fixtures: robots and their maps, built once per test session."""

import os

import pytest

os.environ.setdefault("MPLBACKEND", "Agg")


@pytest.fixture(scope="session")
def paper():
    from balance_opt.model.library import paper_robot

    return paper_robot()


@pytest.fixture(scope="session")
def baxter():
    from balance_opt.model.library import baxter_floating

    return baxter_floating()
