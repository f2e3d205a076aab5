"""Keep-out zones: volumes fixed on a frame of the robot (a star tracker's field of view, an
antenna's beam) that the named arms must never enter. A zone is a body of the robot's geometry
(:class:`~balance_opt.geometry.robot_geometry.RobotGeometry` adds it as a coal shape on the
frame's joint, paired only with the links of the arms it binds), so the clearance check, the
planner's collision rows and every report hold it as they hold a link (``docs/collision.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from balance_opt.config.typed_config import setting
from balance_opt.errors import InputError

#: The geometry objects of a zone are named so (their pairs read ``keep_out:NAME / LINK``).
PREFIX = "keep_out:"
#: What a zone's name may be: it names the zone's pairs and the scene's key.
NAME_PATTERN = (r"[A-Za-z0-9][A-Za-z0-9._-]{0,99}", "letters, digits, '.', '_' and '-'")


def _vector(doc: str, unit: str | None = "m", **limits):
    """Three numbers: a point or the sides [m], or a direction (``unit`` None)."""
    return setting(unit=unit, min_items=3, max_items=3, doc=doc, **limits)


_AXIS = "direction of the axis in the zone's frame (any length but zero)"


@dataclass(frozen=True, kw_only=True)
class ZoneBox:
    """A box along the axes of the zone's frame."""

    center: tuple[float, ...] = _vector("centre of the box in the zone's frame")
    size: tuple[float, ...] = _vector(
        "side lengths along the frame's x, y, z", exclusive_minimum=0.0
    )


@dataclass(frozen=True, kw_only=True)
class ZoneCylinder:
    """A solid cylinder."""

    center: tuple[float, ...] = _vector("centre of the cylinder in the zone's frame")
    axis: tuple[float, ...] = _vector(_AXIS, unit=None)
    radius: float = setting(unit="m", exclusive_minimum=0.0, doc="radius")
    length: float = setting(unit="m", exclusive_minimum=0.0, doc="length along the axis")


@dataclass(frozen=True, kw_only=True)
class ZoneCone:
    """A solid cone (a field of view, a beam): from its apex along its axis."""

    apex: tuple[float, ...] = _vector("apex in the zone's frame")
    axis: tuple[float, ...] = _vector(_AXIS, unit=None)
    half_angle: float = setting(
        unit="rad", exclusive_minimum=0.0, doc="angle between the axis and the side, below pi/2"
    )
    length: float = setting(unit="m", exclusive_minimum=0.0, doc="height from the apex")


@dataclass(frozen=True, kw_only=True)
class KeepOutZone:
    """A volume fixed on a frame of the robot that the named arms' links must stay out of."""

    __exactly_one__ = ("box", "cylinder", "cone")

    name: str = setting(pattern=NAME_PATTERN, doc="name of the zone (unique)")
    frame: str = setting(doc="the robot frame (link) the zone is fixed on; it moves with it")
    box: ZoneBox | None = setting(None, doc="the zone as a box")
    cylinder: ZoneCylinder | None = setting(None, doc="the zone as a cylinder")
    cone: ZoneCone | None = setting(None, doc="the zone as a cone")
    arms: tuple[str, ...] | None = setting(
        None,
        min_items=1,
        item="arm",
        doc="the arms it binds: mission, balance, balance2, ... (default: every arm)",
    )

    @property
    def label(self) -> str:
        """Its geometry object's name, which names its pairs."""
        return PREFIX + self.name


def _turning_z_to(axis) -> np.ndarray:
    """A rotation whose z axis is ``axis`` (normalised)."""
    z = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def zone_shape(zone: KeepOutZone):
    """The zone's coal shape and its placement in the zone's frame, ``(shape, R, p)``: a box,
    a cylinder along its z axis, or a cone (coal's: base at ``-length / 2``, apex at
    ``+length / 2`` on its z axis)."""
    import coal

    if zone.box is not None:
        return coal.Box(*zone.box.size), np.eye(3), np.asarray(zone.box.center, float)
    if zone.cylinder is not None:
        c = zone.cylinder
        return coal.Cylinder(c.radius, c.length), _turning_z_to(c.axis), np.asarray(c.center, float)
    c = zone.cone
    axis = np.asarray(c.axis, float) / np.linalg.norm(c.axis)
    centre = np.asarray(c.apex, float) + 0.5 * c.length * axis
    return coal.Cone(c.length * np.tan(c.half_angle), c.length), _turning_z_to(-axis), centre


def zone_object(zone: KeepOutZone, model):
    """The zone as a Pinocchio geometry object on its frame's joint of ``model``, named
    :attr:`KeepOutZone.label`.

    Raises:
        InputError: ``model`` has no frame ``zone.frame``.
    """
    import pinocchio as pin

    if not model.existFrame(zone.frame):
        raise InputError(f"keep-out zone {zone.name}: no frame {zone.frame}")
    index = model.getFrameId(zone.frame)
    frame = model.frames[index]
    shape, R, p = zone_shape(zone)
    shape.computeLocalAABB()
    placement = frame.placement * pin.SE3(R, p)
    return pin.GeometryObject(zone.label, frame.parentJoint, index, placement, shape)


def zone_problems(zone: KeepOutZone) -> list[tuple[tuple, str]]:
    """What is wrong with a zone's sizes that the format cannot say, as ``(key path below the
    zone, problem)``: a zero axis, a cone's half angle not below pi/2."""
    out = []
    for kind in ("cylinder", "cone"):
        shape = getattr(zone, kind)
        if shape is not None and np.linalg.norm(shape.axis) < 1e-9:
            out.append(((kind, "axis"), "the axis must not be zero"))
    if zone.cone is not None and not zone.cone.half_angle < 0.5 * np.pi - 1e-6:
        out.append(
            (("cone", "half_angle"), f"must be below pi/2 rad, got {zone.cone.half_angle:g}")
        )
    return out
