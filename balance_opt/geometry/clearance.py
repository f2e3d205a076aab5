"""How close a motion brings the robot's bodies to each other, on the continuous motion
(``docs/collision.md``, "The clearance of a motion"): exact distances (coal) at samples and, in
between, conservative advancement (bodies move at most ``sum_j |dq_j| R_j``), intervals split
until each pair's bound is settled to :data:`RESOLUTION` (down to :data:`MIN_STEP`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
import pinocchio as pin

from balance_opt.geometry.robot_geometry import RobotGeometry

#: Precision of each pair's smallest distance on the continuous motion [m].
RESOLUTION = 1e-3
#: Pairs farther apart than this are only certified to stay beyond it [m].
WATCH = 0.1
#: Shortest interval the refinement splits [s].
MIN_STEP = 1e-6
#: Every pair's distance is computed at every this-many-th sample; the bound on the motion
#: decides where the samples in between are needed (far pairs rarely need any).
COARSE = 10


@dataclass(frozen=True)
class PairClearance:
    """One pair's smallest distance over a motion [m] (negative: penetration depth), when [s],
    and a ``lower_bound`` it stays above on the whole continuous motion [m]."""

    pair: str
    index: int
    distance: float
    time: float
    lower_bound: float


@dataclass(frozen=True)
class Penetration:
    """The first penetration: ``pair`` touches first at ``time`` [s] and goes ``depth`` [m]
    deep (its deepest over the motion)."""

    pair: str
    time: float
    depth: float


@dataclass(frozen=True)
class ClearanceReport:
    """The clearance of a motion (:func:`clearance`): every checked pair, the first penetration
    (or ``None``), the URDF elements the geometry came from and the exact distances computed."""

    pairs: tuple[PairClearance, ...]
    first_penetration: Penetration | None
    source: str
    evaluations: int

    @property
    def closest(self) -> PairClearance | None:
        """The pair that comes closest (``None`` without pairs)."""
        return min(self.pairs, key=lambda p: p.distance, default=None)

    @property
    def min_distance(self) -> float:
        """The smallest distance of any pair [m] (inf without pairs)."""
        closest = self.closest
        return closest.distance if closest is not None else float("inf")

    @property
    def collision_free(self) -> bool:
        return self.first_penetration is None and self.min_distance > 0.0

    def below(self, distance: float) -> list[PairClearance]:
        """The pairs that come closer than ``distance`` [m], closest first."""
        return sorted((p for p in self.pairs if p.distance < distance), key=lambda p: p.distance)

    def joined(self, other: ClearanceReport) -> ClearanceReport:
        """This report and ``other`` (of other pairs, or of a part of the motion) as one: every
        pair of both, the earlier penetration (a pair's ``index`` is its own geometry's)."""
        pens = [p for p in (self.first_penetration, other.first_penetration) if p is not None]
        return ClearanceReport(
            self.pairs + other.pairs,
            min(pens, key=lambda p: p.time, default=None),
            self.source,
            self.evaluations + other.evaluations,
        )

    def to_dict(self, closest: int = 5) -> dict:
        """Plain data for ``metrics.json``: minimum, first penetration, ``closest`` pairs."""
        best = sorted(self.pairs, key=lambda p: p.distance)[:closest]
        pen = self.first_penetration
        return {
            "min_distance_m": self.min_distance,
            "closest_pair": best[0].pair if best else None,
            "closest_time_s": best[0].time if best else None,
            "collision_free": self.collision_free,
            "first_penetration": None
            if pen is None
            else {"pair": pen.pair, "time_s": pen.time, "depth_m": pen.depth},
            "closest_pairs": [
                {
                    "pair": p.pair,
                    "distance_m": p.distance,
                    "time_s": p.time,
                    "lower_bound_m": p.lower_bound,
                }
                for p in best
            ],
            "pairs_checked": len(self.pairs),
            "geometry_source": self.source,
            "distance_evaluations": self.evaluations,
        }


def _lower(da, db, motion):
    """The smallest distance a pair can reach between two instants where it is ``da`` and
    ``db`` apart, its bodies moving by at most ``motion`` in between."""
    return np.where(np.abs(da - db) >= motion, np.minimum(da, db), 0.5 * (da + db - motion))


def _first_contact(distance, t, motion, until: float, tolerance: float = 1e-6) -> float:
    """The first time a pair touches (within ``tolerance``), at the latest ``until``, by
    conservative advancement from ``t[0]``."""
    k, tau = 0, float(t[0])
    d = distance(tau)
    for _ in range(100_000):  # converges geometrically; the bound only guards a stall
        if d <= tolerance or tau >= until:
            break
        while k < t.size - 2 and t[k + 1] <= tau:
            k += 1
        speed = motion(k, k + 1) / (t[k + 1] - t[k])
        step = d / speed if speed > 0.0 else np.inf
        # samples a hair apart (a closed-loop flight's, 1e-8 s apart where a re-plan takes
        # over) bound the speed so high that a step no longer moves tau: it stalled there for
        # the 100,000 rounds, minutes of distances, and gave its time as the contact's; the
        # interval's end is the next instant checked
        tau = float(t[k + 1]) if tau + step == tau else min(tau + step, float(t[k + 1]))
        d = distance(tau)
    return float(min(tau, until))


def _refine(geometry, index, items, configuration, state, limits) -> int:
    """Split the intervals ``items`` until each pair's bound is settled, updating ``state`` (best
    distance, its time, lower bound per pair, penetrations) in place; returns the distances
    computed. An item is ``(pair column, t_a, t_b, d_a, d_b, motion bound, i_a, i_b)``."""
    best, best_t, lower, first = state
    watch, t, motion = limits
    geom, gdata = geometry.geometry_model, geometry.geometry_data
    evaluations = 0
    while items:
        by_time: dict[float, list] = {}
        for item in items:
            ia, ib = item[6], item[7]
            tm = t[(ia + ib) // 2] if ib - ia > 1 else 0.5 * (item[1] + item[2])
            by_time.setdefault(float(tm), []).append(item)
        items = []
        for tm, group in sorted(by_time.items()):
            geometry.place(configuration(tm))
            for c, ta, tb, da, db, m, ia, ib in group:
                dm = pin.computeDistance(geom, gdata, int(index[c])).min_distance
                evaluations += 1
                if dm < best[c]:
                    best[c], best_t[c] = dm, tm
                if dm <= 0.0:
                    first.append((tm, c))
                if ib - ia > 1:
                    im = (ia + ib) // 2
                    halves = ((ta, tm, da, dm, motion(ia, im, c), ia, im),
                              (tm, tb, dm, db, motion(im, ib, c), im, ib))
                else:
                    halves = ((ta, tm, da, dm, 0.5 * m, ia, ib), (tm, tb, dm, db, 0.5 * m, ia, ib))
                for a, b, d1, d2, mh, i1, i2 in halves:
                    bound = float(_lower(d1, d2, mh))
                    if bound >= min(best[c], watch) - RESOLUTION or b - a <= MIN_STEP:
                        lower[c] = min(lower[c], bound)
                    else:
                        items.append((c, a, b, d1, d2, mh, i1, i2))
    return evaluations


def clearance(
    geometry: RobotGeometry,
    t,
    q,
    pairs: Sequence[int] | None = None,
    watch: float = WATCH,
) -> ClearanceReport:
    """The clearance of a motion of the robot: sample times ``t`` (T,), arm vectors ``q``
    (T, n); ``pairs`` (default all) farther than ``watch`` [m] are only certified to stay beyond
    it."""
    t = np.asarray(t, dtype=float).ravel()
    q = np.atleast_2d(np.asarray(q, dtype=float))
    if q.shape[0] != t.size:
        raise ValueError(f"{t.size} times but {q.shape[0]} configurations")
    chosen = geometry.pairs if pairs is None else [geometry.pairs[k] for k in pairs]
    if not chosen:
        return ClearanceReport((), None, geometry.source, 0)
    E, e = geometry.robot.mimic_matrix
    # the joints' travel from the first sample: a body moves at most its reach times it
    steps = np.abs(np.diff(q @ E.T + e, axis=0))
    travel = np.vstack([np.zeros((1, E.shape[0])), np.cumsum(steps, axis=0)])
    reach = geometry.reach
    coef = np.stack([reach[p.first] + reach[p.second] for p in chosen])  # (P, n_moving)

    def motion(i, j, c):
        return float((travel[j] - travel[i]) @ coef[c])

    geom, gdata = geometry.geometry_model, geometry.geometry_data
    model, data = geometry.model, geometry.data
    index = np.array([p.index for p in chosen], dtype=int)
    # every pair at every COARSE-th sample; the refinement splits at the samples in between
    coarse = np.unique(np.r_[np.arange(0, t.size, COARSE), t.size - 1])
    D = np.empty((coarse.size, index.size))
    for row, k in enumerate(coarse):
        pin.computeDistances(model, data, geom, gdata, geometry.robot.pin_q(q[k]))
        results = gdata.distanceResults
        D[row] = [results[int(i)].min_distance for i in index]
    evaluations = D.size
    best_k = D.argmin(axis=0)
    best = D[best_k, np.arange(index.size)]
    best_t = t[coarse[best_k]]
    lower = best.copy()
    neg = D <= 0.0
    first = [(t[coarse[np.argmax(neg[:, c])]], c) for c in range(index.size) if neg[:, c].any()]
    items = []  # see _refine
    target = np.minimum(best, watch) - RESOLUTION
    for r in range(coarse.size - 1):
        ia, ib = int(coarse[r]), int(coarse[r + 1])
        m = (travel[ib] - travel[ia]) @ coef.T
        lb = _lower(D[r], D[r + 1], m)
        for c in np.flatnonzero(lb < target):
            items.append((c, t[ia], t[ib], D[r, c], D[r + 1, c], m[c], ia, ib))
        lower = np.minimum(lower, np.where(lb >= target, lb, np.inf))

    def configuration(time):
        return np.array([np.interp(time, t, q[:, j]) for j in range(q.shape[1])])

    state = (best, best_t, lower, first)
    limits = (watch, t, motion)
    evaluations += _refine(geometry, index, items, configuration, state, limits)
    lower = np.minimum(lower, best)
    report = tuple(
        PairClearance(p.name, p.index, float(best[c]), float(best_t[c]), float(lower[c]))
        for c, p in enumerate(chosen)
    )
    penetration = None
    if first:
        # the earliest contact of each penetrating pair, found from the start by conservative
        # advancement (the refinement finds penetrations, not where they begin)
        contacts = []
        for c in sorted({c for _, c in first}):

            def distance(time, pair=int(index[c])):
                return geometry.distances(configuration(time), [pair])[0]

            until = min(tn for tn, k in first if k == c)
            contacts.append((_first_contact(distance, t, partial(motion, c=c), until), c))
        tp, c = min(contacts)
        penetration = Penetration(chosen[c].name, float(tp), float(-best[c]))
    return ClearanceReport(report, penetration, geometry.source, evaluations)
