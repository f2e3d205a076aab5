"""Time per evaluation of the base Jacobian ``J_base`` (its angular rows are ``(J_wM, J_wB)``),
side by side:

* the CasADi function ``base_jacobian`` (symbolic backend, as the planner uses it), one call
  from Python, and mapped over 1000 configurations (``fun.map(1000)``, serial and with 2
  threads), per configuration;
* the numeric path ``NumericMaps.base_jacobian`` (Pinocchio's ``A_G`` and a 6 x 6 solve);
* Pinocchio's own ``computeCentroidalMap`` alone, the floor of the numeric path.

Run: ``python benchmarks/bench_maps.py`` (one run, prints one table, times in microseconds:
the best of ``--repeat`` repeats).
"""

from __future__ import annotations

import argparse
import timeit

import casadi as cs
import numpy as np
import pinocchio as pin

from balance_opt.model.library import baxter_floating, paper_robot
from balance_opt.model.maps import NumericMaps
from balance_opt.model.symbolic import SymbolicMaps

N_MAP = 1000


def _best_us(stmt, number: int, repeat: int, per: int = 1) -> float:
    """Best time of ``repeat`` runs of ``number`` calls, per call and per ``per`` items [us]."""
    return min(timeit.repeat(stmt, number=number, repeat=repeat)) / number / per * 1e6


def bench_robot(robot, repeat: int, rng: np.random.Generator) -> dict[str, float]:
    maps = SymbolicMaps(robot)
    fun = maps.base_jacobian_fun()
    serial, threads = fun.map(N_MAP), fun.map(N_MAP, "thread", 2)
    numeric = NumericMaps(robot)
    Q = rng.uniform(robot.limits.lower, robot.limits.upper, size=(N_MAP, robot.n))
    Q_dm = cs.DM(Q.T)
    q = Q[0]
    q_pin = robot.pin_q(q)
    data = robot.model.createData()
    # the mapped functions must give the single-call results
    np.testing.assert_allclose(
        np.array(serial(Q_dm))[:, : robot.n], numeric.base_jacobian(q), rtol=0, atol=1e-9
    )
    return {
        "casadi single call": _best_us(lambda: fun(q), 2000, repeat),
        f"casadi map({N_MAP}) serial, per q": _best_us(lambda: serial(Q_dm), 5, repeat, N_MAP),
        f"casadi map({N_MAP}) 2 threads, per q": _best_us(lambda: threads(Q_dm), 5, repeat, N_MAP),
        "NumericMaps.base_jacobian": _best_us(lambda: numeric.base_jacobian(q), 2000, repeat),
        "pin.computeCentroidalMap alone": _best_us(
            lambda: pin.computeCentroidalMap(robot.model, data, q_pin), 2000, repeat
        ),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="timeit repeats (best is kept)")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    robots = {"paper (3+3)": paper_robot(), "baxter (7+7)": baxter_floating()}
    results = {name: bench_robot(robot, args.repeat, rng) for name, robot in robots.items()}
    rows = list(next(iter(results.values())))
    width = max(len(r) for r in rows)
    header = f"{'J_base per evaluation [us]':<{width}}" + "".join(f"{n:>16}" for n in results)
    print(header)
    print("-" * len(header))
    for row in rows:
        print(f"{row:<{width}}" + "".join(f"{results[n][row]:>16.2f}" for n in results))
    ratio = "NumericMaps / computeCentroidalMap"
    print(
        f"{ratio:<{width}}"
        + "".join(
            f"{results[n]['NumericMaps.base_jacobian'] / results[n]['pin.computeCentroidalMap alone']:>15.2f}x"
            for n in results
        )
    )


if __name__ == "__main__":
    main()
