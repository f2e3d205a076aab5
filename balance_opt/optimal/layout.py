"""Where everything sits in the balance NLP's vectors: blocks of variables, parameters and rows
stacked one after the other, and the units of their rows."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import casadi as cs
import numpy as np

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
    """Unit of a state, control or limit label (an attitude row's is rad)."""
    if label.startswith("attitude"):
        return "rad"
    return UNITS[label.split()[-1]]


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
        return slice(self.offset, self.offset + self.size)

    def locate(self, index: int) -> tuple[str, str, float]:
        """``(row label, unit, tau)`` of a global index inside this block."""
        local = index - self.offset
        row, col = local % len(self.rows), local // len(self.rows)
        return self.rows[row], self.units[row], float(self.taus[col])


class BlockStack:
    """Blocks stacked one after the other into a vector: the decision variables, the parameters
    or the rows of ``g``. A block of variables or parameters is a field of what the vector
    unpacks to (:class:`Solution`, a namespace of the parameters)."""

    def __init__(self, *blocks: Block):
        self.blocks: list[Block] = []
        self.by_name: dict[str, Block] = {}
        self.size = 0
        for block in blocks:
            self.add(block)

    def add(self, block: Block) -> Block:
        block = dataclasses.replace(block, offset=self.size)
        self.blocks.append(block)
        self.by_name[block.name] = block
        self.size += block.size
        return block

    def block_at(self, index: int) -> Block:
        offsets = [b.offset for b in self.blocks]
        return self.blocks[int(np.searchsorted(offsets, index, side="right")) - 1]

    def unpack(self, w, into=None):
        """The blocks of ``w`` (NumPy, or a CasADi symbol), each a (rows, columns) matrix, as
        the fields of ``into`` (default :class:`Solution`)."""
        into = into or Solution
        if isinstance(w, (cs.SX, cs.MX)):
            return into(**{n: cs.reshape(w[b.slice], *b.shape) for n, b in self.by_name.items()})
        w = np.asarray(w, dtype=float).ravel()
        return into(**{n: w[b.slice].reshape(b.shape, order="F") for n, b in self.by_name.items()})

    def pack(self, fields) -> np.ndarray:
        w = np.empty(self.size)
        for name, b in self.by_name.items():
            w[b.slice] = np.asarray(getattr(fields, name), dtype=float).ravel(order="F")
        return w


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
    #: a free mission timing's (:mod:`balance_opt.optimal.timing`): the mission joints at the
    #: points, the path progress and its rate, its acceleration
    M: Any = None
    Mm: Any = None
    P: Any = None
    Pm: Any = None
    A: Any = None
    Am: Any = None

    def points(self) -> tuple[Any, Any]:
        """``(states, controls)`` at every collocation point: nodes, then midpoints."""
        if self.Xm is None:
            return self.X, self.U
        if isinstance(self.X, np.ndarray):
            return np.hstack([self.X, self.Xm]), np.hstack([self.U, self.Um])
        return cs.horzcat(self.X, self.Xm), cs.horzcat(self.U, self.Um)


def variable_layout(
    transcription: Transcription,
    N: int,
    state_labels,
    control_labels,
    mission_labels=(),
    extra: tuple[Block, ...] = (),
) -> BlockStack:
    """The decision vector's blocks ``X``, ``Xm``, ``U``, ``Um`` (the midpoints' with the
    transcription's midpoints), with ``mission_labels`` (a free mission timing) ``M``, ``Mm``
    (the mission joints at the points: kernel inputs, so before the others), ``P``, ``Pm``,
    ``A``, ``Am`` (the path progress), and the terms' ``extra`` blocks (the peak's ``S``)."""
    nodes = np.arange(N + 1, dtype=float)
    layout = BlockStack()
    for name, labels, taus in (
        ("X", state_labels, nodes),
        ("Xm", state_labels, nodes[:-1] + 0.5),
        ("U", control_labels, nodes),
        ("Um", control_labels, nodes[:-1] + 0.5),
    ):
        if transcription.has_midpoints or not name.endswith("m"):
            layout.add(Block(name, tuple(labels), tuple(unit_of(r) for r in labels), taus))
    if mission_labels:
        path = {"P": ("path progress", "path progress rate"), "A": ("path progress acceleration",)}
        for name, labels in (("M", mission_labels), *path.items()):
            for suffix, taus in (("", nodes), ("m", nodes[:-1] + 0.5)):
                if transcription.has_midpoints or not suffix:
                    units = ("(path)",) * len(labels) if name != "M" else None
                    units = units or tuple(unit_of(r) for r in labels)
                    layout.add(Block(name + suffix, tuple(labels), units, taus))
    for block in extra:
        layout.add(block)
    return layout


def parameter_layout(values: dict[str, Any]) -> BlockStack:
    """The parameter vector ``p``: the terms' values (:meth:`~.terms.Term.values`), one after
    the other, each a matrix stacked column by column (a scalar 1 x 1, a vector a column); it
    unpacks to a namespace of them."""
    blocks = []
    for name, value in values.items():
        value = np.asarray(value, dtype=float)
        rows, columns = value.shape if value.ndim == 2 else (value.size, 1)
        blocks.append(Block(name, (name,) * rows, ("",) * rows, np.arange(float(columns))))
    return BlockStack(*blocks)
