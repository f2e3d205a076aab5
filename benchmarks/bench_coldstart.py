"""Cold and warm first optimal plans: the time a user waits for the first plan of a robot.

For each task (the paper robot, Baxter 7+7 and Talos 7+7 arm joints), in a fresh temporary
cache folder that holds only the Pinocchio-CasADi bridge program (built once per machine, like
a compiled wheel: not part of a robot's cold start):

* **cold**: a new process loads the task and plans with the optimal method. It builds the
  robot's symbolic model, saves it to the cache, starts the C compilation of the point kernels
  as its own child process, solves with the kernels on CasADi's virtual machine meanwhile, and
  waits for the compiler before it returns (nothing outlives the command);
* **warm**: a new process plans the same task again: the model comes from the cache, the
  kernels from the compiled library.

Wall and CPU times are those of the whole process, imports and the compiler child included
(its wall time is read from the library's record). With ``--wait`` a third column times the
cold plan compiling the kernels before it solves. The load average is printed: on a loaded
machine wall times grow, CPU times much less.

The table also replaces the ``coldstart`` section of ``docs/performance.md``.

Run: ``python benchmarks/bench_coldstart.py [TASK ...] [--wait] [--no-doc]`` (default: the
three example tasks).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from perf_doc import write_section

from balance_opt.model.bridge import BridgeUnavailable, ensure_bridge
from balance_opt.optimal.codegen import wait_for_library

ROOT = Path(__file__).resolve().parent.parent
TASKS = (
    ROOT / "examples" / "capture_task.yaml",
    ROOT / "examples" / "baxter_floating.yaml",
    ROOT / "examples" / "talos_arms.yaml",
)
#: The child process: load the task, plan it with the optimal method, print what happened.
CHILD = """
import json, sys, time
start = time.perf_counter()
from balance_opt.app.pipeline import plan_optimal
from balance_opt.tasks.task import load_task
from balance_opt.app.models import ModelCache
task = load_task(sys.argv[1])
# "wait": compile the kernels before solving; "auto": compile beside the solve
models = ModelCache(compile=True if sys.argv[2] == "wait" else "auto")
result = plan_optimal(task, models=models)
info = result.info
print(json.dumps({
    "plan_wall": time.perf_counter() - start,
    "iterations": info.get("total_iterations", info["iterations"]),
    "kernels": info["kernels"],
    "final_drift": result.final_drift,
    "robot_joints": int(task.robot.n),
}))
"""


def _children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_plan(task: Path, cache: Path, mode: str) -> dict:
    """One planning process; its wall and CPU time [s] and what it printed."""
    env = dict(os.environ, BALANCE_OPT_CACHE=str(cache))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    start, cpu0 = time.perf_counter(), _children_cpu()
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(task), mode],
        capture_output=True,
        text=True,
        env=env,
        check=False,
    )
    wall, cpu = time.perf_counter() - start, _children_cpu() - cpu0
    if proc.returncode != 0:
        raise RuntimeError(f"planning {task.name} failed:\n{proc.stderr[-2000:]}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    return {"wall": wall, "cpu": cpu, **out}


def fresh_cache(bridge_program: Path | None) -> Path:
    """A temporary cache folder holding only the bridge program (a per-machine installation)."""
    folder = Path(tempfile.mkdtemp(prefix="balance-opt-coldstart-"))
    if bridge_program is not None:
        target = folder / "pinocchio-bridge"
        target.mkdir()
        for path in (bridge_program, bridge_program.with_suffix(".json")):
            shutil.copy2(path, target / path.name)
    return folder


def bench(name: str, task: Path, bridge_program: Path | None, wait: bool) -> dict:
    row = {"load": os.getloadavg()[0]}
    cache = fresh_cache(bridge_program)
    try:
        row["cold"] = run_plan(task, cache, "auto")
        library = row["cold"]["kernels"]["library"]
        compiled = row["cold"]["kernels"]["compiled"]
        record = None if compiled or not library else wait_for_library(library)
        row["compile"] = float(record["compile_seconds"]) if record else float("nan")
        row["warm"] = run_plan(task, cache, "auto")
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    if wait:
        cache = fresh_cache(bridge_program)
        try:
            row["wait"] = run_plan(task, cache, "wait")
        finally:
            shutil.rmtree(cache, ignore_errors=True)
    return row


def _kernels(run: dict) -> str:
    return "C" if run["kernels"]["compiled"] else "VM"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tasks", nargs="*", type=Path, default=list(TASKS))
    parser.add_argument(
        "--wait", action="store_true", help="also time a cold plan that waits for the compiler"
    )
    parser.add_argument("--no-doc", action="store_true", help="do not write docs/performance.md")
    args = parser.parse_args()
    try:
        bridge_program = ensure_bridge().path
    except BridgeUnavailable:
        bridge_program = None  # the adam backend
    load = os.getloadavg()[0]
    print(f"CPU cores: {os.cpu_count()}; times of whole processes [s]; load = 1-min load average")
    header = (
        "| task | robot joints | load | cold wall | cold CPU | kernels | Ipopt iter | "
        "compile wall | warm wall | warm CPU | kernels | cold/warm wall |"
    )
    if args.wait:
        header += " cold, waiting for compiler: wall | CPU |"
    lines = [header, "|" + " --- |" * (header.count("|") - 1)]
    print("\n".join(lines))
    for task in args.tasks:
        r = bench(task.stem, task.resolve(), bridge_program, args.wait)
        cold, warm = r["cold"], r["warm"]
        line = (
            f"| {task.stem} | {cold['robot_joints']} | {r['load']:.1f} | {cold['wall']:.1f} | "
            f"{cold['cpu']:.1f} | {_kernels(cold)} | {cold['iterations']} | {r['compile']:.1f} | "
            f"{warm['wall']:.1f} | {warm['cpu']:.1f} | {_kernels(warm)} | "
            f"{cold['wall'] / warm['wall']:.2f} |"
        )
        if args.wait:
            line += f" {r['wait']['wall']:.1f} | {r['wait']['cpu']:.1f} |"
        lines.append(line)
        print(line, flush=True)
    if not args.no_doc:
        command = " ".join(["python benchmarks/bench_coldstart.py", *sys.argv[1:]])
        print(f"wrote {write_section('coldstart', command, lines, load)}")


if __name__ == "__main__":
    main()
