"""Speed of the optimal balance planner on the capture task (Hermite-Simpson).

For N = 50, 100, 200, 400, 800 intervals, in one warm process: the NLP build time (first build
of that N; later builds of the same N reuse the compiled structure), the Ipopt solve time and
iterations (every Ipopt solve of the plan: the peak objective's three stages) and the time per
iteration, the initial-guess and re-simulation times, the total
(build + guess + solve, and with the re-simulation) and the re-simulated maximum drift.

The per-robot model (symbolic kernels, built once per robot and reused for every N) is timed
separately, and so is the one-time compilation of its kernels to C (0 when the shared library
is already in the cache folder; ``--cold`` compiles into a fresh temporary folder to measure it).

Run: ``python benchmarks/bench_planner.py`` (``--help`` for options). Times are wall times [s],
the median of ``--repeat`` solves.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

from balance_opt.app.scenarios import capture_task
from balance_opt.optimal.model import PlannerModel
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp

INTERVALS = (50, 100, 200, 400, 800)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--intervals", type=int, nargs="+", default=list(INTERVALS))
    parser.add_argument("--repeat", type=int, default=3, help="solves per N (median kept)")
    parser.add_argument("--guess", default="analytic", choices=("analytic", "rest"))
    parser.add_argument(
        "--compile",
        default="auto",
        choices=("auto", "yes", "no"),
        help="compile the kernels to C (auto: if a C compiler is found)",
    )
    parser.add_argument("--cold", action="store_true", help="compile into a fresh cache folder")
    args = parser.parse_args(argv)
    compile_flag = {"auto": "auto", "yes": True, "no": False}[args.compile]

    scenario = capture_task()
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        model = PlannerModel(
            scenario.robot, compile=compile_flag, cache_dir=tmp if args.cold else None
        )
        kernels = model.kernels("acceleration")
        model_time = time.perf_counter() - start
        print(
            f"capture task, {scenario.mission.duration:g} s, Hermite-Simpson, "
            f"control: acceleration, guess: {args.guess}"
        )
        print(
            f"per-robot model (symbolic kernels, once per robot): {model_time - kernels.compile_time:.3f} s; "
            f"kernels {'compiled to C' if kernels.compiled else 'on the CasADi VM'}"
            + (
                f", first-time compilation {kernels.compile_time:.1f} s"
                if kernels.compile_time
                else " (loaded from the cache)"
                if kernels.compiled
                else ""
            )
        )
        # warm the process (imports, Ipopt, Pinocchio) on a small problem
        build_balance_nlp(
            model, scenario.mission, scenario.q_B0, PlannerOptions(intervals=10)
        ).solve(args.guess)

        header = (
            f"{'N':>5} {'build':>7} {'guess':>7} {'solve':>7} {'iters':>6} {'per iter':>9} "
            f"{'total':>7} {'resim':>7} {'+resim':>7} {'max drift':>10} {'status':>16}"
        )
        print(header)
        print("-" * len(header))
        for N in args.intervals:
            options = PlannerOptions(intervals=N)
            start = time.perf_counter()
            nlp = build_balance_nlp(model, scenario.mission, scenario.q_B0, options)
            build = time.perf_counter() - start
            runs = [nlp.solve(args.guess) for _ in range(args.repeat)]
            walls = [r.info["wall_time_s"] for r in runs]
            # every Ipopt solve of the plan (the peak objective's stages, refinement)
            solve = statistics.median(r.info["total_solve_time_s"] for r in runs)
            guess = statistics.median(w["guess"] for w in walls)
            resim = statistics.median(w["resimulate"] for w in walls)
            result = runs[0]
            iters = result.info["total_iterations"]
            total = build + guess + solve
            print(
                f"{N:>5} {build:>7.3f} {guess:>7.3f} {solve:>7.3f} {iters:>6d} {solve / max(iters, 1) * 1e3:>7.2f}ms "
                f"{total:>7.3f} {resim:>7.3f} {total + resim:>7.3f} {result.max_drift:>10.5f} "
                f"{result.info['status']:>16}"
            )


if __name__ == "__main__":
    main()
