"""Self-collision pairs computed without an SRDF (issue 34): their cost and how they depend on
the number of samples, on the example robots that ship an SRDF (Talos 7 + 7 with legs, torso,
head and grippers locked; Baxter), their SRDF set aside as if copied out of their package.

For each robot and sample count: the link pairs left after same body and adjacency, those
disabled in the reference pose (``default``), in nearly every sampled configuration
(``always``) and one body apart never 2 cm clear (``near``), whether the disabled set is the one of MoveIt's default count (10,000), the pairs
the shipped SRDF also disables, and the wall time of the computation (the best of
``--repeat``). Run: ``python benchmarks/bench_self_collision.py [--repeat 3]``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from balance_opt.geometry import self_collision
from balance_opt.geometry.robot_geometry import RobotGeometry, default_srdf
from balance_opt.tasks.task import load_task

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"
COUNTS = (250, 1000, 10_000)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(
        "| robot | link pairs | samples | default | always | near | same as 10,000 "
        "| also in its SRDF | time [s] |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in ("talos_arms", "baxter_floating"):
        task = load_task(EXAMPLES / f"{name}.yaml")
        bare = RobotGeometry(task.robot, disabled={})
        links = {tuple(sorted(p.links)) for p in bare.pairs}
        shipped = RobotGeometry(task.robot)  # the SRDF beside the URDF
        assert shipped.srdf == default_srdf(Path(task.robot.source))
        in_srdf = {k for k, r in shipped.ignored.items() if r == "srdf"}
        found, times = {}, {}
        for count in COUNTS:
            best = float("inf")
            for _ in range(args.repeat if count < 10_000 else 1):
                start = time.perf_counter()
                found[count] = self_collision.disabled_pairs(bare, count)
                best = min(best, time.perf_counter() - start)
            times[count] = best
        for count in COUNTS:
            d = found[count]
            n = {r: sum(v == r for v in d.values()) for r in ("default", "always", "near")}
            same = "yes" if d == found[10_000] else "no"
            print(
                f"| {name} | {len(links)} | {count} | {n['default']} | {n['always']} "
                f"| {n['near']} | {same} "
                f"| {len(set(d) & in_srdf)} of {len(d)} | {times[count]:.2f} |"
            )


if __name__ == "__main__":
    main()
