"""Choosing the symbolic backend: ``robot.backend`` in the task, ``--backend`` on the command
line, passed to the planner model's symbolic maps, and shown by ``balance-opt inspect``."""

import pytest

from balance_opt.app import pipeline
from balance_opt.app.models import ModelCache
from balance_opt.cli import main
from balance_opt.model.symbolic import available_backends
from balance_opt.tasks.task import load_task

TASK = """name: t
robot: {{shipped: paper_robot.urdf{backend}}}
arms:
  mission: [mission_joint1, mission_joint2, mission_joint3]
  balance: [balance_joint1, balance_joint2, balance_joint3]
initial: {{balance: [0.0, 0.5, -1.0]}}
mission: {{type: ptp, start: [0, 0.3, -0.6], goal: [0.5, 0.3, -0.6], duration: 5.0}}
"""


def _task(tmp_path, backend=None):
    path = tmp_path / "task.yaml"
    path.write_text(TASK.format(backend="" if backend is None else f", backend: {backend}"))
    return path


def _needs(backend):
    if backend not in available_backends():
        pytest.skip(f"backend {backend} not available here")


@pytest.mark.parametrize("backend", [None, "auto", "pinocchio", "adam"])
def test_task_file_selects_the_backend(tmp_path, backend):
    task = load_task(_task(tmp_path, backend))
    assert task.spec.robot.backend == (backend or "auto")


def test_task_choices_are_the_symbolic_backends():
    from balance_opt.model.symbolic import BACKENDS
    from balance_opt.tasks.task_spec import SYMBOLIC_BACKENDS

    assert SYMBOLIC_BACKENDS == ("auto", *BACKENDS)


def test_unknown_backend_is_refused_with_line_and_key(tmp_path, capsys):
    path = _task(tmp_path, "pinochio")
    assert main(["validate", str(path)]) == 2
    assert capsys.readouterr().err.strip() == (
        f"balance-opt: error: {path}:2: robot.backend: expected one of 'auto', 'pinocchio', "
        "'adam', got 'pinochio' (a string); did you mean 'pinocchio'?"
    )


@pytest.mark.parametrize("backend", ["pinocchio", "adam"])
def test_model_cache_builds_the_maps_with_the_backend(paper, backend):
    _needs(backend)
    models = ModelCache()
    model = models.planner_model(paper, backend)
    assert model.maps.backend == backend
    assert models.planner_model(paper, backend) is model
    assert paper in models and len(models) == 1


def test_the_optimal_plan_uses_the_task_backend(tmp_path, monkeypatch):
    seen = []

    class Stop(Exception):
        pass

    def planner_model(self, robot, backend="auto"):
        seen.append(backend)
        raise Stop

    monkeypatch.setattr(ModelCache, "planner_model", planner_model)
    with pytest.raises(Stop):
        pipeline.plan_optimal(load_task(_task(tmp_path, "adam")))
    assert seen == ["adam"]


@pytest.mark.parametrize(
    "in_task, flag, shown",
    [
        ("adam", None, "symbolic backend: adam"),
        ("pinocchio", "adam", "symbolic backend: adam"),
        ("adam", "pinocchio", "symbolic backend: pinocchio ("),
        (None, None, "symbolic backend: "),
    ],
)
def test_inspect_prints_the_backend(tmp_path, capsys, in_task, flag, shown):
    _needs(flag or in_task or "adam")
    args = ["inspect", str(_task(tmp_path, in_task))] + (["--backend", flag] if flag else [])
    assert main(args) == 0
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith(shown)
    assert last.startswith(("symbolic backend: pinocchio (", "symbolic backend: adam"))


def test_backend_flag_reaches_the_run(tmp_path, monkeypatch):
    seen = []

    def run_task(task, **kwargs):
        seen.append(task.spec.robot.backend)
        raise KeyboardInterrupt

    monkeypatch.setattr(pipeline, "run_task", run_task)
    path = _task(tmp_path, "pinocchio")
    out = tmp_path / "out"
    assert main(["plan", str(path), "-o", str(out), "--backend", "adam"]) == 130
    assert main(["plan", str(path), "-o", str(out)]) == 130
    assert seen == ["adam", "pinocchio"]
