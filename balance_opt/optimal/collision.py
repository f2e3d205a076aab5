"""Collision avoidance in the optimal planner: which pairs a problem keeps apart, and how.

For one problem (:func:`collision_setup`): the robot's geometry
(:class:`~balance_opt.geometry.robot_geometry.RobotGeometry`, the task's ``collision.ignore``
pairs left out), the pairs already in contact at the initial configuration (left out of this
plan and reported: a constraint could not hold at ``t = 0``), the pairs the balance joints move
(the others are the mission's business: no plan of the balance arm changes them), and the rows
of the NLP (:class:`~balance_opt.geometry.shapes.ClearanceRows`: a soft minimum of fitted-shape
distances per body the balance joints move, at every collocation point, the point kernels'
last outputs). The constraint kind is :class:`~balance_opt.optimal.constraints.Collision`.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import casadi as cs
import numpy as np

from balance_opt.geometry.robot_geometry import Pair, RobotGeometry
from balance_opt.geometry.shapes import ClearanceRows, clearance_rows, moved_by

log = logging.getLogger(__name__)

#: A pair whose fitted shapes start closer than the margin plus this [m] gets a row of its own
#: (a shared row's soft minimum lies up to log(n) / BETA below its pairs).
ALONE_GAP = 0.01


@dataclass
class CollisionSetup:
    """The collision avoidance of one problem.

    Attributes:
        geometry: the robot's geometry.
        rows: the NLP's rows.
        pairs: the checked pairs the balance joints move (the ones the plan is held to).
        fixed_pairs: the checked pairs the balance joints do not move (reported only).
        initial_contacts: pairs in contact at the initial configuration, left out.
        initial_rows: the rows' values at the initial configuration [m].
        owner: the row of each pair of ``pairs`` (by pair index).
    """

    geometry: RobotGeometry
    rows: ClearanceRows
    pairs: list[Pair]
    fixed_pairs: list[Pair]
    initial_contacts: list[Pair]
    initial_rows: np.ndarray
    owner: dict[int, int]

    @property
    def key(self) -> str:
        """The structure's collision key (the rows' content key)."""
        return self.rows.key


def rows_function(geometry: RobotGeometry, rows: ClearanceRows) -> cs.Function:
    """``clearance(q_model) -> rows``: the rows as a function of the model joints' positions."""
    q = cs.SX.sym("q_model", len(geometry.moving_joints))
    return cs.Function("clearance_rows", [q], [rows.expressions(geometry, q)], {"cse": True})


def _moving_rows(geometry: RobotGeometry, rows: ClearanceRows) -> ClearanceRows:
    """``rows`` without the rows the balance joints cannot change (a link turning about its
    own axis of symmetry, its pairs with bodies the mission moves): constant rows in the NLP."""
    robot = geometry.robot
    q = cs.SX.sym("q", robot.n)
    E, e = robot.mimic_matrix
    values = rows.expressions(geometry, cs.DM(E) @ q + cs.DM(e))
    balance = q[robot.mission.dof :]
    keep = [k for k in range(values.numel()) if cs.depends_on(values[k], balance)]
    return dataclasses.replace(rows, rows=tuple(rows.rows[k] for k in keep))


def collision_setup(model, options, q0: np.ndarray) -> CollisionSetup | None:
    """The collision avoidance of a problem of ``model`` (a
    :class:`~balance_opt.optimal.model.PlannerModel`) starting at the arm configuration ``q0``;
    ``None`` when ``options.collision_avoidance`` is off or no pair involves the balance arm."""
    if not options.collision_avoidance:
        return None
    # the stages and refinements of one plan are variants of one problem: built once
    key = (options.collision_ignore, options.collision_margin, np.asarray(q0, float).tobytes())
    return model.collision_setups(key, lambda: _setup(model, options, q0))


def _setup(model, options, q0: np.ndarray) -> CollisionSetup | None:
    geometry = model.geometry(options.collision_ignore)
    robot = geometry.robot
    moved = moved_by(geometry, [robot.joint_names[i] for i in robot.balance_indices])
    contacts = geometry.contacts(q0)
    if contacts:
        log.warning(
            "%s: pairs in contact at the initial configuration, not checked in this plan: %s",
            robot.name,
            ", ".join(p.name for p in contacts),
        )
    touching = {p.index for p in contacts}
    pairs, fixed = [], []
    for p in geometry.pairs:
        if p.index in touching:
            continue
        (pairs if {geometry.body(p.first), geometry.body(p.second)} & moved else fixed).append(p)
    if not pairs:
        return None
    rows = clearance_rows(geometry, pairs, moved)
    # pairs whose shapes start closer than the margin get rows of their own, bounded below
    # their start: in a shared row they would lower the bound of every pair of their body
    E, e = robot.mimic_matrix
    shape_pairs, distances = rows.pair_distances(geometry)
    start = np.array(distances(E @ q0 + e)).ravel()
    alone = {p for p, d in zip(shape_pairs, start) if d < options.collision_margin + ALONE_GAP}
    rows = _moving_rows(geometry, clearance_rows(geometry, pairs, moved, alone))
    if not rows.rows:
        return None
    kept = [p for p in pairs if rows.row_of(p) is not None]
    fixed += [p for p in pairs if rows.row_of(p) is None]
    pairs = kept
    f = model.clearance_function(geometry, rows)
    initial = np.array(f(E @ q0 + e)).ravel()
    owner = {p.index: rows.row_of(p) for p in pairs}
    return CollisionSetup(geometry, rows, pairs, fixed, contacts, initial, owner)
