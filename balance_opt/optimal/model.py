"""The per-robot symbolic model of the optimal balance planner: the balance dynamics, the running
cost and the free-floating inverse dynamics as CasADi functions of ONE collocation point, saved
on disk once and loaded by every later run instead of being built again."""

from __future__ import annotations

import contextlib
import hashlib
import importlib.util
import logging
import weakref
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import casadi as cs

from balance_opt.cache import (
    kinematics_key,
)
from balance_opt.errors import BalanceOptError
from balance_opt.model.robot import FloatingRobot
from balance_opt.model.symbolic import (
    SymbolicMaps,
    adam_kindyn,
    backend_identity,
    check_adam_joints,
    model_joint_positions,
    model_velocity_map,
)
from balance_opt.motion.so3_casadi import inverse_right_jacobian_sym, rotation_matrix_sym
from balance_opt.optimal.collision import CollisionModels
from balance_opt.optimal.terms import Output, Point
from balance_opt.solvers import codegen
from balance_opt.solvers.codegen import FunctionStore
from balance_opt.solvers.kernel_nlp import function, kernel_functions

log = logging.getLogger(__name__)

#: The modules whose code decides the planner's symbolic functions.
FORMULATION_MODULES = (
    "balance_opt.optimal.model",
    "balance_opt.model.symbolic",
    "balance_opt.model.coupling",
    "balance_opt.model.robot",
    "balance_opt.model.joints",
    "balance_opt.model.bridge",
    "balance_opt.motion.so3_casadi",
    "balance_opt.geometry.shapes",  # the collision rows in the kernels
    "balance_opt.solvers.kernel_nlp",  # the kernels' derivatives
)

#: Rows of the momentum ``h0`` at the end of a point's data ``m`` ([linear; angular]).
MOMENTUM_ROWS = 6


def formulation_fingerprint() -> str:
    """Hash of the source of :data:`FORMULATION_MODULES` and of CasADi's version."""
    digest = hashlib.sha256(cs.__version__.encode())
    for name in FORMULATION_MODULES:
        spec = importlib.util.find_spec(name)
        digest.update(Path(spec.origin).read_bytes() if spec and spec.origin else name.encode())
    return digest.hexdigest()


def model_key(robot: FloatingRobot, backend_identity: str) -> str:
    """The content key of a robot's planner model built with a backend: its kinematics, the
    backend and the code of the formulation."""
    parts = [kinematics_key(robot), backend_identity, formulation_fingerprint()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:20]


def _tag(momentum: bool) -> str:
    return "_h" if momentum else ""


@dataclass(frozen=True)
class PointKernels:
    """The NLP's nonlinear work at one collocation point, with its exact derivatives: the
    outputs ``y`` of the terms' :class:`Output` declarations (``layout``: ``(name, size)`` in
    order), stacked."""

    value: cs.Function
    jacobian: cs.Function
    gradient: cs.Function
    hessian: cs.Function
    n_x: int
    n_z: int
    layout: tuple[tuple[str, int], ...]
    n_cost: int
    compiled: bool = False
    compile_time: float = 0.0
    library: str | None = None
    background: bool = False
    #: with outputs out of the cost: the outputs ``y`` without them
    cost: cs.Function | None = None
    #: ``(control, outputs, momentum, timing)`` it was made of (to make it again)
    variant: tuple = field(default=(), compare=False, repr=False)

    @property
    def n_y(self) -> int:
        return sum(size for _, size in self.layout)

    def rows(self, Y) -> dict:
        """The rows of kernel outputs ``Y`` (n_y, n_points) by output name."""
        out, start = {}, 0
        for name, size in self.layout:
            out[name] = Y[start : start + size, :]
            start += size
        return out


class PlannerModel:
    """Symbolic model of a robot for the optimal planner, built once and cached in memory and
    on disk (:class:`FunctionStore`).

    ``compile``: ``"auto"`` compiles a new robot's point kernels before its first plan solves,
    waiting (at most :data:`~balance_opt.solvers.codegen.COMPILE_WAIT`; the VM if that fails),
    if there is a C compiler; ``"background"`` solves on CasADi's VM while they compile and
    waits at the end of the plan; ``True`` compiles now; ``False`` never."""

    def __init__(
        self,
        robot: FloatingRobot,
        maps: SymbolicMaps | None = None,
        compile: bool | str = "auto",
        cache_dir: str | Path | None = None,
        backend: str = "auto",
        store: bool = True,
    ):
        if compile not in (True, False, "auto", "background"):
            raise ValueError(
                f"compile must be True, False, 'auto' or 'background', got {compile!r}"
            )
        self.robot = robot
        self._maps = maps
        self._backend = maps.backend if maps is not None else backend
        self.n_M = robot.mission.dof
        self.n_B = int(robot.balance_indices.size)
        if compile == "auto" and codegen.find_compiler() is None:
            compile = False
        self.compile = compile
        # background compilations this model started: waited for at the end of a plan
        # (finish_compiling), stopped when the model goes or the process exits
        self._compiling: list = []
        weakref.finalize(self, _stop_all, self._compiling)
        self.cache_dir = cache_dir
        self.store = FunctionStore(robot.name, self.key, cache_dir) if store else None
        self._funs: dict[str, cs.Function] = {}
        self._kernels: dict[tuple, PointKernels] = {}
        self.nlp_cache: dict = {}
        self.collisions = CollisionModels(robot)

    @property
    def maps(self) -> SymbolicMaps:
        if self._maps is None:
            self._maps = SymbolicMaps(self.robot, self._backend)
        return self._maps

    @cached_property
    def key(self) -> str:
        return model_key(self.robot, backend_identity(self._backend)[1])

    def _stored(self, name: str, make) -> list[cs.Function]:
        return self.store.get(name, make) if self.store is not None else make()

    def _stored_one(self, name: str, make) -> cs.Function:
        return self._cached(name, lambda: self._stored(name, lambda: [make()])[0])

    def n_x(self, control: str) -> int:
        """State size: attitude (3) and balance position, velocity (and acceleration for jerk)."""
        return 3 + (2 if control == "acceleration" else 3) * self.n_B

    @property
    def n_u(self) -> int:
        return self.n_B

    @property
    def n_m(self) -> int:
        """Size of a point's data ``[q_M; q_dot_M; q_ddot_M; h0]``."""
        return 3 * self.n_M + MOMENTUM_ROWS

    def joint_rows(self, control: str) -> list[slice]:
        """State rows of the balance joints' chain of integrators: position, velocity (and
        acceleration with control ``"jerk"``)."""
        n_B = self.n_B
        return [
            slice(3 + k * n_B, 3 + (k + 1) * n_B) for k in range((self.n_x(control) - 3) // n_B)
        ]

    def state_labels(self, control: str) -> list[str]:
        names = self.robot.joint_names
        balance = [names[i] for i in self.robot.balance_indices]
        labels = [f"attitude phi_{a}" for a in "xyz"]
        kinds = ["position", "velocity"] + (["acceleration"] if control == "jerk" else [])
        for kind in kinds:
            labels += [f"{j} {kind}" for j in balance]
        return labels

    def _symbols(self, control: str):
        n_B, n_M = self.n_B, self.n_M
        x = cs.SX.sym("x", self.n_x(control))
        u = cs.SX.sym("u", n_B)
        m = cs.SX.sym("m", self.n_m)
        return x, u, m, x[:3], x[3 : 3 + n_B], x[3 + n_B : 3 + 2 * n_B], m[:n_M], m[n_M : 2 * n_M]

    def _momentum_in_base(self, phi, m):
        """``R^T h0`` (6): the point's momentum (last rows of ``m``, initial base axes) in the
        axes of the base at attitude ``phi``."""
        Rt = rotation_matrix_sym(phi).T
        h0 = m[3 * self.n_M :]
        return cs.vertcat(Rt @ h0[:3], Rt @ h0[3:])

    def _cached(self, key: str, make) -> cs.Function:
        if key not in self._funs:
            self._funs[key] = make()
        return self._funs[key]

    def _omega(self, q_M, q_B, q_dot_M, q_dot_B, ell):
        """``omega_b = I_G^{-1} (ell - A_j q_dot)`` from the angular rows of the centroidal
        momentum matrix (Eq. 26): ``I_G`` is the locked inertia about the CoM, ``A_j`` the joint
        columns, ``ell = R^T L0`` the angular momentum about the CoM in base axes; the base's
        linear columns of these rows are zero, so the linear momentum does not turn the base.
        One 3 x 3 solve of a vector instead of the full 6 x 6 ``J_base``: a smaller Hessian."""
        A = self.maps.centroidal_momentum_matrix_fun()(cs.vertcat(q_M, q_B))
        return cs.solve(A[3:, 3:6], ell - A[3:, 6:] @ cs.vertcat(q_dot_M, q_dot_B))

    def dynamics_fun(self, control: str = "acceleration", momentum: bool = True) -> cs.Function:
        """``balance_dynamics(x, u, m) -> (x_dot, omega)``: the state's time derivative and the
        base angular velocity in the base frame [rad/s] (Eq. 26 with the momentum ``h0`` of
        ``m``; without ``momentum`` its rows are ignored: zero momentum)."""

        def make():
            x, u, m, phi, q_B, q_dot_B, q_M, q_dot_M = self._symbols(control)
            ell = self._momentum_in_base(phi, m)[3:] if momentum else cs.SX.zeros(3)
            omega = self._omega(q_M, q_B, q_dot_M, q_dot_B, ell)
            parts = [inverse_right_jacobian_sym(phi) @ omega, q_dot_B]
            parts += [u] if control == "acceleration" else [x[3 + 2 * self.n_B :], u]
            return function(
                "balance_dynamics",
                {"x": x, "u": u, "m": m},
                {"x_dot": cs.vertcat(*parts), "omega": omega},
            )

        return self._stored_one(f"dynamics_{control}{_tag(momentum)}", make)

    @cached_property
    def _dynamics_terms(self) -> cs.Function:
        """``(q, nu) -> (M, h)``: mass matrix and bias forces of the free-floating system,
        base at the identity, ``nu = [base twist in the base frame; q_dot]`` (adam, body-fixed
        representation, no gravity)."""
        try:
            from adam import Representations
        except ImportError as exc:
            raise BalanceOptError(f"torque limits need adam-robotics[casadi]: {exc}") from exc
        robot = self.robot
        check_adam_joints(robot, "lock it, or plan without torque limits (they use adam)")
        kd = adam_kindyn(robot)
        kd.set_frame_velocity_representation(Representations.BODY_FIXED_REPRESENTATION)
        q = cs.SX.sym("q", robot.n)
        nu = cs.SX.sym("nu", 6 + robot.n)
        H = cs.SX.eye(4)
        # mimic joints move with their drivers: reduced coordinates, M_r = G^T M G, h_r = G^T h
        G = cs.DM(model_velocity_map(robot))
        q_m, nu_m = model_joint_positions(robot, q), cs.mtimes(G, nu) if robot.followers else nu
        M = kd.mass_matrix(H, q_m)
        h = kd.bias_force(H, q_m, nu_m[:6], nu_m[6:])
        M = cs.SX(M.array if hasattr(M, "array") else M)
        h = cs.SX(h.array if hasattr(h, "array") else h)
        if robot.followers:
            M, h = G.T @ M @ G, G.T @ h
        return function("floating_dynamics_terms", {"q": q, "nu": nu}, {"M": M, "h": h})

    def _torques(self, q, q_dot, q_ddot, v_b):
        M, h = self._dynamics_terms(q, cs.vertcat(v_b, q_dot))
        a_b = -cs.solve(M[:6, :6], M[:6, 6:] @ q_ddot + h[:6])
        return M[6:, :6] @ a_b + M[6:, 6:] @ q_ddot + h[6:]

    def torque_fun(self, momentum: bool = False) -> cs.Function:
        """``joint_torques(q, q_dot, q_ddot) -> tau``: arm joint torques [N m] (arm order) that
        produce the joint accelerations ``q_ddot`` of the free-floating system with no external
        wrench on the base, at zero momentum (the base twist ``J_base q_dot``, Eq. 19); with
        ``momentum``, ``joint_torques_h(q, q_dot, q_ddot, h_b)`` at the momentum ``h_b`` (base
        axes, [linear; angular about the CoM])."""

        def make():
            n = self.robot.n
            inputs = {k: cs.SX.sym(k, n) for k in ("q", "q_dot", "q_ddot")}
            q, q_dot, q_ddot = inputs.values()
            v_b = self.maps.base_jacobian_fun()(q) @ q_dot
            if momentum:
                inputs["h_b"] = cs.SX.sym("h_b", MOMENTUM_ROWS)
                A = self.maps.centroidal_momentum_matrix_fun()(q)
                v_b = v_b + cs.solve(A[:, :6], inputs["h_b"])
            tau = self._torques(q, q_dot, q_ddot, v_b)
            return function(f"joint_torques{_tag(momentum)}", inputs, {"tau": tau})

        return self._stored_one(f"torque{_tag(momentum)}", make)

    def balance_torque_fun(
        self, control: str = "acceleration", momentum: bool = True
    ) -> cs.Function:
        """``balance_torques(x, u, m) -> tau_B``: the balance joints' torques [N m] at a point
        (zero momentum without ``momentum``)."""

        def make():
            x, u, m, phi, q_B, q_dot_B, q_M, q_dot_M = self._symbols(control)
            q_ddot_B = u if control == "acceleration" else x[3 + 2 * self.n_B :]
            q_ddot_M = m[2 * self.n_M : 3 * self.n_M]
            joints = (
                cs.vertcat(q_M, q_B),
                cs.vertcat(q_dot_M, q_dot_B),
                cs.vertcat(q_ddot_M, q_ddot_B),
            )
            h_b = [self._momentum_in_base(phi, m)] if momentum else []
            tau = self.torque_fun(momentum)(*joints, *h_b)
            return function("balance_torques", {"x": x, "u": u, "m": m}, {"tau_B": tau[self.n_M :]})

        return self._cached(f"balance_torque_{control}{_tag(momentum)}", make)

    def kernels(
        self,
        control: str = "acceleration",
        outputs: tuple[Output, ...] = (),
        momentum: bool = False,
        timing: bool = False,
    ) -> PointKernels:
        """The point kernels (:class:`PointKernels`) of a control, the terms' ``outputs`` and
        momentum setting, built once (and compiled once, if the model compiles); with
        ``timing`` (a free mission timing) the mission joints ``[q_M; q_dot_M; q_ddot_M]`` are
        the last rows of ``z``, not of the data ``m``."""
        key = kernel_key(control, outputs, momentum, timing)
        if key not in self._kernels:
            self._kernels[key] = self._make_kernels(control, tuple(outputs), momentum, timing)
        return self._kernels[key]

    def finish_compiling(self, timeout: float = codegen.COMPILE_WAIT) -> None:
        """Wait for the background compilations this model started, each at most ``timeout``
        [s], stopping those that do not end (:func:`~balance_opt.solvers.codegen.finish`); the
        end of every planning call (nothing it started outlives it)."""
        try:
            while self._compiling:
                codegen.finish(self._compiling.pop(), timeout)
        finally:  # interrupted while waiting for one: the others end too
            self.stop_compiling()

    def stop_compiling(self) -> None:
        """Stop the background compilations this model started (they are not cached)."""
        _stop_all(self._compiling)

    def upgrade_kernels(self) -> int:
        """Swap kernels running on the VM for their library once its background compilation
        has finished (and drop the NLPs built on them); for processes that plan many tasks."""
        done = []
        for key, kernels in list(self._kernels.items()):
            if kernels.background and Path(kernels.library).exists():
                self._kernels[key] = self._make_kernels(*kernels.variant)
                done += [key] if self._kernels[key].compiled else []
        if done:
            log.info("planner kernels of %s: compiled library loaded", self.robot.name)
        self.nlp_cache = {k: v for k, v in self.nlp_cache.items() if v.kernel_key not in done}
        return len(done)

    def _make_kernels(
        self, control: str, outputs: tuple[Output, ...], momentum: bool, timing: bool = False
    ) -> PointKernels:
        """The kernels from the compiled library (no expression built), else from the disk
        store or built, compiled now or in the background as :attr:`compile` says."""
        tags = "".join(o.tag for o in outputs)
        suffix = f"{control}{tags}{_tag(momentum)}{'_free' if timing else ''}"
        n_x = self.n_x(control)
        n_z = n_x + self.n_u + (3 * self.n_M if timing else 0)
        costly = any(not o.in_cost for o in outputs)
        sizes = (n_x, n_z, tuple((o.name, o.size) for o in outputs))
        sizes += (sum(o.size for o in outputs if o.in_cost),)
        variant = (control, outputs, momentum, timing)
        parts = ("", "_jac", "_grad", "_hess") + (("_cost",) if costly else ())
        names = [f"balance_kernel{part}_{suffix}" for part in parts]
        digest = f"{self.key}/{suffix}" if self.store is not None else None
        compiler = codegen.find_compiler() if self.compile else None
        if compiler is not None and digest is not None:
            library = codegen.library_path(digest, compiler, self.cache_dir)
            with contextlib.suppress(BlockingIOError):  # being compiled by another process
                loaded = codegen.load_cached(names, library)
                if loaded is not None:
                    compiled = codegen.Compiled(loaded, True, 0.0, str(library))
                    return _point_kernels(compiled, sizes, variant)
        functions = self._stored(
            f"kernels_{suffix}",
            lambda: self._kernel_functions(control, outputs, momentum, suffix, timing),
        )
        out = codegen.Compiled(functions, False, 0.0, None)
        if self.compile:
            try:
                out = codegen.compile_functions(
                    functions,
                    self.cache_dir,
                    digest,
                    background=self.compile in ("auto", "background"),
                    label=self.robot.name,
                    # the compilers on every core cost less than the VM's solve beside them
                    wait=self.compile == "auto",
                )
            except (OSError, RuntimeError) as exc:
                log.warning(
                    "balance kernels not compiled (%s); using CasADi's virtual machine", exc
                )
            if out.process is not None:
                self._compiling.append(out.process)
        return _point_kernels(out, sizes, variant)

    def _kernel_functions(
        self,
        control: str,
        outputs: tuple[Output, ...],
        momentum: bool,
        suffix: str,
        timing: bool = False,
    ) -> list[cs.Function]:
        """The point kernels as SX functions: value, Jacobian, gradient (of the outputs in the
        cost), Hessian, and with outputs out of the cost the outputs before them
        (:attr:`PointKernels.cost`)."""
        n_x, n_u, n_j = self.n_x(control), self.n_u, 3 * self.n_M
        z = cs.SX.sym("z", n_x + n_u + (n_j if timing else 0))
        m_in = cs.SX.sym("m", self.n_m)
        extra = dict(i for o in outputs for i in o.inputs)
        inputs = {"z": z, "m": m_in} | {k: cs.SX.sym(k, n) for k, n in extra.items()}
        x, u = z[:n_x], z[n_x : n_x + n_u]
        # a free timing's mission joints are variables: the data's rows of them are unused
        m = cs.vertcat(z[n_x + n_u :], m_in[n_j:]) if timing else m_in
        given = [inputs[k] for k in extra]
        fused = self._point_function(control, momentum, outputs, extra)(x, u, m, *given)
        fused = iter([fused] if isinstance(fused, cs.SX) else fused)
        point = self._point(control, momentum, x, u, m, dict(zip(extra, given)))
        parts = [next(fused) if o.with_dynamics else o.make(point) for o in outputs]
        y = cs.vertcat(*parts)
        y_cost = cs.vertcat(*(p for p, o in zip(parts, outputs) if o.in_cost))
        return kernel_functions("balance_kernel", suffix, inputs, y, y_cost)

    def _point(self, control, momentum, x, u, m, inputs) -> Point:
        x_dot, omega = self.dynamics_fun(control, momentum)(x, u, m)
        E, e = self.robot.mimic_matrix
        q = cs.DM(E) @ cs.vertcat(m[: self.n_M], x[3 : 3 + self.n_B]) + cs.DM(e)
        return Point(self, control, momentum, x, u, m, q, x_dot, omega, inputs)

    def _point_function(self, control, momentum, outputs, extra: dict) -> cs.Function:
        """``balance_point(x, u, m, *inputs)``: the outputs made ``with_dynamics`` at one point,
        one function with the dynamics (their common subexpressions shared)."""
        x, u, m, *_ = self._symbols(control)
        inputs = {k: cs.SX.sym(k, n) for k, n in extra.items()}
        point = self._point(control, momentum, x, u, m, inputs)
        made = {o.name: o.make(point) for o in outputs if o.with_dynamics}
        return function("balance_point", {"x": x, "u": u, "m": m, **inputs}, made)


def kernel_key(control: str, outputs, momentum: bool, timing: bool) -> tuple:
    """What makes two point kernels one: the control, the outputs' tags, momentum, timing."""
    return (control, tuple(o.tag for o in outputs), bool(momentum), bool(timing))


def _point_kernels(out: codegen.Compiled, sizes: tuple, variant: tuple) -> PointKernels:
    f = list(out.functions)
    compiled = (out.compiled, out.compile_time, out.library, out.background)
    return PointKernels(*f[:4], *sizes, *compiled, f[4] if len(f) > 4 else None, variant)


def _stop_all(compiling: list) -> None:
    while compiling:
        compiling.pop().stop()
