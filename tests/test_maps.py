"""Momentum maps: the symbolic CasADi functions the planner uses (every available backend)
against numeric Pinocchio, and the numeric maps against independent computations (Pinocchio called directly,
SVD, finite differences on the manifold, momentum conservation), on the paper's robot and on
Baxter (floating, left arm mission, right arm balance, head and grippers locked).

References are computed once per robot in module-scoped fixtures, at ``N_CONFIGS`` seeded
random configurations within the joint limits.
"""

from collections import defaultdict
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
from scipy.linalg import block_diag

from balance_opt.errors import BalanceOptError, JointError
from balance_opt.model.maps import NumericMaps, angular_jacobian_rate, base_angular_velocity
from balance_opt.model.robot import FloatingRobot
from balance_opt.model.symbolic import BACKENDS, SymbolicMaps, available_backends
from balance_opt.motion.so3 import matrix_from_quaternion, quaternion_from_rotvec

#: Largest absolute error allowed between two exact computations of the same quantity.
ATOL = 1e-9
N_CONFIGS = 50
#: Step of the central differences [s]; with one Richardson extrapolation the truncation error
#: is O(h^4) ~ 1e-12 and the rounding error ~ 1e-16 |J| / h ~ 1e-13, well below ATOL.
FD_STEP = 1e-3
#: The force map inverts N^T, whose condition number reaches ~1e5 on Baxter: a backward-stable
#: evaluation errs by ~ eps * cond(N) * |F_B| (~1e-11 |F_B|; measured <= 1e-12 |F_B|), so F_B is
#: compared relative to its size (|F_B| reaches 3e4 N for a unit wrench F_e).
FORCE_RTOL = 1e-9
#: Condition numbers are ratios of singular values (dimensionless, unbounded): compared relatively.
CONDITION_RTOL = 1e-9

ROBOTS = ("paper", "baxter")
CASES = [(r, b) for r in ROBOTS for b in available_backends()]


def _pin_configuration(model, names, q, base=None):
    """Pinocchio configuration with the named revolute joints at ``q``, written by joint name
    (independent of FloatingRobot's index maps)."""
    qp = pin.neutral(model)
    if base is not None:
        qp[:7] = pin.SE3ToXYZQUAT(base)
    for name, value in zip(names, q):
        joint = model.joints[model.getJointId(name)]
        assert joint.nq == 1, name
        qp[joint.idx_q] = value
    return qp


def _columns(model, names):
    return np.r_[0:6, [model.joints[model.getJointId(n)].idx_v for n in names]]


def _direct_A(robot, q, base=None):
    """A_G straight from ``pin.computeCentroidalMap`` (world-aligned axes, base twist local),
    columns [base; arm joints in arm order]."""
    model = robot.model
    qp = _pin_configuration(model, robot.joint_names, q, base)
    return pin.computeCentroidalMap(model, model.createData(), qp)[
        :, _columns(model, robot.joint_names)
    ]


def _base_jacobian_from(A):
    return -np.linalg.solve(A[:, :6], A[:, 6:])


def _richardson(f, q, q_dot, h=FD_STEP):
    """d/dt f(q + t q_dot) at t = 0: central differences with one Richardson extrapolation."""

    def central(step):
        return (f(q + step * q_dot) - f(q - step * q_dot)) / (2 * step)

    return (4 * central(h / 2) - central(h)) / 3


def _pinv_transpose_svd(N, rank):
    """pinv(N^T) from the SVD of N, keeping the ``rank`` largest singular values:
    N = U S V^T, so N^T = V S U^T and pinv(N^T) = U S^+ V^T."""
    U, s, Vt = np.linalg.svd(N)
    return U[:, :rank] @ np.diag(1 / s[:rank]) @ Vt[:rank]


def _evaluate(maps, robot, Q, F_E) -> dict:
    """The numeric maps at every configuration, stacked."""
    out = defaultdict(list)
    for q, F_e in zip(Q, F_E):
        out["A"].append(maps.centroidal_momentum_matrix(q))
        out["J_base"].append(maps.base_jacobian(q))
        J_wM, J_wB = maps.angular_jacobians(q)
        out["J_wM"].append(J_wM)
        out["J_wB"].append(J_wB)
        out["measures"].append(maps.coupling_measures(q))
        for arm in robot.arms:
            J_star, M = maps.ee_generalized_jacobian(q, arm.name)
            M_cf, N = maps.coupling_factors(q, arm.name)
            assert np.array_equal(M_cf, M)
            out[f"J_star_{arm.name}"].append(J_star)
            out[f"M_{arm.name}"].append(M)
            out[f"N_{arm.name}"].append(N)
            out[f"F_B_{arm.name}"].append(maps.force_map(q, F_e, arm.name))
    return {k: (v if k == "measures" else np.array(v)) for k, v in out.items()}


def _numeric_reference(robot):
    rng = np.random.default_rng(20240611)
    numeric = NumericMaps(robot)
    Q = rng.uniform(robot.limits.lower, robot.limits.upper, size=(N_CONFIGS, robot.n))
    QD = rng.uniform(-robot.limits.velocity, robot.limits.velocity, size=(N_CONFIGS, robot.n))
    F_E = rng.normal(size=(N_CONFIGS, 6))
    ref = _evaluate(numeric, robot, Q, F_E)

    def J_w(q):
        return numeric.base_jacobian(q)[3:]

    extra = defaultdict(list)
    for k, (q, q_dot, F_e) in enumerate(zip(Q, QD, F_E)):
        A, J_base = ref["A"][k], ref["J_base"][k]
        extra["A_direct"].append(_direct_A(robot, q))
        extra["dJ_w_fd"].append(_richardson(J_w, q, q_dot))
        # Zero momentum along the motion: 0 = d/dt (A_G v) = A_G v_dot + dA_G v (Pinocchio's dAg);
        # with q_ddot = 0, v_dot = [dJ_base q_dot; 0], so dJ_base q_dot = -A_b^{-1} dAg v.
        v = robot.pin_v(q_dot, J_base @ q_dot)
        data = robot.model.createData()
        pin.computeCentroidalMapTimeVariation(robot.model, data, robot.pin_q(q), v)
        extra["dJ_w_q_dot"].append(-np.linalg.solve(A[:, :6], data.dAg @ v)[3:])
        for arm in robot.arms:
            U, s, Vt = np.linalg.svd(ref[f"M_{arm.name}"][k], full_matrices=False)
            extra[f"N_svd_{arm.name}"].append(J_base[:, arm.indices] @ (Vt.T / s) @ U.T)
            N = ref[f"N_{arm.name}"][k]
            extra[f"F_B_svd_{arm.name}"].append(_pinv_transpose_svd(N, min(arm.dof, 6)) @ F_e)
    ref.update({key: np.array(value) for key, value in extra.items()})
    return SimpleNamespace(
        robot=robot,
        numeric=numeric,
        Q=Q,
        QD=QD,
        F_E=F_E,
        mission=robot.mission_indices,
        balance=robot.balance_indices,
        **ref,
    )


@pytest.fixture(scope="module")
def reference_of(paper, baxter):
    """Numeric references per robot name, computed on first use and kept for the module."""
    robots, cache = {"paper": paper, "baxter": baxter}, {}

    def get(name):
        if name not in cache:
            cache[name] = _numeric_reference(robots[name])
        return cache[name]

    return get


@pytest.fixture(scope="module", params=CASES, ids=[f"{r}-{b}" for r, b in CASES])
def case(request, reference_of):
    """Symbolic maps of one robot with one backend, evaluated at the reference configurations."""
    name, backend = request.param
    ref = reference_of(name)
    robot = ref.robot
    maps = SymbolicMaps(robot, backend=backend)
    A, J_base = maps.centroidal_momentum_matrix_fun(), maps.base_jacobian_fun()
    out = {"A": [A(q) for q in ref.Q], "J_base": [J_base(q) for q in ref.Q]}
    out = {k: np.array([np.array(x) for x in v]) for k, v in out.items()}
    return SimpleNamespace(ref=ref, maps=maps, backend=backend, **out)


def _close(actual, desired, atol=ATOL, **kwargs):
    np.testing.assert_allclose(actual, desired, rtol=0, atol=atol, **kwargs)


# ------------------------------------------------------------------ numeric vs independent
@pytest.mark.parametrize("name", ROBOTS)
def test_numeric_centroidal_map_is_pinocchio_direct(reference_of, name):
    ref = reference_of(name)
    assert ref.A.shape == (N_CONFIGS, 6, 6 + ref.robot.n)
    _close(ref.A, ref.A_direct)
    _close(ref.J_base, [_base_jacobian_from(A) for A in ref.A_direct])
    _close(ref.J_wM, ref.J_base[:, 3:][:, :, ref.mission])
    _close(ref.J_wB, ref.J_base[:, 3:][:, :, ref.balance])


@pytest.mark.parametrize("name", ROBOTS)
def test_base_jacobian_conserves_momentum(reference_of, name):
    """A_G [J_base q_dot; q_dot] = 0, at the identity and at random base poses (world axes)."""
    ref = reference_of(name)
    rng = np.random.default_rng(11)
    for q, q_dot, J_base in zip(ref.Q, ref.QD, ref.J_base):
        v = np.r_[J_base @ q_dot, q_dot]
        base = pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(scale=10, size=3))
        _close(_direct_A(ref.robot, q) @ v, np.zeros(6))
        _close(_direct_A(ref.robot, q, base) @ v, np.zeros(6))
        # and the base twist for a non-zero momentum h0 (base axes)
        h0 = rng.normal(size=6)
        v_b = ref.numeric.base_twist(q, q_dot, h0)
        _close(_direct_A(ref.robot, q) @ np.r_[v_b, q_dot], h0)


@pytest.mark.parametrize("name", ROBOTS)
def test_one_configuration_builder_for_single_configurations_and_batches(reference_of, name):
    """A batch of configurations gives, row by row, the single-configuration maps; a base
    attitude goes where Pinocchio expects it (against ``pin_q`` of an SE(3) base pose)."""
    ref = reference_of(name)
    maps = ref.numeric
    Q = ref.Q[:10]
    quaternion = quaternion_from_rotvec(np.random.default_rng(13).normal(size=(10, 3)))
    batch = maps.centroidal(Q, quaternion)
    I_G, A = maps.angular_maps(Q)
    J_wM, J_wB = maps.angular_jacobians(Q)
    for k, q in enumerate(Q):
        base = pin.SE3(matrix_from_quaternion(quaternion[k]), np.zeros(3))
        single = pin.computeCentroidalMap(ref.robot.model, maps.data, ref.robot.pin_q(q, base))
        _close(batch[k], single)
        _close(I_G[k], ref.A[k][3:, 3:6])
        _close(A[k], ref.A[k][3:, 6:])
        _close(J_wM[k], ref.J_wM[k])
        _close(J_wB[k], ref.J_wB[k])
    np.testing.assert_allclose(
        maps.balance_sigma_min(I_G, A),
        [m.sigma_min for m in ref.measures[:10]],
        rtol=0,
        atol=ATOL,
    )


@pytest.mark.parametrize("name", ROBOTS)
def test_base_angular_velocity_keeps_the_momentum(reference_of, name):
    """The one base-rate function: with the angular momentum ``L`` (world axes) and the base at
    attitude ``R``, ``omega = I_G^{-1} (R^T L - A q_dot)`` gives back ``L`` through Pinocchio's
    world-frame map at ``R``; for ``L = 0`` it is ``J_wM q_dot_M + J_wB q_dot_B``. Batched and
    one at a time alike."""
    ref = reference_of(name)
    maps, robot = ref.numeric, ref.robot
    rng = np.random.default_rng(14)
    quaternion = quaternion_from_rotvec(rng.normal(size=(N_CONFIGS, 3)))
    R = matrix_from_quaternion(quaternion)
    L = rng.normal(size=3)
    I_G, A = maps.angular_maps(ref.Q)
    omega = base_angular_velocity(I_G, A, ref.QD, np.einsum("kji,j->ki", R, L))
    omega_0 = base_angular_velocity(I_G, A, ref.QD)
    for k, (q, q_dot) in enumerate(zip(ref.Q, ref.QD)):
        A_world = _direct_A(robot, q, pin.SE3(R[k], np.zeros(3)))
        _close(A_world[3:] @ np.r_[0.0, 0.0, 0.0, omega[k], q_dot], L)
        _close(omega_0[k], ref.J_wM[k] @ q_dot[ref.mission] + ref.J_wB[k] @ q_dot[ref.balance])
        _close(base_angular_velocity(I_G[k], A[k], q_dot), omega_0[k])


@pytest.mark.parametrize("name", ROBOTS)
def test_base_jacobian_does_not_depend_on_base_pose(reference_of, name):
    """A_G at a random base pose (world-aligned rows) is blkdiag(R, R) A_G(base at identity),
    so J_base = -A_b^{-1} A_j is the same."""
    ref = reference_of(name)
    rng = np.random.default_rng(12)
    for q, A, J_base in zip(ref.Q, ref.A, ref.J_base):
        R = pin.exp3(rng.normal(size=3))
        A_world = _direct_A(ref.robot, q, pin.SE3(R, rng.normal(scale=10, size=3)))
        _close(A_world, block_diag(R, R) @ A)
        _close(ref.numeric.centroidal_momentum_matrix(q, rotation=R), block_diag(R, R) @ A)
        _close(_base_jacobian_from(A_world), J_base)


@pytest.mark.parametrize("name", ROBOTS)
def test_ee_generalized_jacobian_moves_the_end_effector(reference_of, name):
    """J_star q_dot is the end effector's twist (origin velocity, angular velocity; world =
    base axes at the identity) when the joints move at q_dot and the base as momentum
    conservation forces it (base integrated on SE(3) with v_b = J_base q_dot)."""
    ref = reference_of(name)
    model = ref.robot.model
    data = model.createData()
    for arm in ref.robot.arms:
        frame = model.getFrameId(arm.ee_frame)
        for q, q_dot, J_base, J_star in zip(
            ref.Q, ref.QD, ref.J_base, getattr(ref, f"J_star_{arm.name}")
        ):
            q0, v = ref.robot.pin_q(q), ref.robot.pin_v(q_dot, J_base @ q_dot)

            def pose(t):
                pin.framesForwardKinematics(model, data, pin.integrate(model, q0, t * v))
                return data.oMf[frame].copy()

            def twist_fd(h):
                before, after = pose(-h), pose(h)
                linear = (after.translation - before.translation) / (2 * h)
                angular = pin.log3(after.rotation @ before.rotation.T) / (2 * h)
                return np.r_[linear, angular]

            twist = (4 * twist_fd(FD_STEP / 2) - twist_fd(FD_STEP)) / 3
            _close(J_star @ q_dot, twist, err_msg=arm.name)


@pytest.mark.parametrize("name", ROBOTS)
def test_angular_jacobian_rates(reference_of, name):
    """The rates of J_w the balance law uses (Eq. 32), from ``angular_map_rates``, against
    finite differences of J_w along q_dot and, in the product with q_dot, Pinocchio's dAg
    through momentum conservation (the two references also agree with each other)."""
    ref = reference_of(name)
    maps = ref.numeric
    I_G, _ = maps.angular_maps(ref.Q)
    dI_G, dA = maps.angular_map_rates(ref.Q, ref.QD)
    dJ_w = angular_jacobian_rate(I_G, dI_G, dA, ref.J_base[:, 3:])
    _close(dJ_w, ref.dJ_w_fd)
    _close(np.einsum("kij,kj->ki", dJ_w, ref.QD), ref.dJ_w_q_dot)
    _close(np.einsum("kij,kj->ki", ref.dJ_w_fd, ref.QD), ref.dJ_w_q_dot)


@pytest.mark.parametrize("name", ROBOTS)
def test_coupling_factor_reference(reference_of, name):
    """N (Eq. 24) maps the end-effector twist M q_dot back to the base twist J_base,arm q_dot
    for every q_dot the arm can express through its end effector (all of them when M has full
    column rank, the row space of M otherwise), and equals the SVD pseudo-inverse form."""
    ref = reference_of(name)
    for arm in ref.robot.arms:
        M_all, N_all = getattr(ref, f"M_{arm.name}"), getattr(ref, f"N_{arm.name}")
        _close(N_all, getattr(ref, f"N_svd_{arm.name}"))
        for M, N, J_base in zip(M_all, N_all, ref.J_base):
            X = np.eye(arm.dof) if arm.dof <= 6 else M.T
            _close(N @ M @ X, J_base[:, arm.indices] @ X, err_msg=arm.name)


@pytest.mark.parametrize("name", ROBOTS)
def test_force_map_reference(reference_of, name):
    ref = reference_of(name)
    for arm in ref.robot.arms:
        F_B, F_B_svd = getattr(ref, f"F_B_{arm.name}"), getattr(ref, f"F_B_svd_{arm.name}")
        for k in range(N_CONFIGS):
            scale = max(1.0, np.abs(F_B_svd[k]).max())
            _close(F_B[k], F_B_svd[k], atol=FORCE_RTOL * scale, err_msg=arm.name)
            if arm.dof >= 6:  # N is invertible: N^T F_B = F_e
                N = getattr(ref, f"N_{arm.name}")[k]
                _close(N.T @ F_B[k], ref.F_E[k], atol=FORCE_RTOL * scale, err_msg=arm.name)


# ------------------------------------------------------------------------ symbolic vs numeric
def test_centroidal_momentum_matrix(case):
    _close(case.A, case.ref.A)
    _close(case.A, case.ref.A_direct)


def test_base_jacobian(case):
    _close(case.J_base, case.ref.J_base)
    A = case.ref.A_direct
    residual = np.einsum(
        "kij,kj->ki", A[:, :, :6], np.einsum("kij,kj->ki", case.J_base, case.ref.QD)
    )
    _close(residual + np.einsum("kij,kj->ki", A[:, :, 6:], case.ref.QD), 0)  # momentum conservation


@pytest.mark.parametrize("name", ROBOTS)
def test_coupling_measures(reference_of, name):
    """The coupling measures against the SVD of the angular Jacobians."""
    ref = reference_of(name)
    columns = ref.robot.balance_arm_columns
    for m, J_wM, J_wB in zip(ref.measures, ref.J_wM, ref.J_wB):
        s_B = np.linalg.svd(J_wB, compute_uv=False)
        _close(m.balance_singular_values, s_B)
        _close(m.sigma_min, s_B[2])  # the third: the one that controls the base's 3 rotations
        _close(m.mission_norm, np.linalg.svd(J_wM, compute_uv=False)[0])
        np.testing.assert_allclose(m.balance_condition, s_B[0] / s_B[2], rtol=CONDITION_RTOL)
        assert m.per_arm.keys() == columns.keys()
        for arm, (s, cond) in m.per_arm.items():
            s_arm = np.linalg.svd(J_wB[:, columns[arm]], compute_uv=False)
            _close(s, s_arm)
            np.testing.assert_allclose(cond, s_arm[0] / s_arm[2], rtol=CONDITION_RTOL)


def test_functions_are_named_with_named_inputs_and_outputs(case):
    maps = case.maps
    expected = {
        maps.centroidal_momentum_matrix_fun(): ("centroidal_momentum_matrix", ["q"], ["A_G"]),
        maps.base_jacobian_fun(): ("base_jacobian", ["q"], ["J_base"]),
        maps.joint_placements_fun(): ("joint_placements", ["q_model"], ["oMi"]),
    }
    for fun, (name, inputs, outputs) in expected.items():
        assert (fun.name(), fun.name_in(), fun.name_out()) == (name, inputs, outputs)
    assert maps.base_jacobian_fun() is maps.base_jacobian_fun()  # built once


# ----------------------------------------------------------------------------------- backends
def test_backend_selection(paper):
    found = available_backends()
    assert found and set(found) <= set(BACKENDS)
    assert SymbolicMaps(paper).backend == found[0]
    with pytest.raises(
        BalanceOptError, match=r"unknown backend 'casadi'; expected auto, pinocchio, adam"
    ):
        SymbolicMaps(paper, backend="casadi")
    if "pinocchio" not in found:
        with pytest.raises(
            BalanceOptError,
            match=r"backend 'pinocchio' cannot be used here: pinocchio.casadi does not import "
            r"\(PyPI's pin wheels lack it\) and the Pinocchio-CasADi bridge is unavailable: ",
        ):
            SymbolicMaps(paper, backend="pinocchio")


@pytest.mark.skipif("adam" not in available_backends(), reason="adam-robotics not installed")
def test_adam_backend_names_a_prismatic_arm_joint():
    link = (
        '<link name="{}"><inertial><mass value="1"/>'
        '<inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>'
    )
    joint = (
        '<joint name="{}" type="{}"><parent link="base"/><child link="{}"/><axis xyz="1 0 0"/>'
        '<limit lower="-1" upper="1" velocity="1" effort="1"/></joint>'
    )
    urdf = "".join(
        [
            '<robot name="slider">',
            link.format("base"),
            link.format("a"),
            link.format("b"),
            joint.format("turn", "revolute", "a"),
            joint.format("slide", "prismatic", "b"),
            "</robot>",
        ]
    )
    robot = FloatingRobot(urdf, ["turn"], ["slide"])
    with pytest.raises(
        JointError,
        match=r"joint 'slide' in <URDF string>: is prismatic, which the 'adam' "
        r"backend cannot handle",
    ):
        SymbolicMaps(robot, backend="adam")


def test_pinocchio_backend_glue_with_a_numeric_stand_in(paper, baxter, monkeypatch):
    """The 'pinocchio' backend's own code (configuration by joint name, column order) run
    with a stand-in for ``pinocchio.casadi`` that evaluates numeric Pinocchio on constant SX
    inputs. pinocchio.casadi itself is not installed here."""
    import sys
    import types

    import casadi as cs

    from balance_opt.model.symbolic import _centroidal_pinocchio

    def numeric(x):
        return np.array(cs.evalf(x))

    def vector(x):
        return numeric(x).ravel()

    fake = types.ModuleType("pinocchio.casadi")
    fake.Model = lambda model: model.copy()
    fake.computeCentroidalMap = lambda model, data, q: pin.computeCentroidalMap(
        model, data, vector(q)
    )
    monkeypatch.setitem(sys.modules, "pinocchio.casadi", fake)
    rng = np.random.default_rng(13)
    for robot in (paper, baxter):
        numeric_maps = NumericMaps(robot)
        for _ in range(3):
            q = rng.uniform(robot.limits.lower, robot.limits.upper)
            A = _centroidal_pinocchio(robot, cs.SX(q))
            _close(numeric(A), numeric_maps.centroidal_momentum_matrix(q))


@pytest.mark.skipif("adam" not in available_backends(), reason="adam-robotics not installed")
def test_adam_reads_inertials_without_an_origin():
    """An ``<inertial>`` without ``<origin>`` sits at its link frame (the URDF default, as in
    Talos' files); adam's parser needs it spelled out, and its map then equals Pinocchio's."""
    link = (
        '<link name="{}"><inertial><mass value="{}"/>'
        '<inertia ixx="0.3" ixy="0.01" ixz="0" iyy="0.2" iyz="0" izz="0.4"/></inertial></link>'
    )
    joint = (
        '<joint name="{}" type="revolute"><parent link="{}"/><child link="{}"/>'
        '<origin xyz="{}" rpy="0.1 0 0.2"/><axis xyz="{}"/>'
        '<limit lower="-2" upper="2" velocity="1" effort="1"/></joint>'
    )
    urdf = "".join(
        [
            '<robot name="no_origin">',
            link.format("base", 20.0),
            link.format("m1", 2.0),
            link.format("m2", 1.5),
            link.format("b1", 2.5),
            joint.format("mj1", "base", "m1", "0.5 0 0.2", "0 0 1"),
            joint.format("mj2", "m1", "m2", "0.4 0 0", "0 1 0"),
            joint.format("bj1", "base", "b1", "-0.5 0.1 0.2", "1 0 0"),
            "</robot>",
        ]
    )
    robot = FloatingRobot(urdf, ["mj1", "mj2"], ["bj1"])
    maps = SymbolicMaps(robot, backend="adam")
    numeric = NumericMaps(robot)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-1.5, 1.5, robot.n)
        A_sym = np.array(maps.centroidal_momentum_matrix_fun()(q))
        np.testing.assert_allclose(A_sym, numeric.centroidal_momentum_matrix(q), atol=1e-12)


def test_joint_placements_are_pinocchios(case):
    """Every joint frame by the backend (what the collision shapes are placed with) against
    numeric Pinocchio's forward kinematics, at the model joints' positions (followers too)."""
    robot, f = case.ref.robot, case.maps.joint_placements_fun()
    E, e = robot.mimic_matrix
    model, data = robot.model, robot.model.createData()
    for q in case.ref.Q[:10]:
        oMi = np.array(f(E @ q + e))
        pin.forwardKinematics(model, data, robot.pin_q(q))
        for j in range(1, model.njoints):
            rotation, translation = oMi[:9, j - 1].reshape(3, 3, order="F"), oMi[9:, j - 1]
            _close(rotation, data.oMi[j].rotation)
            _close(translation, data.oMi[j].translation)
