"""The paper's simulation study: Figs. 2-5 of a scenario, each plan checked by forward dynamics
(``docs/paper_fig5_study.md``), and ``balance-opt paper-figures``: the study written to an output
folder all-or-nothing, as :func:`balance_opt.app.pipeline.run_task` writes its outputs.

Fig. 3 replays each balance motion with the mission arm held: the motion is non-holonomic, so it
is not the negative of Fig. 2. A plan whose solver failed is still shown (its last iterate) and
flagged in the summary."""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.analytic.rollout import rollout
from balance_opt.app.models import ModelCache
from balance_opt.app.scenarios import Scenario, capture_task, paper_fig5
from balance_opt.app.task_run import METHODS, timed
from balance_opt.dynamics.options import SimulationOptions
from balance_opt.dynamics.simulation import SimulationResult, simulate, simulate_plan
from balance_opt.errors import InputError, SolverError
from balance_opt.interrupts import handling_signals
from balance_opt.motion.options import IntegrationOptions
from balance_opt.motion.replay import phase_one
from balance_opt.motion.result import BULKY_INFO_KEYS, BalanceResult
from balance_opt.optimal.options import PlannerOptions
from balance_opt.optimal.solve import build_balance_nlp
from balance_opt.report.output_dir import OutputFolder
from balance_opt.report.outputs import peak_reaction_torques, to_json
from balance_opt.report.plots import FORMATS, paper_figure_set
from balance_opt.tasks.task import Task

log = logging.getLogger(__name__)

#: Output spacing of the plans and of the simulations [s].
STUDY_OUTPUT_STEP = 0.01
FIGURE_STEMS = {
    "fig2": "fig2_attitude_mission_arm",
    "fig3": "fig3_attitude_balance_arm",
    "fig4": "fig4_reaction_torque",
    "fig5": "fig5_attitude_balanced",
}


@dataclass
class StudyResult:
    """Everything the study computed.

    Attributes:
        output_dir: where the figures and ``study.json`` are.
        plans: ``{method: BalanceResult}``, the balance plans (kinematic).
        mission_only: simulation of the mission arm alone (Fig. 2).
        mission_only_kinematic: kinematic replay of the same (Fig. 2, dashed).
        balance_only: ``{method: SimulationResult}``, balance arm alone (Fig. 3).
        balanced: ``{method: SimulationResult}``, both arms tracking the plan (Figs. 4, 5).
        figures: ``{"fig2": [png, pdf], ...}``.
        figure_objects: ``{"fig2": matplotlib Figure, ...}``.
        summary: plain-data figures of merit (also in ``study.json``).
    """

    output_dir: Path
    plans: dict[str, BalanceResult]
    mission_only: SimulationResult
    mission_only_kinematic: BalanceResult
    balance_only: dict[str, SimulationResult]
    balanced: dict[str, SimulationResult]
    figures: dict[str, list[Path]]
    figure_objects: dict[str, Any] = field(repr=False)
    summary: dict[str, Any]


def _plan(
    method: str,
    scenario: Scenario,
    law: BalanceLawOptions,
    planner: PlannerOptions,
    backend: str = "auto",
) -> tuple[BalanceResult, str]:
    """A balance plan and its status (``"ok"``, or the solver's failure status)."""
    robot, mission = scenario.robot, scenario.mission
    try:
        if method == "analytic":
            integration = IntegrationOptions(output_step=STUDY_OUTPUT_STEP)
            return rollout(robot, mission, scenario.q_B0, law, integration=integration), "ok"
        model = ModelCache().planner_model(robot, backend)
        return build_balance_nlp(model, mission, scenario.q_B0, planner).solve(), "ok"
    except SolverError as exc:
        if exc.result is None:
            raise
        log.warning("%s plan: %s; the study shows its last iterate", method, exc)
        return exc.result, str(exc.status)


def _simulation_summary(sim: SimulationResult) -> dict[str, Any]:
    return {
        "max_drift_rad": float(sim.angle.max()),
        "final_drift_rad": float(sim.angle[-1]),
        "peak_base_rate_rad_s": float(np.linalg.norm(sim.omega, axis=1).max()),
        "max_tracking_error_rad": sim.max_tracking_error,
        "max_relative_momentum_residual": float(sim.momentum_residual.max()),
        "peak_torque_on_base_Nm": peak_reaction_torques(sim),
        "wall_time_s": sim.info["wall_time_s"],
    }


def scenario_study(
    scenario: Scenario,
    output_dir: str | Path,
    *,
    methods: Sequence[str] = METHODS,
    simulation: SimulationOptions | None = None,
    law: BalanceLawOptions | None = None,
    planner: PlannerOptions | None = None,
    formats: Sequence[str] = FORMATS,
    backend: str = "auto",
) -> StudyResult:
    """Figs. 2-5 of one scenario, written to ``output_dir`` with ``study.json``.

    Args:
        methods: the balance plans to compute and overlay, among ``"analytic"`` and ``"optimal"``.
        simulation: simulator settings (default: RK4 at 1 ms, PD tracking, outputs every 10 ms).
        law: settings of the analytic law (default: the scenario's, else damped least squares).
        backend: symbolic backend of the optimal planner.

    Raises:
        InputError: an unknown method.
    """
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise InputError(f"study methods must be among {', '.join(METHODS)}, got {list(methods)}")
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    sim_opts = simulation or SimulationOptions(output_dt=STUDY_OUTPUT_STEP)
    law = law or scenario.law or BalanceLawOptions()
    planner = planner or PlannerOptions()
    robot, mission = scenario.robot, scenario.mission

    # Fig. 2: the mission arm alone, the balance arm held at its start
    with timed(f"{scenario.name}: forward-dynamics simulation of the mission arm alone (Fig. 2)"):
        mission_only = simulate(robot, mission, scenario.q_B0, sim_opts)
    kinematic = phase_one(robot, mission, scenario.q_B0, t_eval=mission_only.t)

    plans, balance_only, balanced, merits = {}, {}, {}, {}
    for method in methods:
        plan, status = _plan(method, scenario, law, planner, backend)
        plans[method] = plan
        balance_only[method], balanced[method] = _simulated(scenario, method, plan, sim_opts)
        merits[method] = {
            "status": status,
            "plan": plan.summary(),
            "limit_violations": [str(v) for v in plan.violations],
            "details": {k: v for k, v in plan.details().items() if k not in BULKY_INFO_KEYS},
            "balance_only": _simulation_summary(balance_only[method]),
            "balanced": _simulation_summary(balanced[method]),
        }

    figures, objects = paper_figure_set(
        output_dir, FIGURE_STEMS, formats, mission_only, kinematic, balance_only, balanced
    )
    summary = _summary(scenario, sim_opts, mission_only, merits, figures)
    (output_dir / "study.json").write_text(json.dumps(to_json(summary), indent=2))
    return StudyResult(
        output_dir,
        plans,
        mission_only,
        kinematic,
        balance_only,
        balanced,
        figures,
        objects,
        summary,
    )


def _summary(scenario: Scenario, sim_opts, mission_only, merits: dict, figures: dict) -> dict:
    """The content of ``study.json``: the scenario, the simulator, each plan's merits, the
    figures' files."""
    robot, mission = scenario.robot, scenario.mission
    return {
        "scenario": {
            "name": scenario.name,
            "robot": robot.name,
            "mission_start_rad": list(map(float, mission.start)),
            "mission_goal_rad": list(map(float, mission.end)),
            "duration_s": mission.duration,
            "balance_start_rad": scenario.q_B0.tolist(),
        },
        "simulation": {
            "integrator": sim_opts.integrator,
            "dt_s": sim_opts.dt,
            "controller": sim_opts.controller,
        },
        "mission_only": _simulation_summary(mission_only),
        "plans": merits,
        "figures": {k: [p.name for p in v] for k, v in figures.items()},
    }


def _simulated(scenario: Scenario, method: str, plan, sim_opts: SimulationOptions) -> tuple:
    """The forward-dynamics simulations of one plan: its balance motion with the mission arm
    held at its start (Fig. 3), and the whole plan (Figs. 4, 5)."""
    robot, mission = scenario.robot, scenario.mission
    name = f"{scenario.name}: forward-dynamics simulation of the {method} plan"
    with timed(f"{name}'s balance arm alone (Fig. 3)"):
        balance_only = simulate(robot, mission.start, plan, sim_opts)
    with timed(f"{name} (Figs. 4, 5)"):
        balanced = simulate_plan(robot, plan, sim_opts)
    log.info(
        "%s on %s: final drift %.3g rad planned, %.3g rad simulated; %d limit violations",
        method,
        scenario.name,
        plan.final_drift,
        balanced.angle[-1],
        len(plan.violations),
    )
    return balance_only, balanced


#: The parts of :func:`paper_study`: name, scenario, methods. Figs. 2-5 with the paper's law on
#: the reading where it works, and the law against the optimal plan on the hard case.
PAPER_PARTS = (
    ("paper_fig5", paper_fig5, ("analytic",)),
    ("capture_task", capture_task, METHODS),
)


@dataclass
class PaperStudy:
    """The parts of :func:`paper_study`.

    Attributes:
        output_dir: the study's folder; each part's figures are in a subfolder of its name.
        parts: ``{part name: StudyResult}``.
        figures: ``{"<part>/fig2": [png, pdf], ...}``, every figure file.
        summary: ``{part name: that part's summary}`` (also ``study.json``).
    """

    output_dir: Path
    parts: dict[str, StudyResult]
    figures: dict[str, list[Path]]
    summary: dict[str, Any]


def paper_study(
    output_dir: str | Path,
    *,
    scenario: Scenario | None = None,
    methods: Sequence[str] | None = None,
    **options,
) -> PaperStudy:
    """The paper's Figs. 2-5: by default each part of :data:`PAPER_PARTS` in its own subfolder
    of ``output_dir``; with ``scenario``, that scenario alone, in a subfolder of its name.

    Args:
        output_dir: folder of the study, created if missing; ``study.json`` there holds every
            part's summary.
        scenario: a scenario to study instead of the paper's parts.
        methods: plans to overlay (default: each part's; ``scenario``: both).
        options: ``simulation``, ``law``, ``planner``, ``formats``, ``backend`` of
            :func:`scenario_study`, for every part (default: each scenario's own law).

    Raises:
        InputError: an unknown method.
    """
    output_dir = Path(output_dir)
    parts = PAPER_PARTS if scenario is None else [(scenario.name, lambda: scenario, METHODS)]
    results = {
        name: scenario_study(
            make(), output_dir / name, methods=methods or default_methods, **options
        )
        for name, make, default_methods in parts
    }
    summary = {name: r.summary for name, r in results.items()}
    (output_dir / "study.json").write_text(json.dumps(to_json(summary), indent=2))
    figures = {f"{name}/{k}": v for name, r in results.items() for k, v in r.figures.items()}
    return PaperStudy(output_dir, results, figures, summary)


def paper_figures(
    folder: OutputFolder,
    task: Task | None = None,
    solver_options: Mapping[str, Any] | None = None,
    backend: str | None = None,
) -> list[Path]:
    """``balance-opt paper-figures``: the paper's study (:func:`paper_study`) written to
    ``folder`` all-or-nothing, as :func:`~balance_opt.app.pipeline.run_task` writes; with
    ``task``, Figs. 2-5 of that task (its robot, mission, balance start and options), both
    methods, in a subfolder of its name. ``backend`` defaults to the task's ``robot.backend``.

    Raises:
        KeyboardInterrupt: Ctrl-C or SIGTERM; nothing is written.
    """
    options = {"backend": backend or (task.spec.robot.backend if task is not None else "auto")}
    if task is not None:
        law = task.spec.analytic.law
        options.update(
            scenario=Scenario(task.robot, task.mission, task.q_B0, task.name, law),
            law=law,
            planner=task.planner_options(solver_options),
            simulation=task.spec.simulation,
        )
    elif solver_options:
        options["planner"] = PlannerOptions(ipopt=dict(solver_options))
    with handling_signals(), folder, timed("paper study (Figs. 2-5)"):
        study = paper_study(folder.staging, **options)
        files = [p for paths in study.figures.values() for p in paths]
        jsons = [folder.staging / name / "study.json" for name in study.parts]
        return [folder.final(p) for p in (*files, *jsons, folder.staging / "study.json")]
