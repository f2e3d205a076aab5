"""The analytic law and the optimal planner compared through the Python API: the same as

    balance-opt compare examples/capture_task.yaml --output results/compare_api

Each plan is computed once: the steps below, then ``run_task`` writes every output from them.
Runs headless (figures are written, not shown). Usage:

    python examples/compare_api.py [TASK.yaml] [OUTPUT_DIR]
"""

import logging
import sys
from pathlib import Path

import balance_opt as bo
from balance_opt.report.output_dir import OutputFolder

HERE = Path(__file__).resolve().parent


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    task_file = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "capture_task.yaml"
    output = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("results") / "compare_api"

    # 1. A task file, validated at the boundary: robot, arms, mission, limits, options.
    task = bo.load_task(task_file)
    print(f"{task.name}: {task.robot!r}, mission {task.duration:g} s")

    # The output folder is checked and locked before anything is computed: one that exists and
    # is not empty is refused at once (OutputFolder(output, force=True) replaces it, once the
    # new results are complete). It is written when this block ends without error.
    with OutputFolder(output) as folder:
        # 2. Each step on its own: Phase I (mission arm alone), the analytic law, the optimal
        #    plan, and the forward-dynamics check of each plan. Each plan is a BalanceResult.
        plans = {"mission-only": bo.plan_mission_only(task), "analytic": bo.plan_analytic(task)}
        # raises SolverError if Ipopt fails (its .result holds the last iterate)
        plans["optimal"] = bo.plan_optimal(task, warm_start=plans["analytic"])
        simulations = {name: bo.simulate(task, plan) for name, plan in plans.items()}
        print(plans["optimal"])  # a short summary: drift, rates, limits, solver status
        print(f"{'':14} {'max drift':>10} {'final drift':>12} {'violations':>11}   [rad]")
        for name, result in plans.items():
            drift, final = result.max_drift, result.final_drift
            print(f"{name:14} {drift:10.4g} {final:12.4g} {len(result.violations):11d}")
            sim = simulations[name]
            print(f"{'  simulated':14} {sim.angle.max():10.4g} {sim.angle[-1]:12.4g}")

        # 3. Every output (CSV, NPZ, metrics.json, PNG, report.html) from the plans above:
        #    nothing is planned or simulated again.
        run = bo.run_task(
            task, simulate=True, output_dir=folder, plans=plans, simulations=simulations
        )
    print(f"report: {run.report}; solver failures: {run.failures or 'none'}")


if __name__ == "__main__":
    try:
        main()
    except bo.BalanceOptError as exc:
        sys.exit(f"compare_api: {exc}")
