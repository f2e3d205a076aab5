"""Why a URDF is refused: its physical sanity (negative mass, inertia not positive
semi-definite, zero axis, two parents, loops), checked before Pinocchio loads it so the error
names the link or joint rather than failing deep in a solver; and urdfdom's own reasons, captured
from standard error, when Pinocchio refuses it."""

from __future__ import annotations

import contextlib
import ctypes
import logging
import math
import os
import sys
import tempfile
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin

from balance_opt.errors import URDFLoadError

log = logging.getLogger(__name__)

#: Relative tolerance of the positive semi-definiteness and triangle-inequality checks (printed
#: URDF inertias are rounded to a few digits).
INERTIA_RTOL = 1e-6
#: A negative principal moment smaller than this is a rounding slip of the file, warned about
#: rather than refused (tiago's antenna: -3.5e-8) [kg m^2].
INERTIA_ROUNDING = 1e-6
#: An inertia whose principal moments are all below this is nil (a bead of 1 g and 1 mm has
#: 4e-10): not checked for shape (icub's head: -2.4e-35) [kg m^2].
INERTIA_NIL = 1e-12
_INERTIA_KEYS = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")


def _number(source: str, where: str, text: str | None) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise URDFLoadError(source, f"{where} is {text!r}, not a number") from None
    if not math.isfinite(value):
        raise URDFLoadError(source, f"{where} is {text!r}, not a finite number")
    return value


def _vector(source: str, where: str, text: str) -> np.ndarray:
    parts = text.split()
    if len(parts) != 3:
        raise URDFLoadError(source, f"{where} is {text!r}, not three numbers")
    return np.array([_number(source, where, p) for p in parts])


def _check_inertial(link: ET.Element, source: str) -> list[str]:
    """Errors raised, warnings returned, for one link's ``<inertial>``."""
    inertial = link.find("inertial")
    if inertial is None:
        return []
    name = link.get("name")
    mass_el = inertial.find("mass")
    mass = _number(
        source,
        f"link '{name}': <inertial> <mass value=...>",
        None if mass_el is None else mass_el.get("value"),
    )
    if mass < 0:
        raise URDFLoadError(source, f"link '{name}': mass {mass:g} kg is negative")
    inertia_el = inertial.find("inertia")
    values = {
        k: _number(
            source,
            f"link '{name}': <inertial> <inertia {k}=...>",
            None if inertia_el is None else inertia_el.get(k),
        )
        for k in _INERTIA_KEYS
    }
    origin = inertial.find("origin")
    for attr in ("xyz", "rpy"):
        text = "0 0 0" if origin is None else origin.get(attr, "0 0 0")
        _vector(source, f"link '{name}': <inertial> <origin {attr}=...>", text)
    inertia = np.array(
        [
            [values["ixx"], values["ixy"], values["ixz"]],
            [values["ixy"], values["iyy"], values["iyz"]],
            [values["ixz"], values["iyz"], values["izz"]],
        ]
    )
    moments = np.linalg.eigvalsh(inertia)
    scale = float(np.max(np.abs(moments)))
    if scale < INERTIA_NIL:
        return []
    warnings = []
    if -INERTIA_ROUNDING <= moments[0] < -INERTIA_RTOL * scale:
        warnings.append(
            f"link '{name}': inertia has a negative principal moment {moments[0]:.3g} kg m^2, "
            "taken as a rounding error"
        )
    elif moments[0] < -INERTIA_RTOL * scale:
        raise URDFLoadError(
            source,
            f"link '{name}': inertia is not positive semi-definite (principal moments "
            f"{', '.join(f'{m:.4g}' for m in moments)} kg m^2)",
        )
    if mass == 0:
        warnings.append(f"link '{name}' has zero mass but a non-zero inertia")
    a, b, c = moments
    if a + b < c * (1 - INERTIA_RTOL):
        warnings.append(
            f"link '{name}': principal moments {a:.4g}, {b:.4g}, {c:.4g} kg m^2 break the "
            "triangle inequality (no rigid body has them; are some given about a joint instead "
            "of the centre of mass?)"
        )
    return warnings


def _check_tree(root: ET.Element, source: str) -> None:
    links = [el.get("name") for el in root.findall("link")]
    if not links:
        raise URDFLoadError(source, "the file has no <link> element")
    known = set(links)
    parent_of: dict[str, str] = {}  # child link -> its joint
    parent_link: dict[str, str] = {}  # child link -> parent link
    for joint in root.findall("joint"):
        name = joint.get("name")
        for tag in ("parent", "child"):
            el = joint.find(tag)
            link = None if el is None else el.get("link")
            if link not in known:
                raise URDFLoadError(
                    source, f"joint '{name}': its {tag} link {link!r} is not a <link> of the file"
                )
        child = joint.find("child").get("link")
        if child in parent_of:
            raise URDFLoadError(
                source,
                f"link '{child}' is the child of two joints ('{parent_of[child]}' and '{name}'); "
                "a URDF is a tree",
            )
        parent_of[child], parent_link[child] = name, joint.find("parent").get("link")
        if joint.get("type") in ("revolute", "continuous", "prismatic"):
            axis = joint.find("axis")
            if axis is not None:
                xyz = _vector(source, f"joint '{name}': <axis xyz=...>", axis.get("xyz", "1 0 0"))
                if np.linalg.norm(xyz) < 1e-12:
                    raise URDFLoadError(source, f"joint '{name}': axis is of zero length")
    roots = [link for link in links if link not in parent_of]
    if len(roots) != 1:
        raise URDFLoadError(
            source,
            f"a URDF has one root link, this one has {len(roots)}"
            + (
                f": {', '.join(repr(r) for r in roots)}"
                if roots
                else " (every link has a parent: a loop)"
            ),
        )
    for link in links:  # every link must reach the root: no loops
        seen, at = set(), link
        while at in parent_link:
            if at in seen:
                raise URDFLoadError(source, f"link '{link}' is in a kinematic loop")
            seen.add(at)
            at = parent_link[at]


def check_urdf_physics(root: ET.Element, source: str) -> list[str]:
    """Raise :class:`URDFLoadError` naming the link or joint of a non-physical URDF; return the
    warnings (implausible but possible values), each naming its link."""
    _check_tree(root, source)
    warnings: list[str] = []
    for link in root.findall("link"):
        warnings.extend(_check_inertial(link, source))
    return warnings


def check_base_mass(model: pin.Model, source: str) -> str | None:
    """A file that forgot its spacecraft's mass: refused when the floating base of ``model``
    weighs nothing (the arms would balance against each other alone); the warning returned when
    it weighs less than a link it carries (a bare root link whose mass is only that of the parts
    bolted to it)."""
    base_mass = model.inertias[1].mass
    root = next(f.name for f in model.frames if f.parentJoint == 1 and f.type == pin.FrameType.BODY)
    if base_mass <= 0:
        raise URDFLoadError(
            source,
            f"the base (link {root}, with the links fixed to it and the locked joints' links) "
            f"has no mass: a free-floating spacecraft needs its own; give link {root} an "
            "<inertial> with its mass and inertia",
        )
    heaviest = max(range(2, model.njoints), key=lambda j: model.inertias[j].mass, default=None)
    if heaviest is None or model.inertias[heaviest].mass <= base_mass:
        return None
    return (
        f"the base (link {root} and the links fixed to it) weighs {base_mass:.3g} kg, less than "
        f"the link of joint {model.names[heaviest]} it carries "
        f"({model.inertias[heaviest].mass:.3g} kg): is the spacecraft's <inertial> missing?"
    )


@contextlib.contextmanager
def _stderr_captured(lines: list[str]):
    """Collect what C++ code (urdfdom) prints on file descriptor 2 into ``lines``; other
    threads' output in the meantime is collected too."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        try:
            os.dup2(tmp.fileno(), 2)
            yield
        finally:
            with contextlib.suppress(OSError, AttributeError):
                ctypes.CDLL(None).fflush(None)
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            lines.extend(tmp.read().decode(errors="replace").splitlines())


def _urdfdom_reasons(lines: list[str]) -> str:
    """urdfdom's messages without their source locations: ``"Error: X\n at line ..."`` -> X."""
    reasons = []
    for line in lines:
        line = line.strip()
        if not line or line.startswith("at line "):
            continue
        text = line.removeprefix("Error:").strip()
        if text not in reasons:
            reasons.append(text)
    return "; ".join(reasons)


def pinocchio_model(text: str, source: str) -> pin.Model:
    """Pinocchio's model of the URDF ``text`` on a free-flyer root joint (URDFLoadError with
    urdfdom's reasons)."""
    printed: list[str] = []
    try:
        with _stderr_captured(printed):
            return pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    except Exception as exc:  # Pinocchio raises ValueError or RuntimeError, with C++ text
        why = _urdfdom_reasons(printed)
        raise URDFLoadError(
            source,
            f"Pinocchio could not build a model: {exc}" + (f" (urdfdom: {why})" if why else ""),
        ) from exc
    finally:
        if printed:
            log.debug("urdfdom on %s: %s", source, _urdfdom_reasons(printed))
