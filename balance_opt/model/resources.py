"""Where robot files live: the URDFs shipped in ``urdf/`` and those of ``example-robot-data``.

``example-robot-data`` 6 ships robot files only, with no Python loader; its files are found
through the installed distribution's metadata.
"""

from __future__ import annotations

import importlib.metadata
import importlib.resources
from pathlib import Path

from balance_opt.errors import InputError

PAPER_ROBOT = "paper_robot.urdf"

#: example-robot-data robots that balance-opt knows by name: (description folder, URDF file).
EXAMPLE_ROBOTS = {
    "baxter": ("baxter_description", "baxter.urdf"),
}


def shipped_urdf(name: str = PAPER_ROBOT) -> Path:
    """Path of a URDF shipped with balance-opt (``urdf/`` in the repository)."""
    path = Path(str(importlib.resources.files("balance_opt.urdf") / name))
    if not path.is_file():
        available = sorted(p.name for p in path.parent.glob("*.urdf"))
        raise InputError(f"no shipped URDF '{name}'; available: {', '.join(available)}")
    return path


def example_robot_urdf(name: str) -> Path:
    """Path of an ``example-robot-data`` URDF, found through the package's installed files."""
    if name not in EXAMPLE_ROBOTS:
        raise InputError(
            f"unknown example-robot-data robot '{name}'; known: {', '.join(sorted(EXAMPLE_ROBOTS))}"
        )
    folder, filename = EXAMPLE_ROBOTS[name]
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        raise InputError(
            "example-robot-data is not installed (pip install example-robot-data)"
        ) from None
    suffix = f"robots/{folder}/urdf/{filename}"
    for f in dist.files or ():
        if str(f).replace("\\", "/").endswith(suffix):
            return Path(str(dist.locate_file(f)))
    raise InputError(f"example-robot-data {dist.version} has no file ending in {suffix}")
