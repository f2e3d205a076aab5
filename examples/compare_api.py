"""The analytic law and the optimal planner compared through the Python API: the same as

    balance-opt compare examples/capture_task.yaml --output results/compare_api

Runs headless (figures are written, not shown). Usage:

    python examples/compare_api.py [TASK.yaml] [OUTPUT_DIR]
"""

import logging
import sys
from pathlib import Path

from balance_opt.app.pipeline import (
    plan_analytic,
    plan_mission_only,
    plan_optimal,
    run_task,
    simulate_result,
)
from balance_opt.io.task import load_task

HERE = Path(__file__).resolve().parent


def main() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    task_file = Path(sys.argv[1]) if len(sys.argv) > 1 else HERE / "capture_task.yaml"
    output = Path(sys.argv[2]) if len(sys.argv) > 2 else Path("results") / "compare_api"

    # 1. A task file, validated at the boundary: robot, arms, mission, limits, options.
    task = load_task(task_file)
    print(f"{task.name}: {task.robot!r}, mission {task.duration:g} s")

    # 2. Each step on its own: Phase I (mission arm alone), the analytic law, the optimal plan,
    #    and the forward-dynamics check of a plan. Each plan is a BalanceResult.
    reference = plan_mission_only(task)
    analytic = plan_analytic(task)
    optimal = plan_optimal(task, warm_start=analytic)  # raises SolverError if Ipopt fails
    simulated = simulate_result(task, optimal)
    print(f"{'':14} {'max drift':>10} {'final drift':>12} {'violations':>11}   [rad]")
    for result in (reference, analytic, optimal):
        print(
            f"{result.method:14} {result.max_drift:10.4g} {result.final_drift:12.4g} {len(result.violations):11d}"
        )
    print(f"{'optimal, sim.':14} {simulated.angle.max():10.4g} {simulated.angle[-1]:12.4g}")

    # 3. Or everything at once, with every output (CSV, NPZ, metrics.json, PNG, report.html).
    if output.exists() and any(output.iterdir()):
        sys.exit(f"{output} exists and is not empty; remove it or give another output directory")
    run = run_task(task, methods=("analytic", "optimal"), simulate=True, output_dir=output)
    print(f"report: {run.report}; solver failures: {run.failures or 'none'}")


if __name__ == "__main__":
    main()
