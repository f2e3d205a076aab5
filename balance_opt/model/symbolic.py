"""Symbolic momentum maps in CasADi, functions of the arm vector ``q`` alone (base at the
identity pose, base-frame axes: ``docs/physics.md``, "Momentum maps"): what the optimal planner
builds on, the centroidal momentum matrix, the base Jacobian drawn from it and every joint's
placement, from the backend ``"pinocchio"`` (``pinocchio.casadi``, else the compiled bridge of
:mod:`balance_opt.model.bridge`) or ``"adam"``; ``"auto"`` takes the first that works. Each map
is a cached ``casadi.Function``, ``name_fun()``; the maps evaluated on numbers are
:mod:`balance_opt.model.maps`' (the reference these are tested against).
"""

from __future__ import annotations

import functools
import importlib
import logging

import casadi as cs
import numpy as np

from balance_opt.errors import BalanceOptError, JointError
from balance_opt.model import coupling
from balance_opt.model.bridge import (
    BridgeUnavailable,
    bridge_centroidal_map,
    bridge_function,
    ensure_bridge,
    find_toolchain,
)
from balance_opt.model.robot import FloatingRobot

log = logging.getLogger(__name__)

BACKENDS = ("pinocchio", "adam")


def _imports(module: str) -> bool:
    try:
        importlib.import_module(module)
    except ImportError:
        return False
    return True


def available_backends() -> list[str]:
    """Backends usable here, in order of preference, found without building anything (the
    bridge's build may still fail)."""
    found = []
    try:
        if not _imports("pinocchio.casadi"):
            find_toolchain()
        found.append("pinocchio")
    except BridgeUnavailable:
        pass
    if _imports("adam.casadi"):
        found.append("adam")
    return found


def _adam_identity() -> str:
    """What adam's expressions depend on: its version."""
    from importlib import metadata

    return f"adam-robotics {metadata.version('adam-robotics')}"


def _fall_back_to_adam(reason: str) -> tuple[str, str, str]:
    """Choose adam for ``auto``: ``("adam", "adam (<why not the bridge>)", identity)``."""
    if not _imports("adam.casadi"):
        raise BalanceOptError(
            f"no symbolic backend: the Pinocchio-CasADi bridge is unavailable ({reason}) "
            "and adam-robotics[casadi] is not installed"
        )
    return "adam", f"adam ({reason})", _adam_identity()


def _resolve_backend(backend: str) -> tuple[str, str, str]:
    """``(backend, description, identity)`` for the backend asked for (see
    :func:`backend_identity`); builds the bridge if needed."""
    if backend not in ("auto", *BACKENDS):
        raise BalanceOptError(f"unknown backend '{backend}'; expected auto, {', '.join(BACKENDS)}")
    if backend == "adam":
        if not _imports("adam.casadi"):
            raise BalanceOptError("backend 'adam' cannot be imported here")
        return "adam", "adam", _adam_identity()
    if _imports("pinocchio.casadi"):
        import pinocchio

        return (
            "pinocchio",
            "pinocchio (pinocchio.casadi)",
            f"pinocchio.casadi {pinocchio.__version__}",
        )
    try:
        record = ensure_bridge()
    except BridgeUnavailable as exc:
        if backend == "auto":
            return _fall_back_to_adam(exc.reason)
        raise BalanceOptError(
            "backend 'pinocchio' cannot be used here: pinocchio.casadi does not import (PyPI's "
            f"pin wheels lack it) and the Pinocchio-CasADi bridge is unavailable: {exc.reason}"
        ) from None
    built = f"pinocchio (bridge, built once per machine: {record.wall_seconds:.0f} s)"
    return "pinocchio", built, f"bridge {record.path.name}"


def backend_description(backend: str = "auto") -> str:
    """What ``SymbolicMaps(robot, backend)`` uses here, for ``balance-opt inspect`` (e.g.
    ``"pinocchio (bridge, built once per machine: 95 s)"``); builds the bridge first if needed."""
    return _resolve_backend(backend)[1]


def backend_identity(backend: str = "auto") -> tuple[str, str]:
    """``(backend, identity)``: the backend ``SymbolicMaps(robot, backend)`` uses here and what
    its expressions depend on (the bridge's build key, or the library's version), for the keys
    of cached planner models. Builds the bridge first if needed."""
    name, _, identity = _resolve_backend(backend)
    return name, identity


def model_joint_positions(robot: FloatingRobot, q: cs.SX) -> cs.SX:
    """Positions of the model joints (arm joints, then followers) from the arm vector ``q``."""
    if not robot.followers:
        return q
    E, e = robot.mimic_matrix
    return cs.mtimes(cs.DM(E), q) + cs.DM(e)


def model_velocity_map(robot: FloatingRobot) -> np.ndarray:
    """(6 + model joints) x (6+n): velocities of [base; model joints] per [base; arm joints]."""
    return robot.velocity_map[np.r_[0:6, robot.model_v_indices]]


def _fold(robot: FloatingRobot, X: cs.SX) -> cs.SX:
    """A 6 x (6 + model joints) matrix as a 6 x (6+n) one over [base; arm joints]: each
    follower's column added, times its multiplier, into its driver's."""
    if not robot.followers:
        return X
    return cs.mtimes(X, cs.DM(model_velocity_map(robot)))


def check_adam_joints(robot: FloatingRobot, remedy: str = "lock it, or use backend='pinocchio'"):
    """Raise a ``JointError`` naming the first prismatic model joint (adam cannot take it),
    ending with ``remedy``."""
    # adam-robotics 0.5 stacks three 3-vectors of zeros into a prismatic joint's motion
    # subspace (12 x 1 instead of 6 x 1): fail here, by name, rather than deep inside adam.
    for j in robot.model_joint_names:
        if robot._urdf_joints[j].type == "prismatic":
            follows = f" (it follows '{robot.followers[j].driver}')" if j in robot.followers else ""
            raise JointError(
                j,
                robot.source,
                f"is prismatic{follows}, which the 'adam' backend cannot handle "
                f"(adam-robotics 0.5); {remedy}",
            )


def adam_kindyn(robot: FloatingRobot):
    """adam's ``KinDynComputations`` of the robot (locked joints baked in, the model joints:
    arm joints then mimic followers, no gravity)."""
    import adam.casadi
    import urdf_parser_py.xml_reflection.core as urdf_core

    # urdf_parser_py prints every tag it does not know (transmissions, ...) to stderr.
    quiet, urdf_core.on_error = urdf_core.on_error, lambda *args, **kwargs: None
    try:
        return adam.casadi.KinDynComputations(
            robot.locked_urdf, list(robot.model_joint_names), gravity=np.zeros(6)
        )
    finally:
        urdf_core.on_error = quiet


def _centroidal_adam(robot: FloatingRobot, q: cs.SX) -> cs.SX:
    """The centroidal momentum matrix from adam's algorithms (:func:`_centroidal_pinocchio`)."""
    check_adam_joints(robot)
    A = adam_kindyn(robot).centroidal_momentum_matrix(cs.SX.eye(4), model_joint_positions(robot, q))
    return _fold(robot, cs.SX(A.array if hasattr(A, "array") else A))


def _centroidal_pinocchio(robot: FloatingRobot, q: cs.SX) -> cs.SX:
    """The centroidal momentum matrix (6 x (6+n), columns [base; arm joints]) from Pinocchio's
    algorithms on ``casadi.SX``: through ``pinocchio.casadi`` where it imports, else through the
    bridge (:mod:`balance_opt.model.bridge`)."""
    try:
        import pinocchio.casadi as cpin
    except ImportError:
        return _fold(robot, bridge_centroidal_map(robot, model_joint_positions(robot, q)))
    cmodel = cpin.Model(robot.model)
    qp = _pin_configuration(robot, model_joint_positions(robot, q))
    A = cs.SX(cpin.computeCentroidalMap(cmodel, cmodel.createData(), qp))
    return cs.mtimes(A, cs.DM(robot.velocity_map))  # followers folded into their drivers


def _pin_configuration(robot: FloatingRobot, qm: cs.SX) -> cs.SX:
    """Pinocchio's configuration (base at the identity) at the model joints' positions ``qm``."""
    model, qp = robot.model, cs.SX(robot.pin_q(np.zeros(robot.n)))
    for i, name in enumerate(robot.model_joint_names):
        joint = model.joints[model.getJointId(name)]
        if joint.nq == 1:
            qp[joint.idx_q] = qm[i]
        else:  # continuous joint stored as (cos, sin)
            qp[joint.idx_q] = cs.cos(qm[i])
            qp[joint.idx_q + 1] = cs.sin(qm[i])
    return qp


def _placements(robot: FloatingRobot, backend: str, qm: cs.SX) -> cs.SX:
    """Every joint's placement ``oMi`` (12 x (njoints - 1): rotation by columns, then
    translation; base at the identity) at the model joints' positions ``qm``, by ``backend``."""
    if backend == "adam":  # a joint's frame is its child link's
        import pinocchio as pin

        kd, H, model = adam_kindyn(robot), cs.SX.eye(4), robot.model
        link = {}
        for frame in model.frames:
            if frame.type == pin.FrameType.BODY and frame.placement.isIdentity():
                link.setdefault(frame.parentJoint, frame.name)
        T = [kd.forward_kinematics(link[j], H, qm) for j in range(1, model.njoints)]
        T = [cs.SX(t.array if hasattr(t, "array") else t) for t in T]
        return cs.horzcat(*(cs.vertcat(cs.vec(t[:3, :3]), t[:3, 3]) for t in T))
    try:
        import pinocchio.casadi as cpin
    except ImportError:
        return cs.SX(bridge_function(robot)(qm)[-1])  # the bridge's last output
    cmodel = cpin.Model(robot.model)
    cdata = cmodel.createData()
    cpin.forwardKinematics(cmodel, cdata, _pin_configuration(robot, qm))
    M = [cdata.oMi[j] for j in range(1, cmodel.njoints)]
    return cs.horzcat(*(cs.vertcat(cs.vec(cs.SX(m.rotation)), cs.SX(m.translation)) for m in M))


def _built_once(method):
    """Cache a ``*_fun`` method's function per arguments."""

    @functools.wraps(method)
    def cached(self, *args):
        key = (method.__name__, *args)
        if key not in self._funs:
            self._funs[key] = method(self, *args)
        return self._funs[key]

    return cached


class SymbolicMaps:
    """CasADi momentum maps of a floating robot.

    Args:
        robot: the floating robot.
        backend: ``"auto"``, ``"adam"`` or ``"pinocchio"``; the one used and why are in
            ``backend`` and ``backend_description``.

    Raises:
        BalanceOptError: the backend asked for cannot be used here.
    """

    def __init__(self, robot: FloatingRobot, backend: str = "auto"):
        self.robot = robot
        self.backend, self.backend_description, _ = _resolve_backend(backend)
        self._funs: dict[tuple, cs.Function] = {}
        self._q = cs.SX.sym("q", robot.n)
        try:
            build = _centroidal_pinocchio if self.backend == "pinocchio" else _centroidal_adam
            self._A = build(robot, self._q)
        except BridgeUnavailable as exc:  # built, but failed on this robot
            if backend != "auto":
                raise
            self.backend, self.backend_description, _ = _fall_back_to_adam(exc.reason)
            self._A = _centroidal_adam(robot, self._q)
        if backend == "auto" and self.backend == "adam":  # why, each time maps are built
            log.info(
                "symbolic backend: %s, not the Pinocchio-CasADi bridge", self.backend_description
            )
        log.debug("symbolic maps of %s built with %s", robot.name, self.backend_description)

    def _fun(self, name: str, inputs: dict, outputs: dict) -> cs.Function:
        return cs.Function(
            name,
            list(inputs.values()),
            list(outputs.values()),
            list(inputs),
            list(outputs),
            {"cse": True},
        )

    @_built_once
    def centroidal_momentum_matrix_fun(self) -> cs.Function:
        """``centroidal_momentum_matrix(q) -> A_G``: 6 x (6+n), momentum [linear; angular] about the
        CoM in base-frame axes, for the base twist in the base frame and the arm joint rates.
        In world axes it is ``blkdiag(R, R) A_G``."""
        return self._fun("centroidal_momentum_matrix", {"q": self._q}, {"A_G": self._A})

    @_built_once
    def base_jacobian_fun(self) -> cs.Function:
        """``base_jacobian(q) -> J_base``: 6 x n, ``v_b = J_base q_dot`` with zero momentum
        (Eq. 19), the base twist [linear; angular] in the base frame."""
        J_base = coupling.base_jacobian(self._A, cs.solve)
        return self._fun("base_jacobian", {"q": self._q}, {"J_base": J_base})

    @_built_once
    def joint_placements_fun(self) -> cs.Function:
        """``joint_placements(q_model) -> oMi``: every joint frame of ``robot.model`` in the base
        frame (the base at the identity), 12 x (njoints - 1) (column ``j - 1``: joint ``j``'s
        rotation by columns, then its translation), at the model joints' positions
        (``robot.model_joint_names``: arm joints, then followers), by this backend."""
        qm = cs.SX.sym("q_model", len(self.robot.model_joint_names))
        oMi = _placements(self.robot, self.backend, qm)
        return self._fun("joint_placements", {"q_model": qm}, {"oMi": oMi})
