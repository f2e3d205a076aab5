"""Self-collision pairs of a robot without an SRDF, as MoveIt's setup assistant computes them,
and the SRDF that writes them down (``docs/collision.md``, "Which pairs are checked").

Besides the pairs of one body and of adjacent bodies (left out by
:class:`~balance_opt.geometry.robot_geometry.RobotGeometry` itself), a link pair is disabled

- ``"default"``: in contact in the reference pose: the arm joints at zero (inside their limits:
  :meth:`~balance_opt.model.robot.FloatingRobot.neutral`), the locked joints at the task's
  values (they are fixed in the robot's reduced model), and in at least :data:`DEFAULT` of the
  sampled configurations as well;
- ``"always"``: in contact in at least :data:`ALWAYS` of :data:`SAMPLES` configurations drawn
  uniformly inside the arm joints' limits (seeded: the same robot gives the same pairs).

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
#: The SRDF ``reason`` of each reason a pair is left out (``"ignored"``: by the task, not
#: written).
SRDF_REASONS = {
    "same body": "Adjacent",
    "adjacent": "Adjacent",
    "default": "Default",
    "always": "Always",
    "srdf": "User",
}


def _link_pairs(pairs) -> dict[tuple[str, str], list[int]]:
    """The object pairs (indices) of each link pair, the captured target's left out."""
    out: dict[tuple[str, str], list[int]] = {}
    for p in pairs:
        if TARGET_LINK not in p.links:
            out.setdefault(tuple(sorted(p.links)), []).append(p.index)
    return out


def _in_contact(geometry, indices: Iterable[int]) -> bool:
    gm, gd = geometry.geometry_model, geometry.geometry_data
    return any(pin.computeDistance(gm, gd, int(k)).min_distance <= 0.0 for k in indices)


def sample_configurations(robot, samples: int = SAMPLES, seed: int = SEED) -> np.ndarray:
    """``samples`` arm configurations (samples, n) uniform inside the position limits
    (continuous joints in [-pi, pi])."""
    low = np.maximum(robot.limits.lower, -np.pi)
    high = np.minimum(robot.limits.upper, np.pi)
    return np.random.default_rng(seed).uniform(low, high, size=(samples, robot.n))


def disabled_pairs(geometry, samples: int = SAMPLES) -> dict[tuple[str, str], str]:
    """The link pairs among ``geometry.pairs`` to disable, ``{(link, link): "default" |
    "always"}``.

    A pair is dropped from the count at its first sample out of contact beyond the share its
    rule allows (:data:`DEFAULT` for a pair in contact in the reference pose, :data:`ALWAYS`
    for the others), so that most pairs cost a few distances, not ``samples``.
    """
    by_link = _link_pairs(geometry.pairs)
    geometry.place(geometry.robot.neutral())
    reference = {links for links, idx in by_link.items() if _in_contact(geometry, idx)}
    allowed = {  # samples out of contact a pair may be in and still be disabled
        links: samples - math.ceil((DEFAULT if links in reference else ALWAYS) * samples)
        for links in by_link
    }
    alive = dict.fromkeys(by_link, 0)  # -> samples out of contact
    for q in sample_configurations(geometry.robot, samples):
        if not alive:
            break
        geometry.place(q)
        for links in list(alive):
            if not _in_contact(geometry, by_link[links]):
                alive[links] += 1
                if alive[links] > allowed[links]:
                    del alive[links]
    return {links: "default" if links in reference else "always" for links in alive}


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
