"""Where a URDF's meshes are: ``package://NAME/REST`` and relative file names resolved to files
(``docs/collision.md``, "Meshes"). Everything that loads geometry (the collision geometry, the
3D scene) hands Pinocchio a URDF whose mesh file names this module made absolute, so one search
order holds everywhere and a mesh not found is one error that names the folders searched.

Search order of ``package://NAME/REST``: the folders the task's ``robot.packages`` lists, those of
``ROS_PACKAGE_PATH``, the URDF's folder and the three above it (never the filesystem's root,
which holds no package), and, for NAME
``example-robot-data``, the installed example-robot-data. In each folder ``F`` the mesh is
``F/NAME/REST``, or ``F/REST`` when ``F`` is itself named NAME.
"""

from __future__ import annotations

import importlib.metadata
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from pathlib import Path

from balance_opt.errors import InputError

PACKAGE = "package://"
FILE = "file://"
#: The URDF's folder and this many above it are searched for ``package://`` meshes.
FOLDERS_ABOVE = 3
#: example-robot-data's own package name (its URDFs' ``package://example-robot-data/...``).
EXAMPLE_PACKAGE = "example-robot-data"
#: The key that tells balance-opt where meshes are, as the error names it.
PACKAGES_KEY = "robot.packages"


class MeshNotFoundError(InputError):
    """A mesh file that none of the folders searched holds; with the URDF (its file, or
    ``<...>`` for text) and the link that names it when they are known."""

    def __init__(
        self,
        uri: str,
        searched: Sequence[tuple[Path, str]],
        hint: str,
        source: str | None = None,
        link: str | None = None,
    ):
        self.uri, self.searched, self.hint = uri, list(searched), hint
        self.source, self.link = source, link
        where = "; ".join(f"{folder} ({origin})" for folder, origin in searched) or "no folder"
        urdf = "" if source is None else "URDF text: " if source.startswith("<") else f"{source}: "
        owner = "" if link is None else f"link {link}: "
        super().__init__(f"{urdf}{owner}mesh {uri} not found; folders searched: {where}; {hint}")


def _example_share() -> Path | None:
    """The folder that holds the installed example-robot-data's ``example-robot-data/``."""
    try:
        dist = importlib.metadata.distribution(EXAMPLE_PACKAGE)
    except importlib.metadata.PackageNotFoundError:
        return None
    for f in dist.files or ():  # <share>/example-robot-data/robots/... (not include/)
        path = Path(str(dist.locate_file(f)))
        if EXAMPLE_PACKAGE in path.parts[:-2]:
            k = path.parts.index(EXAMPLE_PACKAGE)
            if path.parts[k + 1] == "robots":
                return Path(*path.parts[:k])
    return None


def package_folders(
    name: str, urdf_path: Path | None, packages: Sequence[str | Path] = ()
) -> list[tuple[Path, str]]:
    """The folders searched for the meshes of package ``name``, in order, each with where it
    comes from: ``packages`` (``robot.packages``), ``ROS_PACKAGE_PATH``, the URDF's folder and
    the :data:`FOLDERS_ABOVE` above it (not the root), and example-robot-data's share folder
    for its own name."""
    out = [(Path(p), PACKAGES_KEY) for p in packages]
    ros = os.environ.get("ROS_PACKAGE_PATH", "")
    out += [(Path(p), "ROS_PACKAGE_PATH") for p in ros.split(os.pathsep) if p]
    if urdf_path is not None:
        folder = urdf_path.resolve().parent
        above = [folder, *folder.parents][: FOLDERS_ABOVE + 1]
        out += [(p, "above the URDF") for p in above if p.parent != p]
    if name == EXAMPLE_PACKAGE:
        share = _example_share()
        if share is not None:
            out.append((share, EXAMPLE_PACKAGE))
    return out


def resolve_mesh(
    uri: str,
    urdf_path: Path | None,
    packages: Sequence[str | Path] = (),
    folders: dict[str, list[tuple[Path, str]]] | None = None,
) -> Path:
    """The file of mesh ``uri``: ``package://NAME/REST`` searched as the module says, ``file://``
    and absolute paths as they are, other paths relative to the URDF's folder (the working
    folder for a URDF given as text). ``folders``: the caller's record of each package's
    folders (:func:`package_folders`), filled on first use.

    Raises:
        MeshNotFoundError: no such file; it names ``uri``, every folder searched, and the key
            that fixes it.
    """
    if uri.startswith(PACKAGE):
        name, _, rest = uri[len(PACKAGE) :].partition("/")
        folders = {} if folders is None else folders
        if name not in folders:
            folders[name] = package_folders(name, urdf_path, packages)
        for folder, _ in folders[name]:
            for candidate in (folder / name / rest, folder / rest if folder.name == name else None):
                if candidate is not None and candidate.is_file():
                    return candidate.resolve()
        raise MeshNotFoundError(
            uri,
            folders[name],
            f"add the folder that holds {name}/ to {PACKAGES_KEY} in the task file "
            "(or to ROS_PACKAGE_PATH)",
        )
    path = Path(uri.removeprefix(FILE))
    folder = Path.cwd() if urdf_path is None else urdf_path.resolve().parent
    if path.is_absolute():
        if path.is_file():
            return path
        raise MeshNotFoundError(uri, [], "the URDF names an absolute path that does not exist")
    if (folder / path).is_file():
        return (folder / path).resolve()
    raise MeshNotFoundError(
        uri,
        [(folder, "the URDF's folder")],
        "a mesh path without package:// is relative to the URDF file",
    )


def geometry_kind(text: str) -> str:
    """The URDF elements the clearance check and the collision avoidance read: ``"collision"``
    when URDF ``text`` has any, else ``"visual"``."""
    return "collision" if ET.fromstring(text).find("link/collision") is not None else "visual"


def resolved_urdf(
    text: str,
    source: str,
    packages: Sequence[str | Path] = (),
    kind: str | None = None,
    strict: bool = True,
) -> str:
    """URDF ``text`` with the mesh file names of its ``<kind>`` elements (``"collision"``,
    ``"visual"``; None: both) made absolute (:func:`resolve_mesh`); ``source``: the URDF's file
    (a name starting with ``<``: text of no file). ``strict=False`` leaves a mesh not found as
    it is instead of raising :class:`MeshNotFoundError`."""
    root = ET.fromstring(text)
    urdf_path = None if source.startswith("<") else Path(source)
    kinds = ("collision", "visual") if kind is None else (kind,)
    found: dict[str, str] = {}
    folders: dict[str, list[tuple[Path, str]]] = {}  # searched once per package
    for k in kinds:
        for link in root.iterfind("link"):
            for mesh in link.iterfind(f"{k}/geometry/mesh"):
                uri = mesh.get("filename", "")
                if uri not in found:
                    try:
                        found[uri] = str(resolve_mesh(uri, urdf_path, packages, folders))
                    except MeshNotFoundError as exc:
                        if strict:  # the file and the link the user looks for
                            raise MeshNotFoundError(
                                uri, exc.searched, exc.hint, source, link.get("name")
                            ) from None
                        found[uri] = uri
                mesh.set("filename", found[uri])
    return ET.tostring(root, encoding="unicode") if found else text
