"""The package list, which pyproject.toml cannot state alone: every ``balance_opt.*`` folder,
found (so that a new subpackage cannot be left out of the wheel), and ``balance_opt.urdf``, the
shipped URDFs, which pyproject.toml maps to ``urdf/``: a ``[tool.setuptools.packages.find]``
table finds folders only, never a mapped package, and excludes a ``packages`` list."""

from setuptools import find_packages, setup

setup(packages=[*find_packages(include=["balance_opt", "balance_opt.*"]), "balance_opt.urdf"])
