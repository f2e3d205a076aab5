"""The smallest exact distance between a box or cone fixed on the base and an arm's links over a plan,
computed apart from balance-opt's geometry and clearance code: the URDF's collision geometry
loaded by Pinocchio, the box and the distances by coal, at dense samples of the plan's CSV
(its joint motion interpolated linearly). Prints the smallest distance, where and when.

    python benchmarks/keep_out_distance.py results/capture_keep_out/optimal.csv \
        --center -0.25 0.4 0.85 --size 0.4 0.2 0.3 --arm balance_
    python benchmarks/keep_out_distance.py PLAN.csv --cone -0.25 0.25 0.5 0 1 1 0.3 1.0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import coal
import numpy as np
import pinocchio as pin

URDF = Path(__file__).resolve().parent.parent / "urdf" / "paper_robot.urdf"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("csv", help="a plan's CSV (time and one column per joint)")
    parser.add_argument("--urdf", default=str(URDF))
    parser.add_argument("--center", type=float, nargs=3, help="the box's centre [m], base frame")
    parser.add_argument("--size", type=float, nargs=3, help="the box's sides [m]")
    parser.add_argument(
        "--cone", type=float, nargs=8, help="apex (3) [m], axis (3), half angle [rad], length [m]"
    )
    parser.add_argument("--arm", default="balance_", help="prefix of the arm's link names")
    parser.add_argument("--step", type=float, default=2e-4, help="sample spacing [s]")
    args = parser.parse_args()
    if args.cone is None and (args.center is None or args.size is None):
        parser.error("give the zone: --center and --size for a box, or --cone")

    data = np.genfromtxt(args.csv, delimiter=",", names=True)
    model = pin.buildModelFromUrdf(args.urdf)  # fixed base: distances to the base do not
    geom = pin.buildGeomFromUrdf(model, args.urdf, pin.COLLISION)  # depend on its pose
    pdata, gdata = model.createData(), pin.GeometryData(geom)
    t = np.arange(0.0, data["time"][-1] + 1e-12, args.step)
    columns = {model.names[j]: model.joints[j].idx_q for j in range(1, model.njoints)}
    q = np.zeros((t.size, model.nq))
    for name, i in columns.items():
        q[:, i] = np.interp(t, data["time"], data[name])
    if args.cone is None:
        zone, what = coal.Box(*args.size), "box"
        zone_pose = coal.Transform3s(np.eye(3), np.array(args.center))
    else:  # coal's cone: centred, apex at +length / 2 on its z axis
        apex, axis, half, length = args.cone[:3], args.cone[3:6], args.cone[6], args.cone[7]
        z = -np.asarray(axis) / np.linalg.norm(axis)
        x = np.cross(np.eye(3)[int(np.argmin(np.abs(z)))], z)
        x /= np.linalg.norm(x)
        R = np.column_stack([x, np.cross(z, x), z])
        zone, what = coal.Cone(length * np.tan(half), length), "cone"
        zone_pose = coal.Transform3s(R, np.asarray(apex) - 0.5 * length * z)
    links = [
        (k, o) for k, o in enumerate(geom.geometryObjects)
        if model.frames[o.parentFrame].name.startswith(args.arm)
    ]  # fmt: skip
    request, result = coal.DistanceRequest(), coal.DistanceResult()
    best = (np.inf, None, None)
    for tk, qk in zip(t, q):
        pin.updateGeometryPlacements(model, pdata, geom, gdata, qk)
        for k, o in links:
            result.clear()
            M = gdata.oMg[k]
            pose = coal.Transform3s(M.rotation, M.translation)
            d = coal.distance(o.geometry, pose, zone, zone_pose, request, result)
            if d < best[0]:
                best = (d, model.frames[o.parentFrame].name, tk)
    print(
        f"{args.csv}: {t.size} samples every {args.step * 1e3:g} ms; smallest distance of the "
        f"{what} and the {args.arm}* links: {best[0]:.4f} m ({best[1]}, t = {best[2]:.4f} s)"
    )


if __name__ == "__main__":
    main()
