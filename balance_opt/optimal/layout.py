"""Where everything sits in the balance NLP's vectors, in one place for the build and the solve."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, NamedTuple

import casadi as cs
import numpy as np

from balance_opt.optimal.budget import limited_kinds
from balance_opt.optimal.collocation import Transcription

#: Unit of a row, by the last word of its label (``"balance_joint2 velocity"`` -> rad/s).
UNITS = {
    "position": "rad",
    "velocity": "rad/s",
    "acceleration": "rad/s^2",
    "jerk": "rad/s^3",
    "torque": "N m",
}


def unit_of(label: str) -> str:
    """Unit of a state, control or limit label: the attitude rows are in rad, a joint row in the
    unit of its last word (:data:`UNITS`)."""
    if label.startswith("attitude"):
        return "rad"
    return UNITS[label.split()[-1]]


@dataclass(frozen=True)
class StructureKey:
    """What two problems must share to share one compiled NLP (everything else is numeric data)."""

    intervals: int
    transcription: str
    control: str
    joint_limits: tuple[str, ...]
    torque_limits: bool
    objective: str
    path_attitude_bound: bool
    terminal_attitude_bound: bool
    tolerance: float
    max_iterations: int
    ipopt: tuple[tuple[str, str], ...]
    momentum: bool = False
    between_points: bool = True
    collision: str = ""

    @classmethod
    def of(cls, limits, options, momentum: bool = False, collision: str = "") -> StructureKey:
        """The key of a problem."""
        enforced = limited_kinds(options, limits)
        joints = ("position", "velocity", "acceleration", "jerk")
        return cls(
            intervals=int(options.intervals),
            transcription=options.transcription,
            control=options.control,
            joint_limits=tuple(sorted(kind for kind in joints if enforced[kind])),
            torque_limits=enforced["torque"],
            objective=options.objective,
            path_attitude_bound=options.path_attitude_bound is not None
            and options.objective != "peak",
            terminal_attitude_bound=options.terminal_attitude_bound is not None,
            tolerance=options.tolerance,
            max_iterations=int(options.max_iterations),
            ipopt=tuple(sorted((k, repr(v)) for k, v in options.ipopt.items())),
            momentum=bool(momentum),
            collision=collision if options.collision_avoidance else "",
        )


@dataclass(frozen=True)
class Block:
    """A block of variables or constraints: a matrix whose columns are time, stacked column by
    column into its vector."""

    name: str
    rows: tuple[str, ...]
    units: tuple[str, ...]
    taus: np.ndarray
    per_interval: bool = False
    offset: int = 0

    @property
    def size(self) -> int:
        return len(self.rows) * len(self.taus)

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.rows), len(self.taus)

    @property
    def slice(self) -> slice:
        """Its entries in the stacked vector."""
        return slice(self.offset, self.offset + self.size)

    def locate(self, index: int) -> tuple[str, str, float]:
        """``(row label, unit, tau)`` of a global index inside this block."""
        local = index - self.offset
        row, col = local % len(self.rows), local // len(self.rows)
        return self.rows[row], self.units[row], float(self.taus[col])


class BlockStack:
    """Blocks stacked one after the other into a vector."""

    def __init__(self):
        self.blocks: list[Block] = []
        self.size = 0

    def add(self, block: Block) -> Block:
        """Stack a block after the others; returns it with its offset."""
        block = dataclasses.replace(block, offset=self.size)
        self.blocks.append(block)
        self.size += block.size
        return block

    def block_at(self, index: int) -> Block:
        """The block holding entry ``index``."""
        offsets = [b.offset for b in self.blocks]
        return self.blocks[int(np.searchsorted(offsets, index, side="right")) - 1]


@dataclass
class Solution:
    """A point of the NLP, unpacked: states and controls at the nodes and midpoints (the
    midpoints' are ``None`` without them) and the peak objective's epigraph variable ``S``
    (``None`` without it). NumPy arrays, or CasADi symbols in the build."""

    X: Any
    U: Any
    Xm: Any = None
    Um: Any = None
    S: Any = None

    def points(self) -> tuple[Any, Any]:
        """``(states, controls)`` at every collocation point: nodes, then midpoints."""
        if self.Xm is None:
            return self.X, self.U
        if isinstance(self.X, np.ndarray):
            return np.hstack([self.X, self.Xm]), np.hstack([self.U, self.Um])
        return cs.horzcat(self.X, self.Xm), cs.horzcat(self.U, self.Um)


class VariableLayout(BlockStack):
    """The decision vector's blocks ``X``, ``Xm``, ``U``, ``Um``, ``S`` (see the module
    docstring)."""

    def __init__(
        self, transcription: Transcription, N: int, state_labels, control_labels, peak=False
    ):
        super().__init__()
        nodes = np.arange(N + 1, dtype=float)
        mids = nodes[:-1] + 0.5
        self.has_midpoints = transcription.has_midpoints
        self.by_name: dict[str, Block] = {}
        for name, labels, taus in (
            ("X", state_labels, nodes),
            ("Xm", state_labels, mids),
            ("U", control_labels, nodes),
            ("Um", control_labels, mids),
        ):
            if name.endswith("m") and not self.has_midpoints:
                continue
            units = tuple(unit_of(r) for r in labels)
            self.by_name[name] = self.add(Block(name, tuple(labels), units, taus))
        if peak:
            label = ("attitude peak^2 / PEAK_SCALE^2",)
            self.by_name["S"] = self.add(Block("S", label, ("(relative)",), np.array([0.0])))

    def unpack(self, w) -> Solution:
        """States and controls of a numeric decision vector."""
        w = np.asarray(w, dtype=float).ravel()
        return Solution(
            **{n: w[b.slice].reshape(b.shape, order="F") for n, b in self.by_name.items()}
        )

    def unpack_symbolic(self, w) -> Solution:
        """States and controls of a symbolic decision vector (CasADi column vector)."""
        return Solution(
            **{
                n: cs.reshape(w[b.offset : b.offset + b.size], *b.shape)
                for n, b in self.by_name.items()
            }
        )

    def pack(self, sol: Solution) -> np.ndarray:
        """The numeric decision vector of unpacked states and controls."""
        w = np.empty(self.size)
        for name, b in self.by_name.items():
            w[b.slice] = np.asarray(getattr(sol, name), dtype=float).ravel(order="F")
        return w

    def point_indices(self) -> np.ndarray:
        """(n_z, n_points) indices into ``w`` of each point's ``z = [x; u]``, points in the order
        nodes, then midpoints."""

        def indices(name):
            b = self.by_name[name]
            return b.offset + np.arange(b.size).reshape(b.shape, order="F")

        X, U = indices("X"), indices("U")
        if self.has_midpoints:
            X, U = np.hstack([X, indices("Xm")]), np.hstack([U, indices("Um")])
        return np.vstack([X, U])

    def describe(self, index: int) -> tuple[str, float]:
        """``(name, tau)`` of entry ``index``: ``"node balance_joint1 velocity"``,
        ``"midpoint ..."``, ``"peak ..."``."""
        block = self.block_at(index)
        row, _, tau = block.locate(index)
        if block.name == "S":
            return f"peak {row}", tau
        return f"{'midpoint' if block.name.endswith('m') else 'node'} {row}", tau


class NLPParameters(NamedTuple):
    """The fields of the parameter vector ``p``, in its order."""

    h: Any
    terminal_weight: Any
    running_weights: Any
    path_scale: Any
    terminal_scale: Any
    peak_weight: Any
    smooth_weight: Any
    smooth_scale: Any
    jerk_weight: Any
    q_rest: Any
    mission: Any


@dataclass(frozen=True)
class ParameterLayout:
    """The parameter vector ``p``: the fields of :class:`NLPParameters`, one after the other
    (the mission samples column by column)."""

    n_weights: int
    n_B: int
    n_m: int
    n_points: int

    @property
    def slices(self) -> dict[str, slice]:
        """Each field's entries in ``p``."""
        sizes = {
            "h": 1,
            "terminal_weight": 1,
            "running_weights": self.n_weights,
            "path_scale": 1,
            "terminal_scale": 1,
            "peak_weight": 1,
            "smooth_weight": 1,
            "smooth_scale": 1,
            "jerk_weight": 1,
            "q_rest": self.n_B,
            "mission": self.n_m * self.n_points,
        }
        out, start = {}, 0
        for name in NLPParameters._fields:
            out[name] = slice(start, start + sizes[name])
            start += sizes[name]
        return out

    @property
    def size(self) -> int:
        return self.slices["mission"].stop

    def pack(self, values: NLPParameters) -> np.ndarray:
        """The numeric parameter vector of a problem."""
        p = np.empty(self.size)
        for name, sl in self.slices.items():
            value = np.asarray(getattr(values, name), dtype=float)
            p[sl] = value.ravel(order="F")
        return p

    def unpack_symbolic(self, p) -> NLPParameters:
        """The fields of a symbolic parameter vector (CasADi column vector): each a column
        (the scalars 1 x 1), the mission samples an (n_m, n_points) matrix."""
        fields = {name: p[sl] for name, sl in self.slices.items()}
        fields["mission"] = cs.reshape(fields["mission"], self.n_m, self.n_points)
        return NLPParameters(**fields)
