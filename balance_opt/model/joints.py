"""Joint handling of the URDF: mimic joints (``q = multiplier * q_driver + offset``, chains
resolved) and locked joints written into the URDF text as fixed joints."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from balance_opt.errors import URDFLoadError

MOVABLE_TYPES = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class Mimic:
    """How a mimic joint follows ``driver`` (the first of a chain of mimics):
    ``q = multiplier * q_driver + offset`` [rad or m]."""

    driver: str
    multiplier: float
    offset: float


def parse_mimic(el: ET.Element, source: str) -> tuple[str, float, float] | None:
    """``(driver, multiplier, offset)`` of a joint element's ``<mimic>``, or ``None``."""
    mimic = el.find("mimic")
    if mimic is None:
        return None
    try:
        k = float(mimic.get("multiplier", "1"))
        c = float(mimic.get("offset", "0"))
    except ValueError:
        raise URDFLoadError(
            source, f"joint '{el.get('name')}': <mimic> multiplier or offset is not a number"
        ) from None
    if mimic.get("joint") is None:
        raise URDFLoadError(source, f"joint '{el.get('name')}': <mimic> names no joint")
    return mimic.get("joint"), k, c


def resolve_mimics(joints: Mapping, source: str) -> dict[str, Mimic]:
    """Every mimic joint of ``joints`` (name -> parsed URDF joint, with ``type`` and
    ``mimic``) with its first driver, chains composed:
    ``k1 (k2 q + c2) + c1 = (k1 k2) q + (k1 c2 + c1)``."""
    out = {}
    for name, uj in joints.items():
        if uj.mimic is None:
            continue
        driver, k, c = uj.mimic
        seen = [name]
        while True:
            if driver not in joints or joints[driver].type not in MOVABLE_TYPES:
                raise URDFLoadError(
                    source, f"mimic joint '{name}' follows '{driver}', which is not a movable joint"
                )
            if driver in seen:
                raise URDFLoadError(source, f"mimic joints follow each other in a loop: {seen}")
            parent = joints[driver].mimic
            if parent is None:
                break
            seen.append(driver)
            driver, k, c = parent[0], k * parent[1], k * parent[2] + c
        out[name] = Mimic(driver, k, c)
    return out


def mimic_matrix(joint_names, followers: Mapping[str, Mimic]) -> tuple[np.ndarray, np.ndarray]:
    """``(E, e)``: the model joints (``joint_names``, then the ``followers``) are at ``E q + e``
    for the arm vector ``q`` (positions ``joint_names``)."""
    n = len(joint_names)
    E = np.zeros((n + len(followers), n))
    E[:n] = np.eye(n)
    e = np.zeros(n + len(followers))
    for r, m in enumerate(followers.values(), start=n):
        E[r, list(joint_names).index(m.driver)] = m.multiplier
        e[r] = m.offset
    return E, e


def narrow_driver_limits(
    values: dict[str, np.ndarray], model: pin.Model, joint_names, followers: Mapping[str, Mimic]
) -> None:
    """Narrow each driver's position and velocity limits in ``values`` (arrays in arm order)
    to those its followers (joints of the Pinocchio ``model``) allow."""
    for f, m in followers.items():
        i, k = list(joint_names).index(m.driver), m.multiplier
        jm = model.joints[model.getJointId(f)]
        if k == 0.0:
            continue
        if jm.nq == 1:
            bounds = [
                (model.lowerPositionLimit[jm.idx_q] - m.offset) / k,
                (model.upperPositionLimit[jm.idx_q] - m.offset) / k,
            ]
            values["lower"][i] = max(values["lower"][i], min(bounds))
            values["upper"][i] = min(values["upper"][i], max(bounds))
        values["velocity"][i] = min(values["velocity"][i], model.velocityLimit[jm.idx_v] / abs(k))


def _origin(el: ET.Element) -> pin.SE3:
    origin = el.find("origin")
    xyz = np.zeros(3)
    rpy = np.zeros(3)
    if origin is not None:
        xyz = np.array([float(v) for v in origin.get("xyz", "0 0 0").split()])
        rpy = np.array([float(v) for v in origin.get("rpy", "0 0 0").split()])
    return pin.SE3(pin.rpy.rpyToMatrix(*rpy), xyz)


def _axis(el: ET.Element) -> np.ndarray:
    axis = el.find("axis")
    vec = (
        np.array([1.0, 0.0, 0.0])
        if axis is None
        else np.array([float(v) for v in axis.get("xyz", "1 0 0").split()])
    )
    return vec / np.linalg.norm(vec)


def lock_joints(
    root: ET.Element,
    joints: Mapping,
    locked: Mapping[str, float],
    followers=(),
) -> str:
    """URDF text in which each locked joint is a fixed joint at its locked position, and the
    ``followers`` (mimic joints of arm joints) are plain joints: the caller drives them."""
    root = ET.fromstring(ET.tostring(root))  # work on a copy
    by_name = {el.get("name"): el for el in root.findall("joint")}
    for name in followers:
        for child in by_name[name].findall("mimic"):
            by_name[name].remove(child)
    for name, value in locked.items():
        el = by_name[name]
        motion = (
            pin.SE3(np.eye(3), _axis(el) * value)
            if joints[name].type == "prismatic"
            else pin.SE3(pin.exp3(_axis(el) * value), np.zeros(3))
        )
        placement = _origin(el) * motion
        rpy = pin.rpy.matrixToRpy(placement.rotation)
        for tag in ("origin", "axis", "limit", "mimic", "dynamics", "safety_controller"):
            for child in el.findall(tag):
                el.remove(child)
        el.set("type", "fixed")
        ET.SubElement(
            el,
            "origin",
            xyz=" ".join(repr(float(v)) for v in placement.translation),
            rpy=" ".join(repr(float(v)) for v in rpy),
        )
    # An inertial without an origin sits at the link frame (the URDF default); adam's parser
    # needs it spelled out (Talos has such links).
    for inertial in root.iter("inertial"):
        if inertial.find("origin") is None:
            ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    return ET.tostring(root, encoding="unicode")
