"""The robots of example-robot-data, by name, and their joints grouped by chain
(``balance-opt robots``).

A robot's name is its URDF's stem, or its description folder's when two files share a stem;
:data:`ALIASES` adds example-robot-data's short names. A chain is a sequence of movable joints,
each the only movable joint below the previous one.
"""

from __future__ import annotations

import difflib
import functools
import importlib.metadata
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from balance_opt.errors import InputError

DISTRIBUTION = "example-robot-data"
#: Short names: example-robot-data's loader names whose file stem differs.
ALIASES = {
    "talos": "talos_reduced",
    "talos_arm": "talos_left_arm",
    "talos_full": "talos_full_v2",
    "ur3": "ur3_robot",
    "ur5": "ur5_robot",
    "ur10": "ur10_robot",
    "hyq": "hyq_no_sensors",
    "anymal": "anymal_b_simple",
    "anymal_c": "anymal_c_simple",
}
#: Joint types that move (``fixed`` joints only carry a link along).
MOVABLE = ("revolute", "continuous", "prismatic", "floating", "planar")


@functools.lru_cache(maxsize=1)
def example_robots() -> dict[str, Path]:
    """Every URDF of the installed example-robot-data, by robot name."""
    try:
        dist = importlib.metadata.distribution(DISTRIBUTION)
    except importlib.metadata.PackageNotFoundError:
        raise InputError(f"{DISTRIBUTION} is not installed (pip install {DISTRIBUTION})") from None
    files = sorted(Path(str(dist.locate_file(f))) for f in dist.files or () if f.suffix == ".urdf")
    stems: dict[str, list[Path]] = {}
    for path in files:
        stems.setdefault(path.stem, []).append(path)
    robots: dict[str, Path] = {}
    for stem, paths in stems.items():
        if len(paths) == 1:
            robots[stem] = paths[0]
            continue
        for path in paths:  # .../robots/<folder>_description/<urdf|robots>/<stem>.urdf
            folder = path.parent.parent.name
            for suffix in ("_description", "_data"):
                folder = folder.removesuffix(suffix)
            robots[folder if folder not in stems else f"{folder}_{stem}"] = path
    return dict(sorted(robots.items()))


def resolve_name(name: str) -> str:
    """The catalog name of ``name`` (an alias resolved); InputError with close names."""
    robots = example_robots()
    name = ALIASES.get(name, name)
    if name in robots:
        return name
    known = sorted({*robots, *ALIASES})
    close = difflib.get_close_matches(name, known, n=3, cutoff=0.6)
    hint = f"did you mean {', '.join(close)}? " if close else ""
    raise InputError(
        f"unknown example-robot-data robot '{name}'; {hint}"
        f"list them with `balance-opt robots` ({len(robots)} robots)"
    )


def example_urdf(name: str) -> Path:
    """Path of the example-robot-data URDF of robot ``name`` (or an alias)."""
    return example_robots()[resolve_name(name)]


# ----------------------------------------------------------------------------- chains
@dataclass
class JointInfo:
    """A movable joint: name, URDF type, and the joint it mimics (if any)."""

    name: str
    type: str
    mimic: str | None = None

    def __str__(self) -> str:
        kind = self.type if self.mimic is None else f"{self.type}, mimics {self.mimic}"
        return f"{self.name} ({kind})"


@dataclass
class RobotInfo:
    """A robot of the catalog: its file, why it does not load ("" when it does), its movable
    joints by chain from the root down, its mass [kg] and the implausible values in its file."""

    name: str
    path: Path
    error: str = ""
    chains: list[list[JointInfo]] = field(default_factory=list)
    mass: float = 0.0
    warnings: list[str] = field(default_factory=list)

    @property
    def dof(self) -> int:
        return sum(len(c) for c in self.chains)


def _chains(root: ET.Element) -> list[list[JointInfo]]:
    """Movable joints grouped by chain (module docstring), depth first from the root link."""
    below: dict[str, list[ET.Element]] = {}  # link -> joints whose parent it is
    for joint in root.findall("joint"):
        below.setdefault(joint.find("parent").get("link"), []).append(joint)
    children = {j.find("child").get("link") for j in root.findall("joint")}
    roots = [link.get("name") for link in root.findall("link") if link.get("name") not in children]

    def movable_below(link: str) -> list[ET.Element]:
        """The first movable joints under ``link`` (through fixed joints)."""
        found = []
        for joint in below.get(link, []):
            if joint.get("type") in MOVABLE:
                found.append(joint)
            else:
                found.extend(movable_below(joint.find("child").get("link")))
        return found

    chains: list[list[JointInfo]] = []
    starts = [j for r in roots for j in movable_below(r)]
    while starts:
        joint, chain = starts.pop(0), []
        while True:
            mimic = joint.find("mimic")
            chain.append(
                JointInfo(
                    joint.get("name"),
                    joint.get("type"),
                    None if mimic is None else mimic.get("joint"),
                )
            )
            nxt = movable_below(joint.find("child").get("link"))
            if len(nxt) != 1:
                starts[:0] = nxt  # each branch is a chain of its own
                break
            joint = nxt[0]
        chains.append(chain)
    return chains


def robot_info(name: str) -> RobotInfo:
    """Load robot ``name`` as balance-opt would (XML, physical checks, Pinocchio on a free-flying
    base) and group its movable joints by chain; a failure is recorded, not raised."""
    import pinocchio as pin

    from balance_opt.model.urdf_checks import check_urdf_physics

    resolved = resolve_name(name)
    info = RobotInfo(resolved, example_robots()[resolved])
    try:
        text = info.path.read_text()
        root = ET.fromstring(text)
        info.warnings = check_urdf_physics(root, str(info.path))
        model = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
        info.mass = float(sum(inertia.mass for inertia in model.inertias))
        info.chains = _chains(root)
    except Exception as exc:  # noqa: BLE001 (any reason a file does not load is reported)
        message = " ".join(str(exc).replace(f"URDF {info.path}: ", "").split())
        info.error = f"{type(exc).__name__}: {message}"[:300]
    return info
