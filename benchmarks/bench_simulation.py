"""Wall time of the free-floating simulation: 10 s of the capture task's move on the Table 1
robot, RK4 at 1 kHz with PD tracking of all six joints (issue 5 target: <= 2 s), and variants.

Run: python benchmarks/bench_simulation.py [--repeat N]
Prints one row per configuration: median wall time over the repeats (integration, outputs
and total), the real-time factor (simulated time / wall time) and the run's accuracy.
"""

from __future__ import annotations

import argparse
import statistics
import time

from balance_opt.app.scenarios import capture_task
from balance_opt.dynamics.options import SimulationOptions
from balance_opt.dynamics.simulation import simulate

CASES = (
    ("RK4 1 kHz, PD, outputs every step", SimulationOptions(dt=1e-3, output_dt=None)),
    ("RK4 1 kHz, PD, outputs every 10 ms", SimulationOptions(dt=1e-3, output_dt=0.01)),
    (
        "RK4 1 kHz, computed torque",
        SimulationOptions(dt=1e-3, output_dt=None, controller="computed-torque"),
    ),
    ("DOPRI5 rtol 1e-10, PD, outputs 10 ms", SimulationOptions(integrator="dopri5")),
    (
        "DOPRI5 rtol 1e-8, PD, outputs 10 ms",
        SimulationOptions(integrator="dopri5", rtol=1e-8, atol=1e-10),
    ),
)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--repeat", type=int, default=5, help="runs per configuration (median reported)"
    )
    args = parser.parse_args(argv)
    sc = capture_task()
    simulate(
        sc.robot, sc.mission, sc.q_B0, SimulationOptions(output_dt=1.0)
    )  # warm up imports and caches

    header = (
        f"{'configuration':40s} {'steps':>6s} {'integr. s':>9s} {'outputs s':>9s} {'total s':>8s} "
        f"{'RTF':>6s} {'track err rad':>13s} {'mom. resid.':>11s}"
    )
    print(f"capture task, {sc.mission.duration:.0f} s simulated, median of {args.repeat} runs")
    print(header)
    print("-" * len(header))
    for name, opts in CASES:
        runs = []
        for _ in range(args.repeat):
            started = time.perf_counter()
            res = simulate(sc.robot, sc.mission, sc.q_B0, opts)
            runs.append((time.perf_counter() - started, res))
        total = statistics.median(r[0] for r in runs)
        res = runs[0][1]
        integration = statistics.median(r[1].info["wall_time_integration_s"] for r in runs)
        outputs = statistics.median(r[1].info["wall_time_outputs_s"] for r in runs)
        print(
            f"{name:40s} {res.info['steps']:6d} {integration:9.3f} {outputs:9.3f} {total:8.3f} "
            f"{res.t[-1] / total:6.1f} {res.max_tracking_error:13.2e} {res.momentum_residual.max():11.1e}"
        )


if __name__ == "__main__":
    main()
