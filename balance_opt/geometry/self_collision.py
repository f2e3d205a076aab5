"""Self-collision pairs of a robot without an SRDF, as MoveIt's setup assistant computes them,
and the SRDF that writes them down (``docs/collision.md``, "Which pairs are checked").

Besides the pairs of one body and of adjacent bodies (left out by
:class:`~balance_opt.geometry.robot_geometry.RobotGeometry` itself), a link pair is disabled

- ``"default"``: in contact in the reference pose: the arm joints at zero (inside their limits:
  :meth:`~balance_opt.model.robot.FloatingRobot.neutral`), the locked joints at the task's
  values (they are fixed in the robot's reduced model), and in at least :data:`DEFAULT` of the
  sampled configurations as well;
- ``"always"``: in contact in at least :data:`ALWAYS` of :data:`SAMPLES` configurations drawn
  uniformly inside the arm joints' limits (seeded: the same robot gives the same pairs);
- ``"near"``: of bodies one body apart (a joint's parent body and its child's child) and never
  more than :data:`NEAR` apart, in the reference pose and every sample: they meet at the body
  between them, as adjacent bodies meet at their joint (the UR5's wrist 1 and 3, forearm and
  wrist 2, base and upper arm, Baxter's shoulder and elbow, Talos's arm 5 and its wrist's force
  sensor: each disabled by the robot's own SRDF too).

A link pair is in contact when one of its objects' pairs is (exact distance <= 0, as the
clearance check counts it). The captured target's pairs are never disabled so.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Iterable, Mapping

import numpy as np
import pinocchio as pin

from balance_opt.model.capture import TARGET_LINK

#: Configurations sampled for the ``"always"`` rule (MoveIt's default is 10,000, which disable
#: the same pairs on Talos and Baxter at ten times the cost: docs/collision.md).
SAMPLES = 1000
#: Share of the samples a pair must be in contact in to be disabled as ``"always"`` (MoveIt's
#: default 95 %).
ALWAYS = 0.95
#: Share of the samples a pair in contact in the reference pose must be in contact in too, to
#: be disabled as ``"default"``. MoveIt disables every pair in contact there and counts on a
#: person reviewing the list in its setup assistant; here nobody does, and the reference pose
#: is also the default balance start. Pairs that overlap by design (Talos's and Baxter's wrist
#: and elbow hulls) are in contact in every sample; those the pose alone puts in contact
#: (Talos's hands in its thighs' hulls) in about 1 %: a share above one half tells one from
#: the other with a wide gap on both sides, and a pair kept so is checked (a start in contact
#: on it is refused) rather than silently dropped.
DEFAULT = 0.5
#: Seed of the samples.
SEED = 0
#: Largest distance [m] of a ``"near"`` pair: bodies one body apart that are never farther apart
#: than this cannot be kept clear by any motion (the users' robots' near pairs: at most 18 mm).
NEAR = 0.02
#: The SRDF ``reason`` of each reason a pair is left out (``"ignored"``: by the task, not
#: written).
SRDF_REASONS = {
    "same body": "Adjacent",
    "adjacent": "Adjacent",
    "default": "Default",
    "always": "Always",
    "near": "Adjacent",
    "srdf": "User",
}


def _link_pairs(pairs) -> dict[tuple[str, str], list[int]]:
    """The object pairs (indices) of each link pair, the captured target's left out."""
    out: dict[tuple[str, str], list[int]] = {}
    for p in pairs:
        if TARGET_LINK not in p.links:
            out.setdefault(tuple(sorted(p.links)), []).append(p.index)
    return out


def _distance(geometry, indices: Iterable[int]) -> float:
    """The smallest exact distance [m] of the object pairs ``indices`` where they are placed."""
    gm, gd = geometry.geometry_model, geometry.geometry_data
    return min(pin.computeDistance(gm, gd, int(k)).min_distance for k in indices)


def _in_contact(geometry, indices: Iterable[int]) -> bool:
    return _distance(geometry, indices) <= 0.0


def _one_apart(geometry, index: int) -> bool:
    """Whether the bodies of object pair ``index`` are one body apart (grandparent and child)."""
    pair = geometry.geometry_model.collisionPairs[index]
    a, b = geometry.body(pair.first), geometry.body(pair.second)
    parents = geometry.model.parents
    return (a > 0 and parents[parents[a]] == b) or (b > 0 and parents[parents[b]] == a)


def sample_configurations(robot, samples: int = SAMPLES, seed: int = SEED) -> np.ndarray:
    """``samples`` arm configurations (samples, n) uniform inside the position limits
    (continuous joints in [-pi, pi])."""
    low = np.maximum(robot.limits.lower, -np.pi)
    high = np.minimum(robot.limits.upper, np.pi)
    return np.random.default_rng(seed).uniform(low, high, size=(samples, robot.n))


def disabled_pairs(geometry, samples: int = SAMPLES) -> dict[tuple[str, str], str]:
    """The link pairs among ``geometry.pairs`` to disable, ``{(link, link): "default" |
    "always" | "near"}``.

    A pair is dropped from the ``"default"``/``"always"`` count at its first sample out of
    contact beyond the share its rule allows (:data:`DEFAULT` for a pair in contact in the
    reference pose, :data:`ALWAYS` for the others), and from the ``"near"`` one at its first
    sample farther than :data:`NEAR`, so that most pairs cost a few distances, not ``samples``.
    """
    by_link = _link_pairs(geometry.pairs)
    geometry.place(geometry.robot.neutral())
    reference = {links for links, idx in by_link.items() if _in_contact(geometry, idx)}
    allowed = {  # samples out of contact a pair may be in and still be disabled
        links: samples - math.ceil((DEFAULT if links in reference else ALWAYS) * samples)
        for links in by_link
    }
    alive = dict.fromkeys(by_link, 0)  # -> samples out of contact
    near = {
        links
        for links, idx in by_link.items()
        if _one_apart(geometry, idx[0]) and _distance(geometry, idx) <= NEAR
    }
    for q in sample_configurations(geometry.robot, samples):
        if not alive and not near:
            break
        geometry.place(q)
        for links in list(alive):
            if not _in_contact(geometry, by_link[links]):
                alive[links] += 1
                if alive[links] > allowed[links]:
                    del alive[links]
        near = {links for links in near if _distance(geometry, by_link[links]) <= NEAR}
    out = {links: "default" if links in reference else "always" for links in alive}
    out.update({links: "near" for links in near if links not in out})
    return out


def srdf_text(robot_name: str, disabled: Mapping[tuple[str, str], str]) -> str:
    """An SRDF whose ``<disable_collisions>`` are the link pairs ``disabled`` (``{(link, link):
    reason}``, :data:`SRDF_REASONS`; the task's own ignored pairs are not written)."""
    root = ET.Element("robot", name=robot_name)
    root.text = "\n  "
    written = sorted((links, r) for links, r in disabled.items() if r in SRDF_REASONS)
    for k, ((a, b), reason) in enumerate(written):
        item = ET.SubElement(
            root, "disable_collisions", link1=a, link2=b, reason=SRDF_REASONS[reason]
        )
        item.tail = "\n  " if k + 1 < len(written) else "\n"
    return ET.tostring(root, encoding="unicode") + "\n"
