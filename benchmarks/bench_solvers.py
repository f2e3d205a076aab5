"""NLP solvers on the optimal planner's problems: Ipopt with each linear solver the CasADi wheel
may carry (MUMPS, the default; SPRAL; HSL's MA27/MA57/MA86/MA97, which need the separately
licensed HSL library) and ``fatrop``, the structure-exploiting interior-point solver bundled
with CasADi, given the problem's stage structure.

Two problems of the default (peak) plan of the capture task: its first stage (the integral
objective on the inner stages' coarser grid, a quarter of ``--intervals``, from the analytic
guess) and its last (the exact epigraph, from the smooth stage's plan interpolated onto the
plan's grid, as the planner solves them). Every variant solves the same NLP from the same start:

* Ipopt runs on the planner's compiled NLP (``build_balance_nlp``, with the linear solver set
  through ``optimal.ipopt``);
* fatrop runs on the stage form of that NLP (:mod:`stage_form`: the rows reordered stage by
  stage and re-expressed so that each depends on one stage, with the structure declared:
  ``structure_detection: manual``), on CasADi's SX virtual machine (fatrop takes its derivatives
  from CasADi's own differentiation of the expression). So that the comparison is like for
  like, Ipopt + MUMPS also solves that stage form (``Ipopt + MUMPS, stage form``).

Printed per variant and problem: iterations, return status, the solve's wall time (median of
``--repeat``), the solver's own time (the wall time outside the NLP's function evaluations:
what a faster solver can save), the objective, and the same-plan check: the largest difference
of the decision vector from Ipopt/MUMPS's solution on the compiled NLP (``same`` below 1e-5).
A variant that cannot run prints its error in one line. Each variant runs in its own process
(a solver that crashes or hangs ends only its row).

    python benchmarks/bench_solvers.py [--intervals 100] [--repeat 3] [--timeout 900]
        [--only mumps fatrop:stages ...]

``--only fatrop:none`` and ``fatrop:auto`` try fatrop on the planner's NLP as it is (no
structure; CasADi's automatic detection, which needs the stage form's ordering and explicit
gap-closing rows, and refuses the planner's NLP).
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
TASK = ROOT / "examples" / "capture_task.yaml"
#: (kind, variant) in the table's order; MUMPS on the compiled NLP first: the reference.
VARIANTS = [("ipopt", ls) for ls in ("mumps", "spral", "ma27", "ma57", "ma86", "ma97")] + [
    ("ipopt-stages", "mumps"),
    ("fatrop", "stages"),
]
PROBLEMS = ("integral", "epigraph")
#: Largest decision-vector difference still called the same plan.
SAME_PLAN = 1e-5


def _problems(intervals: int, compile_kernels: bool, ipopt=None):
    """``{name: (problem, start, captured nlpsol input)}`` of the capture task's peak plan."""
    import casadi as cs

    from balance_opt.model.symbolic import SymbolicMaps
    from balance_opt.optimal.model import PlannerModel
    from balance_opt.optimal.solve import build_balance_nlp
    from balance_opt.tasks.task import load_task

    task = load_task(TASK)
    options = task.planner_options(ipopt)
    options = type(options)(**{**options.__dict__, "intervals": intervals})
    model = PlannerModel(
        task.robot, SymbolicMaps(task.robot, task.spec.robot.backend), compile=compile_kernels
    )
    captured, real = [], cs.nlpsol

    def spy(name, plugin, nlp, opts=None):
        captured.append(nlp)
        return real(name, plugin, nlp, opts or {})

    cs.nlpsol = spy
    try:
        peak = build_balance_nlp(model, task.mission, task.q_B0, options, robot=task.robot)
        integral, smooth = peak.stage("integral"), peak.stage("smooth")
    finally:
        cs.nlpsol = real
    # the starts the planner gives them (refine.plan_peak): the integral plan, then the smooth
    w_integral = _raw_solve(integral, integral.initial_guess("analytic"))
    sol = integral.unpack(w_integral)
    X, _ = smooth.unpack(smooth.initial_guess(sol)).points()
    smooth = smooth.with_bounds(peak_reference=max(float(np.linalg.norm(X[:3], axis=0).max()), 1e-4))
    w_smooth = _raw_solve(smooth, smooth.initial_guess(sol))
    return {
        "integral": (integral, integral.initial_guess("analytic"), captured[1]),
        "epigraph": (peak, peak.initial_guess(smooth.unpack(w_smooth)), captured[0]),
    }


def _raw_solve(problem, w0):
    out = problem.structure.solver(**_arguments(problem, w0))
    return np.array(out["x"]).ravel()


def _arguments(problem, w0) -> dict:
    return {
        "x0": w0,
        "p": problem.parameters,
        "lbx": problem.lbx,
        "ubx": problem.ubx,
        "lbg": problem.lbg,
        "ubg": problem.ubg,
    }


def _own_time(solver) -> float:
    """The solve's wall time outside the NLP's function evaluations [s]."""
    stats = solver.stats()
    if "fatrop" in stats:
        f = stats["fatrop"]
        return f["time_total"] - sum(v for k, v in f.items() if k.endswith("_time") and "eval" in k)
    evals = sum(v for k, v in stats.items() if k.startswith("t_wall_nlp_"))
    return stats["t_wall_total"] - evals


def _timed(solver, args: dict, repeat: int, back=lambda z: z) -> dict:
    walls, own, out = [], [], None
    for _ in range(repeat):
        start = time.perf_counter()
        out = solver(**args)
        walls.append(time.perf_counter() - start)
        own.append(_own_time(solver))
    stats = solver.stats()
    status = stats.get("return_status", "?")
    if not isinstance(status, str):  # fatrop: a number; CasADi's success flag says more
        status = "success" if stats.get("success") else f"failed (return flag {status})"
    return {
        "wall": statistics.median(walls),
        "own": statistics.median(own),
        "iterations": int(stats.get("iter_count", -1)),
        "status": status,
        "objective": float(out["f"]),
        "x": back(np.array(out["x"]).ravel()),
    }


def _solver_on_stage_form(kind: str, problem, captured):
    import casadi as cs
    from stage_form import stage_form

    from balance_opt.optimal.nlp import ipopt_options_for

    form = stage_form(problem, captured)
    ipopt = ipopt_options_for(problem.structure.key.objective, problem.options)  # the planner's
    if kind == "fatrop":
        opts = {"structure_detection": "manual", **form.structure, "print_time": False}
        opts["fatrop"] = {"print_level": 0, "tol": ipopt["tol"], "max_iter": 3000}
        if "mu_init" in ipopt:  # the epigraph stage's start (PEAK_IPOPT)
            opts["fatrop"]["mu_init"] = ipopt["mu_init"]
    else:
        opts = {"ipopt": ipopt, "print_time": False, "record_time": True}
    return cs.nlpsol("balance_stages", kind.split("-")[0], form.nlp, opts), form


def run_variant(kind: str, variant: str, intervals: int, repeat: int) -> dict:
    """Every problem of the table with one variant: ``{problem: row}``."""
    import casadi as cs

    start = time.perf_counter()
    ipopt = {"linear_solver": variant} if kind == "ipopt" else None
    problems = _problems(intervals, compile_kernels=kind == "ipopt", ipopt=ipopt)
    rows = {}
    for name, (problem, w0, captured) in problems.items():
        args = _arguments(problem, w0)
        del args["p"]
        if kind == "ipopt":
            args["p"] = problem.parameters
            rows[name] = _timed(problem.structure.solver, args, repeat)
        elif kind == "ipopt-stages" or variant == "stages":
            solver, form = _solver_on_stage_form(kind, problem, captured)
            args = {"x0": form.to_stages(w0), **form.bounds}
            rows[name] = _timed(solver, args, repeat, form.from_stages)
        else:  # fatrop on the planner's NLP as it is
            equality = list(np.asarray(problem.lbg) == np.asarray(problem.ubg))
            solver = cs.nlpsol(
                "balance_fatrop",
                "fatrop",
                captured,
                {
                    "expand": True,
                    "structure_detection": variant,
                    "equality": equality,
                    "fatrop": {"print_level": 0, "tol": 1e-8, "max_iter": 3000},
                },
            )
            rows[name] = _timed(solver, {**args, "p": problem.parameters}, repeat)
    rows["setup"] = time.perf_counter() - start
    return rows


def _child(queue, kind: str, variant: str, intervals: int, repeat: int) -> None:
    try:
        queue.put(run_variant(kind, variant, intervals, repeat))
    except Exception as exc:  # noqa: BLE001 - the benchmark reports every failure as a row
        message = " ".join(str(exc).split())
        queue.put({"error": f"{type(exc).__name__}: {message[:300]}"})


def run_isolated(kind: str, variant: str, intervals: int, repeat: int, timeout: float) -> dict:
    """One variant in its own process."""
    ctx = multiprocessing.get_context("spawn")
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(queue, kind, variant, intervals, repeat))
    proc.start()
    proc.join(timeout)
    if proc.is_alive():
        proc.terminate()
        proc.join()
        return {"error": f"no result within {timeout:.0f} s (stopped)"}
    if queue.empty():
        return {"error": f"the process ended with exit code {proc.exitcode} and no result"}
    return queue.get()


def _name(kind: str, variant: str) -> str:
    if kind == "ipopt":
        return f"Ipopt + {variant.upper()}"
    if kind == "ipopt-stages":
        return "Ipopt + MUMPS, stage form"
    return "fatrop, stage form" if variant == "stages" else f"fatrop ({variant})"


def print_table(results) -> None:
    print(
        "\n| solver | problem | iterations | status | solve [s] | solver's own [s] "
        "| objective | max diff. to MUMPS | same plan |"
    )
    print("| --- | --- | --- | --- | --- | --- | --- | --- | --- |")
    reference = results[0][2]
    for kind, variant, rows in results:
        name = _name(kind, variant)
        if "error" in rows:
            print(f"| {name} | - | failed: {rows['error']} | | | | | | |")
            continue
        for problem in PROBLEMS:
            row = rows[problem]
            if row["status"] == "Invalid_Option":  # refused before iterating
                print(f"| {name} | {problem} | | Invalid_Option (not available) | | | | | |")
                continue
            ref = reference.get(problem, {}).get("x")
            diff = float(np.abs(row["x"] - ref).max()) if ref is not None else float("nan")
            print(
                f"| {name} | {problem} | {row['iterations']} | {row['status']} "
                f"| {row['wall']:.3f} | {row['own']:.3f} | {row['objective']:.10g} "
                f"| {diff:.1e} | {'yes' if diff < SAME_PLAN else 'no'} |"
            )


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", type=int, default=100)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--timeout", type=float, default=900, help="per variant [s]")
    parser.add_argument("--only", nargs="+", help="only these variants (mumps, fatrop:stages)")
    args = parser.parse_args(argv)
    print(
        f"capture task, N = {args.intervals}, median of {args.repeat} solves, "
        f"{os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}"
    )
    variants = list(VARIANTS)
    if args.only:
        extra = [tuple(v.split(":")) for v in args.only if v.startswith("fatrop:")]
        variants = [(k, v) for k, v in variants if v in args.only or f"{k}:{v}" in args.only]
        variants += [kv for kv in extra if kv not in variants]
        if variants[0] != ("ipopt", "mumps"):  # the reference of the same-plan check
            variants.insert(0, ("ipopt", "mumps"))
    results = []
    for kind, variant in variants:
        rows = run_isolated(kind, variant, args.intervals, args.repeat, args.timeout)
        results.append((kind, variant, rows))
        print(f"  {_name(kind, variant)}: {rows.get('error') or 'done'}", flush=True)
    print_table(results)
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
