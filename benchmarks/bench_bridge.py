"""The Pinocchio-CasADi bridge against adam: build and generation times, expression sizes and
evaluation speed of the symbolic maps, on the paper robot and on Baxter.

* the bridge program's build (wall and CPU time), from its cache record, or built anew in a
  temporary folder with ``--build`` (about 1.5 min of CPU);
* per robot: the time to generate its saved function (one run of the program) and to build
  ``SymbolicMaps`` with each backend;
* per robot and backend: the node count and evaluation time of ``centroidal_momentum_matrix``
  and of ``angular_jacobians``; the time to build the planner's point kernels
  (``PlannerModel.kernels``: value, Jacobian, gradient, Hessian, the NLP's nonlinear work),
  the Hessian kernel's instruction count and evaluation time (CasADi's virtual machine), and
  with ``--compile-kernels`` the time to compile the kernels to C in a temporary folder.
  Evaluation times are the best of ``--repeat`` repeats.

Run: ``python benchmarks/bench_bridge.py [--build] [--compile-kernels] [--repeat N]``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import timeit
from pathlib import Path

import numpy as np

from balance_opt.model import bridge
from balance_opt.model.library import baxter_floating, paper_robot
from balance_opt.model.symbolic import SymbolicMaps
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.nlp import point_kernels

BACKENDS = ("pinocchio", "adam")


def _best_us(stmt, number: int, repeat: int) -> float:
    """Best time of ``repeat`` runs of ``number`` calls, per call [us]."""
    return min(timeit.repeat(stmt, number=number, repeat=repeat)) / number * 1e6


def _timed(make):
    start = time.perf_counter()
    out = make()
    return out, time.perf_counter() - start


def bench_backend(robot, backend: str, repeat: int, compile_kernels: bool) -> dict[str, float]:
    maps, t_maps = _timed(lambda: SymbolicMaps(robot, backend=backend))
    cmm, jb = maps.centroidal_momentum_matrix_fun(), maps.base_jacobian_fun()
    rng = np.random.default_rng(0)
    q = rng.uniform(np.maximum(robot.limits.lower, -1), np.minimum(robot.limits.upper, 1))
    row = {
        "SymbolicMaps build [s]": t_maps,
        "A_G nodes": cmm.n_nodes(),
        "A_G eval [us]": _best_us(lambda: cmm(q), 2000, repeat),
        "J_base eval [us]": _best_us(lambda: jb(q), 1000, repeat),
    }
    model = PlannerModel(robot, maps=maps, compile=False, store=False)  # built, not loaded
    kernels, row["planner kernels build [s]"] = _timed(lambda: point_kernels(model))
    hess = kernels.hessian
    args = [rng.normal(size=hess.size_in(i)) for i in range(hess.n_in())]
    row["Hessian kernel instructions"] = hess.n_instructions()
    row["Hessian kernel eval [us]"] = _best_us(lambda: hess(*args), 200, repeat)
    if compile_kernels:
        with tempfile.TemporaryDirectory() as tmp:
            compiled = PlannerModel(robot, maps=maps, compile=True, cache_dir=tmp, store=False)
            row["kernels C compile [s]"] = point_kernels(compiled).compile_time
    return row


def bench_generation(robot) -> float:
    """Seconds to run the bridge program on ``robot`` (process start and loading included)."""
    bridge.function_path(robot, bridge.ensure_bridge().path).unlink(missing_ok=True)
    start = time.perf_counter()
    bridge.bridge_function(robot)
    return time.perf_counter() - start


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--build", action="store_true", help="build the bridge anew (minutes)")
    parser.add_argument("--repeat", type=int, default=5, help="timeit repeats (best is kept)")
    parser.add_argument(
        "--compile-kernels", action="store_true", help="also time the planner kernels' C compile"
    )
    args = parser.parse_args(argv)
    if args.build:
        with tempfile.TemporaryDirectory() as tmp:
            record = bridge.ensure_bridge(Path(tmp))
    else:
        record = bridge.ensure_bridge()
    print(
        f"bridge build: {record.wall_seconds:.0f} s wall, {record.cpu_seconds:.0f} s CPU "
        f"({'now' if record.built_now else 'from the cache record'})"
    )
    robots = {"paper": paper_robot(), "baxter": baxter_floating()}
    results, generation = {}, {}
    for name, robot in robots.items():
        generation[name] = bench_generation(robot)
        for backend in BACKENDS:
            results[f"{name} {backend}"] = bench_backend(
                robot, backend, args.repeat, args.compile_kernels
            )
    print("function generation [s]: " + ", ".join(f"{n} {t:.2f}" for n, t in generation.items()))
    rows = list(next(iter(results.values())))
    width = max(len(r) for r in rows)
    print(f"{'':<{width}}" + "".join(f"{c:>18}" for c in results))
    for row in rows:
        print(f"{row:<{width}}" + "".join(f"{results[c][row]:>18.4g}" for c in results))


if __name__ == "__main__":
    main()
