"""NLP solvers on the optimal planner's problem: Ipopt with each linear solver the CasADi wheel
may carry (MUMPS, the default; SPRAL; HSL's MA27/MA57/MA86/MA97, which need the separately
licensed HSL library) and ``fatrop``, the structure-exploiting interior-point solver bundled
with CasADi.

Every variant solves the same NLP of the paper task (same initial guess, parameters and
bounds). Printed per variant: the setup time (model, NLP and solver built, in a fresh process;
kernels from the cache), solve time (median of ``--repeat``;
wall and CPU), iterations, return status, objective, and the same-plan check: the largest
difference of the decision vector from Ipopt/MUMPS's solution (``same`` below 1e-6). A variant
that cannot run prints its error message in one line.

Ipopt runs on the planner's compiled NLP (``build_balance_nlp``, with the linear solver set
through ``optimal.ipopt``). fatrop gets the NLP expression the planner hands to Ipopt, rebuilt
on CasADi's SX virtual machine (fatrop differentiates the expression itself; the compiled
kernels carry no derivatives CasADi can use) and expanded, once with ``structure_detection:
none`` and once with ``auto`` (which needs the variables stage by stage, ``x0, u0, x1, ...``,
and gap-closing constraints ``x_{k+1} - F(x_k, u_k)``).

    python benchmarks/bench_solvers.py [--intervals 50] [--repeat 3] [--timeout 600] [--no-fatrop]
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PAPER_TASK = ROOT / "examples" / "capture_task.yaml"
#: Ipopt linear solvers tried (MUMPS first: the reference).
LINEAR_SOLVERS = ("mumps", "spral", "ma27", "ma57", "ma86", "ma97")
#: Largest decision-vector difference still called the same plan.
SAME_PLAN = 1e-6


def _planner(intervals: int, compile_kernels=True, ipopt=None):
    """``(nlp, solve arguments, captured nlpsol call)`` of the paper task at N = ``intervals``."""
    import casadi as cs

    from balance_opt.io.task import load_task
    from balance_opt.model.symbolic import SymbolicMaps
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.solve import build_balance_nlp

    task = load_task(PAPER_TASK)
    options = dataclasses.replace(task.planner_options(ipopt), intervals=intervals)
    model = PlannerModel(
        task.robot, SymbolicMaps(task.robot, task.spec.robot.backend), compile=compile_kernels
    )
    captured: dict = {}
    real = cs.nlpsol

    def spy(name, plugin, nlp, opts=None):
        captured.update(nlp=nlp, opts=opts or {})
        return real(name, plugin, nlp, opts or {})

    cs.nlpsol = spy
    try:
        nlp = build_balance_nlp(model, task.mission, task.q_B0, options, robot=task.robot)
    finally:
        cs.nlpsol = real
    w0 = nlp.initial_guess("analytic")
    args = {"x0": w0, "p": nlp.parameters, "lbx": nlp.lbx, "ubx": nlp.ubx}
    args.update(lbg=nlp.lbg, ubg=nlp.ubg)
    return nlp, args, captured


def _timed_solves(solver, args, repeat: int):
    walls, cpus, out = [], [], None
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        out = solver(**args)
        walls.append(time.perf_counter() - w0)
        cpus.append(time.process_time() - c0)
    stats = solver.stats()
    return {
        "wall": statistics.median(walls),
        "cpu": statistics.median(cpus),
        "iterations": int(stats.get("iter_count", -1)),
        "status": str(stats.get("return_status", stats.get("unified_return_status", "?"))),
        "objective": float(out["f"]),
        "x": np.array(out["x"]).ravel(),
    }


def ipopt_variant(intervals: int, linear_solver: str, repeat: int) -> dict:
    """Ipopt with ``linear_solver`` on the planner's compiled NLP."""
    start = time.perf_counter()
    nlp, args, _ = _planner(intervals, ipopt={"linear_solver": linear_solver})
    row = {"setup": time.perf_counter() - start}
    row.update(_timed_solves(nlp.structure.solver, args, repeat))
    return row


def fatrop_variant(intervals: int, detection: str, repeat: int) -> dict:
    """fatrop on the planner's NLP expression (SX kernels, expanded)."""
    import casadi as cs

    start = time.perf_counter()
    _, args, captured = _planner(intervals, compile_kernels=False)
    equality = list(np.asarray(args["lbg"]).ravel() == np.asarray(args["ubg"]).ravel())
    solver = cs.nlpsol(
        "balance_fatrop",
        "fatrop",
        captured["nlp"],
        {
            "expand": True,
            "structure_detection": detection,
            "equality": equality,
            "fatrop": {"print_level": 0, "tol": 1e-8, "max_iter": 3000},
        },
    )
    row = {"setup": time.perf_counter() - start}
    row.update(_timed_solves(solver, args, repeat))
    return row


def _child(queue, kind: str, intervals: int, variant: str, repeat: int) -> None:
    try:
        run = ipopt_variant if kind == "ipopt" else fatrop_variant
        queue.put(run(intervals, variant, repeat))
    except Exception as exc:  # noqa: BLE001 - the benchmark reports every failure as a row
        message = " ".join(str(exc).split())
        queue.put({"error": f"{type(exc).__name__}: {message[:300]}"})


def run_isolated(kind: str, intervals: int, variant: str, repeat: int, timeout: float) -> dict:
    """One variant in its own process (a solver that crashes or hangs ends only that row)."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(queue, kind, intervals, variant, repeat))
    proc.start()
    proc.join(timeout)
    if proc.is_alive():
        proc.terminate()
        proc.join()
        return {"error": f"no result within {timeout:.0f} s (stopped)"}
    if queue.empty():
        return {"error": f"the process ended with exit code {proc.exitcode} and no result"}
    return queue.get()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", type=int, default=50)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=600, help="per variant [s]")
    parser.add_argument("--no-fatrop", action="store_true")
    parser.add_argument(
        "--only", nargs="+", help="run only these variants (mumps, fatrop:auto, ...)"
    )
    args = parser.parse_args(argv)
    print(
        f"paper task, N = {args.intervals}, median of {args.repeat} solves, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}"
    )
    variants = [("ipopt", ls) for ls in LINEAR_SOLVERS]
    if not args.no_fatrop:
        variants += [("fatrop", "none"), ("fatrop", "auto")]
    if args.only:
        variants = [(k, v) for k, v in variants if v in args.only or f"{k}:{v}" in args.only]
    rows = []
    for kind, variant in variants:
        row = run_isolated(kind, args.intervals, variant, args.repeat, args.timeout)
        rows.append((kind, variant, row))
        print(f"  {kind} {variant}: {row.get('error') or 'done'}", flush=True)
    reference = rows[0][2].get("x")
    print(
        "\n| solver | setup [s] | solve wall [s] | solve CPU [s] | iterations | status "
        "| objective | max |x - x_mumps| | same plan |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    for kind, variant, row in rows:
        name = f"Ipopt + {variant.upper()}" if kind == "ipopt" else f"fatrop ({variant})"
        if "error" in row:
            print(f"| {name} | failed: {row['error']} | | | | | | | |")
            continue
        if row["status"] == "Invalid_Option":  # Ipopt refused the solver before iterating
            print(f"| {name} | {row['setup']:.2f} | | | | Invalid_Option (not available) | | | |")
            continue
        diff = (
            float(np.abs(row["x"] - reference).max())
            if reference is not None and row["x"].shape == reference.shape
            else float("nan")
        )
        print(
            f"| {name} | {row['setup']:.2f} | {row['wall']:.3f} | {row['cpu']:.3f} | "
            f"{row['iterations']} | {row['status']} | {row['objective']:.10g} | {diff:.2e} | "
            f"{'yes' if diff < SAME_PLAN else 'no'} |"
        )
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
