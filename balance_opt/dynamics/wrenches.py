"""The wrench each arm exerts on the base (paper Fig. 4): minus RNEA's ``data.f`` at the arm's
root joint, run with the simulation's accelerations; summed over the arms, the base's
Newton-Euler wrench (``docs/physics.md``, "Forces on the base")."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from balance_opt.errors import ArmError
from balance_opt.model.robot import FloatingRobot

#: Pinocchio joint id of the free-flyer (the base body).
BASE_JOINT_ID = 1


def arm_root_joints(robot: FloatingRobot) -> dict[str, int]:
    """Pinocchio joint id of each arm's root joint (whose parent is the base), in arm order;
    ArmError when an arm hangs from several or two arms share one."""
    model = robot.model
    roots: dict[str, int] = {}
    owner: dict[int, str] = {}
    for arm in robot.arms:
        # the joint below the base on the way to each of the arm's joints
        found = {model.supports[model.getJointId(name)][BASE_JOINT_ID + 1] for name in arm.joints}
        if len(found) != 1:
            names = ", ".join(sorted(model.names[j] for j in found))
            raise ArmError(
                arm.name,
                robot.source,
                f"joints hang from several joints on the base ({names}); "
                "the wrench it exerts on the base is not defined per arm",
            )
        (root,) = found
        if root in owner:
            raise ArmError(
                arm.name,
                robot.source,
                f"shares its root joint '{model.names[root]}' with arm "
                f"'{owner[root]}'; their wrenches on the base cannot be told apart",
            )
        owner[root] = arm.name
        roots[arm.name] = root
    return roots


def arm_wrenches_on_base(
    robot: FloatingRobot, q_pin, v, a, data: pin.Data | None = None
) -> dict[str, np.ndarray]:
    """The wrench each arm exerts on the base along a motion that obeys the free-floating
    dynamics (``q_pin``, ``v``, ``a``: Pinocchio state and accelerations, T rows):
    ``{arm: (T, 6)}``, ``[force; torque]`` in base axes, torque about the base origin [N, N m]."""
    model = robot.model
    data = data or model.createData()
    q_pin, v, a = (np.atleast_2d(np.asarray(x, dtype=float)) for x in (q_pin, v, a))
    roots = arm_root_joints(robot)
    out = {name: np.empty((q_pin.shape[0], 6)) for name in roots}
    for k in range(q_pin.shape[0]):
        pin.rnea(model, data, q_pin[k], v[k], a[k])
        for name, j in roots.items():
            out[name][k] = -data.liMi[j].act(data.f[j]).vector
    return out
