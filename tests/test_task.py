"""Task files: loading with line numbers, typed validation, every input error located by file,
line and key path, the JSON Schema from the same source, and the examples."""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from balance_opt.analytic.options import BalanceLawOptions
from balance_opt.app.scenarios import capture_task
from balance_opt.config.schema import reference_rows
from balance_opt.config.typed_config import from_data
from balance_opt.config.yaml_lines import TaskFileError, format_path, parse_yaml
from balance_opt.dynamics.options import ClosedLoopOptions, SimulationOptions
from balance_opt.errors import InfeasibleLimitsError, InputError, TrajectoryError
from balance_opt.motion.options import IntegrationOptions
from balance_opt.optimal.options import CostWeights, PlannerOptions
from balance_opt.tasks.task import load_task, task_from_dict
from balance_opt.tasks.task_spec import (
    PtpMission,
    TaskSpec,
    task_json_schema,
    task_reference_markdown,
)

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
PAPER = (EXAMPLES / "capture_task.yaml").read_text()


def _line_of(text: str, fragment: str) -> int:
    """1-based line of the first line of ``text`` that starts with ``fragment``, indentation aside
    (a leading ``^``: an unindented line)."""
    for i, line in enumerate(text.splitlines(), start=1):
        if (
            line.startswith(fragment[1:])
            if fragment.startswith("^")
            else line.lstrip().startswith(fragment)
        ):
            return i
    raise AssertionError(f"{fragment!r} not in the text")


def _edit(text: str, old: str, new: str) -> str:
    assert old in text, old
    return text.replace(old, new, 1)


# ----------------------------------------------------------------------------------- YAML with lines
def test_yaml_lines_record_every_key_path():
    doc = parse_yaml("a: 1\nb:\n  c: [1, 2,\n      3]\n  d:\n    - x: 1\n    - y: 2\n", "t.yaml")
    assert doc.data == {"a": 1, "b": {"c": [1, 2, 3], "d": [{"x": 1}, {"y": 2}]}}
    assert doc.line_of(("b", "c", 2)) == 4
    assert doc.line_of(("b", "d", 1, "y")) == 7
    assert doc.line_of(("b", "nope", 3)) == 2  # nearest present ancestor
    assert format_path(("b", "d", 1, "y")) == "b.d[1].y"
    assert format_path(()) == "(top level)"


def test_yaml_exponent_without_dot_is_a_float():
    # YAML 1.1 (PyYAML) reads 1e-3 as a string; task files must not
    assert parse_yaml("a: 1e-3\nb: -2E+2\nc: 5\n", "t.yaml").data == {
        "a": 0.001,
        "b": -200.0,
        "c": 5,
    }


def test_yaml_duplicate_key_is_an_error():
    with pytest.raises(
        TaskFileError, match=re.escape("t.yaml:3: x.a: key 'a' is given twice (first on line 2)")
    ):
        parse_yaml("x:\n  a: 1\n  a: 2\n", "t.yaml")


def test_yaml_syntax_error_names_the_line():
    with pytest.raises(
        TaskFileError,
        match=re.escape(
            "t.yaml:3: (top level): YAML syntax error: while parsing a "
            "flow sequence that starts on line 2: expected ',' or ']', "
            "but got ':'"
        ),
    ):
        parse_yaml("a: 1\nb: [1, 2\nc: 3\n", "t.yaml")


# ----------------------------------------------------------------------------------- examples
def test_paper_example_is_the_paper_scenario():
    task = load_task(EXAMPLES / "capture_task.yaml")
    scenario = capture_task()
    assert task.robot.joint_names == scenario.robot.joint_names
    for key in ("lower", "upper", "velocity", "acceleration", "effort"):
        np.testing.assert_array_equal(
            getattr(task.robot.limits, key), getattr(scenario.robot.limits, key)
        )
    np.testing.assert_array_equal(task.q0, scenario.q0)
    t = np.linspace(0.0, scenario.mission.duration, 11)
    for a, b in zip(task.mission.sample(t), scenario.mission.sample(t)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(task.h0, np.zeros(6))
    assert task.name == "capture_task"
    assert len(task.sha256) == 64


def test_baxter_example_loads():
    task = load_task(EXAMPLES / "baxter_floating.yaml")
    assert (
        task.robot.mission.joints[0] == "left_s0"
        and task.robot.balance_arms[0].joints[-1] == "right_w2"
    )
    assert task.robot.balance_indices.size == 7
    assert task.robot.locked["head_pan"] == 0.0
    np.testing.assert_array_equal(
        task.robot.limits.acceleration[task.robot.balance_indices], np.full(7, 2.0)
    )


def test_task_hash_is_the_file_hash(tmp_path):
    import hashlib

    path = tmp_path / "t.yaml"
    path.write_text(PAPER)
    assert load_task(path).sha256 == hashlib.sha256(PAPER.encode()).hexdigest()


def test_task_from_dict_reads_relative_paths_from_base_dir(tmp_path):
    (tmp_path / "m.csv").write_text(
        "time,mission_joint1,mission_joint2,mission_joint3\n0,0,0.3,-0.6\n"
        "1,0.1,0.35,-0.65\n2,0.2,0.4,-0.7\n"
    )
    data = {
        "robot": {"shipped": "paper_robot.urdf"},
        "arms": {
            "mission": ["mission_joint1", "mission_joint2", "mission_joint3"],
            "balance": ["balance_joint1", "balance_joint2", "balance_joint3"],
        },
        "mission": {"type": "csv", "file": "m.csv"},
    }
    task = task_from_dict(data, base_dir=tmp_path)
    assert task.duration == 2.0
    np.testing.assert_allclose(task.mission.start, [0.0, 0.3, -0.6], rtol=0, atol=1e-15)
    # default balance start: zero, inside the limits
    np.testing.assert_array_equal(task.q_B0, task.robot.neutral()[task.robot.balance_indices])
    data["mission"]["file"] = "other.csv"
    with pytest.raises(
        TaskFileError, match=r"^<dict>: mission\.file: no such CSV file: .*other\.csv$"
    ):
        task_from_dict(data, base_dir=tmp_path)


def test_via_points_and_several_balance_arms(tmp_path):
    text = PAPER.replace(
        "balance: [balance_joint1, balance_joint2, balance_joint3]",
        "balance: [[balance_joint1, balance_joint2], [balance_joint3]]",
    )
    text = re.sub(
        r"mission:\n  type: ptp\n.*?\n\n",
        "mission:\n  type: via\n  times: [0, 4, 10]\n"
        "  points: [[0, 0.3, -0.6], [0.5, 0.5, -1.0], [1.2, 0.9, -1.6]]\n\n",
        text,
        flags=re.DOTALL,
    )
    path = tmp_path / "via.yaml"
    path.write_text(text)
    task = load_task(path)
    assert [a.name for a in task.robot.balance_arms] == ["balance", "balance2"]
    np.testing.assert_allclose(
        task.mission.sample(np.array([4.0]))[0][0], [0.5, 0.5, -1.0], rtol=0, atol=1e-12
    )


# ----------------------------------------------------------------------------------- input errors
#: (case id, text edits, the line's fragment, the exact message after "task.yaml:LINE: ", error type)
BAD_TASKS = [
    (
        "wrong type",
        [("duration: 10.0", "duration: ten")],
        "duration: ten",
        "mission.duration: expected a number, got 'ten' (a string)",
        TaskFileError,
    ),
    (
        "boolean for a number",
        [("duration: 10.0", "duration: yes")],
        "duration: yes",
        "mission.duration: expected a number, got true (a boolean)",
        TaskFileError,
    ),
    (
        "wrong item type",
        [("goal: [1.2, 0.9, -1.6]", "goal: [1.2, x, -1.6]")],
        "goal:",
        "mission.goal[1]: expected a number, got 'x' (a string)",
        TaskFileError,
    ),
    (
        "unknown top-level key",
        [("mission:\n", "mision:\n")],
        "^mision:",
        (
            "mision: unknown key 'mision'; expected one of name, description, robot, arms, mission, initial, "
            "capture, limits, keep_out, analytic, optimal, simulation, robustness, closed_loop, outputs; did you mean 'mission'?"
        ),
        TaskFileError,
    ),
    (
        "unknown nested key",
        [("balance_joint1: {acceleration: 2.0}", "balance_joint1: {accel: 2.0}")],
        "balance_joint1: {accel",
        (
            "limits.balance_joint1.accel: unknown key 'accel'; expected one of lower, upper, "
            "velocity, acceleration, effort, jerk; did you mean 'acceleration'?"
        ),
        TaskFileError,
    ),
    (
        "unknown mission type",
        [("type: ptp", "type: ptpp")],
        "type: ptpp",
        "mission.type: expected one of 'ptp', 'via', 'csv', 'cartesian', got 'ptpp' (a string); did you mean 'ptp'?",
        TaskFileError,
    ),
    (
        "missing URDF file",
        [("shipped: paper_robot.urdf", "urdf: missing/robot.urdf")],
        "urdf: missing",
        "robot.urdf: no such URDF file: {dir}/missing/robot.urdf",
        TaskFileError,
    ),
    (
        "unknown shipped URDF",
        [("shipped: paper_robot.urdf", "shipped: nope.urdf")],
        "shipped: nope",
        "robot.shipped: no shipped URDF 'nope.urdf'; available: paper_robot.urdf, paper_robot_fig5.urdf",
        TaskFileError,
    ),
    (
        "two robot sources",
        [("shipped: paper_robot.urdf", "shipped: paper_robot.urdf\n  example: baxter")],
        "robot:",
        "robot: expected exactly one of urdf, shipped, example; got shipped, example",
        TaskFileError,
    ),
    (
        "unknown joint",
        [("balance_joint3]", "balance_joint9]")],
        "balance: [balance_joint1",
        (
            "arms.balance[2]: joint 'balance_joint9' in {urdf}: no such joint in the URDF (arm 'balance'); "
            "did you mean 'balance_joint3', 'balance_joint2', 'balance_joint1'?"
        ),
        TaskFileError,
    ),
    (
        "locked arm joint",
        [
            (
                "  balance: [balance_joint1, balance_joint2, balance_joint3]\n",
                (
                    "  balance: [balance_joint1, balance_joint2, balance_joint3]\n"
                    "  locked: {mission_joint1: 0.3}\n"
                ),
            )
        ],
        "locked:",
        "arms.locked.mission_joint1: joint 'mission_joint1' in {urdf}: is both an arm joint and a locked joint",
        TaskFileError,
    ),
    (
        "limit of a joint in no arm",
        [("balance_joint1: {acceleration: 2.0}", "head: {acceleration: 2.0}")],
        "head:",
        "limits.head: joint 'head' in {urdf}: limit override for a joint that is in no arm",
        TaskFileError,
    ),
    (
        "lower above upper",
        [("balance_joint1: {acceleration: 2.0}", "balance_joint1: {lower: 1, upper: 0}")],
        "balance_joint1: {lower",
        (
            "limits.balance_joint1.lower: joint 'balance_joint1' in {urdf}: lower limit 1 is "
            "above upper limit 0"
        ),
        TaskFileError,
    ),
    (
        "negative duration",
        [("duration: 10.0", "duration: -1")],
        "duration: -1",
        "mission.duration: must be greater than 0 s, got -1",
        TaskFileError,
    ),
    (
        "negative velocity limit",
        [("balance_joint1: {acceleration: 2.0}", "balance_joint1: {velocity: -2}")],
        "balance_joint1: {velocity",
        "limits.balance_joint1.velocity: must be greater than 0 rad/s, got -2",
        TaskFileError,
    ),
    (
        "goal of the wrong length",
        [("goal: [1.2, 0.9, -1.6]", "goal: [1.2, 0.9]")],
        "goal:",
        "mission.goal: expected 3 values (one per mission joint: mission_joint1, mission_joint2, mission_joint3), got 2",
        TaskFileError,
    ),
    (
        "momentum of the wrong length",
        [("momentum: [0, 0, 0, 0, 0, 0]", "momentum: [0, 0, 0, 0, 0]")],
        "momentum:",
        "initial.momentum: expected a list of 6 numbers, got 5",
        TaskFileError,
    ),
    (
        "balance start outside the limits",
        [
            (
                "balance_joint2: {acceleration: 2.0}",
                "balance_joint2: {acceleration: 2.0, upper: 0.2}",
            )
        ],
        "balance: [0.0, 0.5, -1.0]",
        (
            "initial.balance[1]: balance joint 'balance_joint2' starts at 0.5 rad, outside its position limits "
            "[-1.5708, 0.2] rad (upper limit from limits.balance_joint2.upper); no plan can meet them"
        ),
        InfeasibleLimitsError,
    ),
    (
        "mission faster than its limits",
        [
            (
                "mission_joint1: {acceleration: 2.0}",
                "mission_joint1: {acceleration: 2.0, velocity: 0.1}",
            )
        ],
        "duration:",
        (
            "mission.duration: the mission trajectory leaves the limits of the mission arm, which "
            "follows it as given: mission_joint1: velocity limit exceeded by up to 0.125 rad/s from t = 2.116 s to 7.884 s "
            "(limit from limits.mission_joint1.velocity); no plan can meet them"
        ),
        InfeasibleLimitsError,
    ),
    (
        "duplicate key",
        [("name: capture_task", "name: capture_task\nname: again")],
        "name: again",
        "name: key 'name' is given twice (first on line 8)",
        TaskFileError,
    ),
    (
        "infinite duration",
        [("duration: 10.0", "duration: .inf")],
        "duration: .inf",
        "mission.duration: expected a finite number, got inf",
        TaskFileError,
    ),
    (
        "infinite option",
        [("limits:", "analytic: {attitude_gain: .inf}\nlimits:")],
        "analytic:",
        "analytic.attitude_gain: expected a finite number, got inf",
        TaskFileError,
    ),
    (
        "option below its minimum",
        [("limits:", "optimal:\n  weights: {omega: -1}\nlimits:")],
        "weights:",
        "optimal.weights.omega: must be at least 0, got -1",
        TaskFileError,
    ),
    (
        "unknown key in a section written flat on its class",
        [("limits:", "optimal:\n  constraints: {position_limit: true}\nlimits:")],
        "constraints:",
        (
            "optimal.constraints.position_limit: unknown key 'position_limit'; expected one of "
            "position_limits, velocity_limits, acceleration_limits, jerk_limits, torque_limits, "
            "terminal_attitude_bound, path_attitude_bound, start, end, rest_at_end, final_configuration; "
            "did you mean 'position_limits', 'velocity_limits', 'acceleration_limits'?"
        ),
        TaskFileError,
    ),
    (
        "attribute name instead of the key",
        [("limits:", "analytic: {method: rk4}\nlimits:")],
        "analytic:",
        (
            "analytic.method: unknown key 'method'; expected one of damping_threshold, "
            "max_damping, null_space_gain, null_space_goal, attitude_gain, integrator, rtol, "
            "atol, step, output_step"
        ),
        TaskFileError,
    ),
    (
        "options that contradict each other",
        [("limits:", "analytic:\n  damping_threshold: 0.01\n  max_damping: 0\nlimits:")],
        "^analytic:",
        "analytic: balance law option 'max_damping' must be > 0 when 'damping_threshold' is > 0",
        TaskFileError,
    ),
    (
        "option list of the wrong length",
        [("limits:", "optimal: {rest_configuration: [0, 0]}\nlimits:")],
        "optimal:",
        (
            "optimal.rest_configuration: expected 3 values (one per balance joint: "
            "balance_joint1, balance_joint2, balance_joint3), got 2"
        ),
        TaskFileError,
    ),
    (
        "gains of the wrong length",
        [("limits:", "simulation: {kp: [1, 2]}\nlimits:")],
        "simulation:",
        (
            "simulation.kp: expected 6 values (one per arm joint: mission_joint1, "
            "mission_joint2, mission_joint3, balance_joint1, balance_joint2, balance_joint3), "
            "got 2"
        ),
        TaskFileError,
    ),
    (
        "horizon shorter than the mission",
        [("limits:", "optimal: {horizon: 5}\nlimits:")],
        "optimal:",
        "optimal.horizon: the horizon (5 s) is shorter than the mission (10 s)",
        TaskFileError,
    ),
    (
        "via times not increasing",
        [
            (
                (
                    "  type: ptp\n  start: [0.0, 0.3, -0.6]          # [rad]\n  goal: [1.2, 0.9, -1.6]           # capture "
                    "configuration [rad]\n  duration: 10.0                   # [s]"
                ),
                "  type: via\n  times: [0, 5, 5]\n  points: [[0, 0, 0], [1, 1, 1], [2, 2, 2]]",
            )
        ],
        "times:",
        "mission.times[2]: times must increase: 5 s after 5 s",
        TaskFileError,
    ),
    (
        "via times fewer than points",
        [
            (
                (
                    "  type: ptp\n  start: [0.0, 0.3, -0.6]          # [rad]\n  goal: [1.2, 0.9, -1.6]           # capture "
                    "configuration [rad]\n  duration: 10.0                   # [s]"
                ),
                "  type: via\n  times: [0, 10]\n  points: [[0, 0, 0], [1, 1, 1], [2, 2, 2]]",
            )
        ],
        "times:",
        "mission.times: expected one time per point: 3 points, 2 times",
        TaskFileError,
    ),
    (
        "via times not starting at 0",
        [
            (
                (
                    "  type: ptp\n  start: [0.0, 0.3, -0.6]          # [rad]\n  goal: [1.2, 0.9, -1.6]           # capture "
                    "configuration [rad]\n  duration: 10.0                   # [s]"
                ),
                "  type: via\n  times: [1, 4, 10]\n  points: [[0, 0, 0], [1, 1, 1], [2, 2, 2]]",
            )
        ],
        "times:",
        "mission.times[0]: the first time must be 0 s, got 1",
        TaskFileError,
    ),
    (
        "via point of the wrong length",
        [
            (
                (
                    "  type: ptp\n  start: [0.0, 0.3, -0.6]          # [rad]\n  goal: [1.2, 0.9, -1.6]           # capture "
                    "configuration [rad]\n  duration: 10.0                   # [s]"
                ),
                "  type: via\n  times: [0, 5, 10]\n  points: [[0, 0.3, -0.6], [1, 1], [2, 2, 2]]",
            )
        ],
        "points:",
        (
            "mission.points[1]: expected 3 values (one per mission joint: mission_joint1, "
            "mission_joint2, mission_joint3), got 2"
        ),
        TaskFileError,
    ),
]


@pytest.mark.parametrize(
    "edits, fragment, message, error", [c[1:] for c in BAD_TASKS], ids=[c[0] for c in BAD_TASKS]
)
def test_bad_task_names_file_line_and_key(tmp_path, edits, fragment, message, error):
    text = PAPER
    for old, new in edits:
        text = _edit(text, old, new)
    path = tmp_path / "task.yaml"
    path.write_text(text)
    from balance_opt.model.library import shipped_urdf

    expected = f"{path}:{_line_of(text, fragment)}: " + message.format(
        dir=tmp_path, urdf=shipped_urdf()
    )
    with pytest.raises(error) as info:
        load_task(path)
    assert str(info.value) == expected
    assert isinstance(info.value, InputError)


def test_malformed_csv_names_task_line_and_csv_line(tmp_path):
    (tmp_path / "m.csv").write_text(
        "time,mission_joint1,mission_joint2,mission_joint3\n0,0,0,0\n1,0,abc,0\n"
    )
    text = re.sub(
        r"mission:\n  type: ptp\n.*?\n\n",
        "mission:\n  type: csv\n  file: m.csv\n\n",
        PAPER,
        flags=re.DOTALL,
    )
    path = tmp_path / "task.yaml"
    path.write_text(text)
    with pytest.raises(TrajectoryError) as info:
        load_task(path)
    assert str(info.value) == (
        f"{path}:{_line_of(text, 'file: m.csv')}: mission.file: {tmp_path / 'm.csv'}: "
        "line 3, column 'mission_joint2': not a number: 'abc'"
    )


def test_missing_required_key_names_the_mapping(tmp_path):
    text = _edit(PAPER, "  duration: 10.0                   # [s]\n", "")
    path = tmp_path / "task.yaml"
    path.write_text(text)
    with pytest.raises(
        TaskFileError,
        match=re.escape(
            f"{path}:{_line_of(text, '^mission:')}: mission: missing required key 'duration' (a number: duration of the move)"
        ),
    ):
        load_task(path)


def test_missing_task_file(tmp_path):
    with pytest.raises(
        TaskFileError, match=re.escape(f"{tmp_path / 'none.yaml'}: (top level): no such file")
    ):
        load_task(tmp_path / "none.yaml")


# ----------------------------------------------------------------------------------- schema
def test_schema_and_validator_agree_on_the_examples_and_on_bad_input():
    jsonschema = pytest.importorskip("jsonschema")
    import yaml

    schema = task_json_schema()
    jsonschema.Draft202012Validator.check_schema(schema)
    validator = jsonschema.Draft202012Validator(schema)
    for path in (EXAMPLES / "capture_task.yaml", EXAMPLES / "baxter_floating.yaml"):
        assert list(validator.iter_errors(yaml.safe_load(path.read_text()))) == [], path
    good = yaml.safe_load(PAPER)
    for bad_edit in (
        lambda d: d["mission"].update(duration=-1.0),
        lambda d: d["mission"].update(speed=3),
        lambda d: d["mission"].update(type="ptpp"),
        lambda d: d["robot"].update(example="baxter"),
        lambda d: d["initial"].update(momentum=[0, 0, 0]),
        lambda d: d["limits"]["balance_joint1"].update(accel=1.0),
        lambda d: d["arms"].update(mission="mission_joint1"),
    ):
        data = json.loads(json.dumps(good))
        bad_edit(data)
        assert list(validator.iter_errors(data)), data
        with pytest.raises(TaskFileError):
            from_data(TaskSpec, parse_yaml(json.dumps(data), "x.json"))


def test_schema_lists_every_key_with_its_description():
    schema = task_json_schema()
    assert schema["additionalProperties"] is False
    assert set(schema["properties"]) == set(TaskSpec.__dataclass_fields__)
    ptp = schema["$defs"]["PtpMission"]
    assert ptp["required"] == ["type", "start", "goal", "duration"]
    assert ptp["properties"]["duration"] == {
        "type": "number",
        "exclusiveMinimum": 0.0,
        "description": "duration of the move [s]",
    }


def test_the_documented_reference_is_the_generated_one():
    documented = (ROOT / "docs" / "task-format.md").read_text()
    assert task_reference_markdown() in documented


def test_typed_spec_defaults():
    m = PtpMission(start=(0.0,), goal=(1.0,), duration=2.0)
    assert m.type == "ptp"


CARTESIAN = """robot: {shipped: paper_robot.urdf}
arms:
  mission: [mission_joint1, mission_joint2, mission_joint3]
  balance: [balance_joint1, balance_joint2, balance_joint3]
initial: {balance: [0.0, 0.5, -1.0]}
mission:
  type: cartesian
  start: [0.0, 0.3, -0.6]
  position: POSITION
  duration: 5
"""


def test_cartesian_goal_is_solved_by_inverse_kinematics(tmp_path):
    import pinocchio as pin

    path = tmp_path / "cart.yaml"
    path.write_text(CARTESIAN.replace("POSITION", "[0.9, 0.4, 1.2]"))
    task = load_task(path)
    model, data = task.robot.model, task.robot.model.createData()
    q = np.r_[task.mission.end, task.q_B0]
    pin.framesForwardKinematics(model, data, task.robot.pin_q(q))
    reached = data.oMf[model.getFrameId(task.robot.mission.ee_frame)].translation
    np.testing.assert_allclose(reached, [0.9, 0.4, 1.2], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(task.mission.start, [0.0, 0.3, -0.6])


def test_unreachable_cartesian_goal_names_the_position(tmp_path):
    path = tmp_path / "cart.yaml"
    text = CARTESIAN.replace("POSITION", "[5.0, 0.0, 1.0]")
    path.write_text(text)
    with pytest.raises(TrajectoryError) as info:
        load_task(path)
    message = str(info.value)
    assert message.startswith(
        f"{path}:{_line_of(text, 'position:')}: mission.position: Cartesian goal [5.0, 0.0, 1.0]"
    )
    number = r"-?[0-9.e+-]+"
    point = rf"\[{number}, {number}, {number}\]"
    assert re.search(
        rf"unreachable within the joint limits: remaining distance [0-9.]+ m; the closest point "
        rf"reached is {point} m \(joints {point}\), the end effector starts at {point} m$",
        message,
    )


# ----------------------------------------------------------------------------------- options
MINIMAL = """robot: {shipped: paper_robot.urdf}
arms:
  mission: [mission_joint1, mission_joint2, mission_joint3]
  balance: [balance_joint1, balance_joint2, balance_joint3]
initial: {balance: [0.0, 0.5, -1.0]}
mission: {type: ptp, start: [0.0, 0.3, -0.6], goal: [0.2, 0.4, -0.7], duration: 2.0}
"""

#: Where each option class sits in a task file (key path of its section) and how to get it
#: from a TaskSpec.
OPTION_SECTIONS = {
    BalanceLawOptions: (("analytic",), lambda spec: spec.analytic.law),
    IntegrationOptions: (("analytic",), lambda spec: spec.analytic.integration),
    PlannerOptions: (("optimal",), lambda spec: spec.optimal.planner),
    CostWeights: (("optimal", "weights"), lambda spec: spec.optimal.planner.weights),
    SimulationOptions: (("simulation",), lambda spec: spec.simulation),
    ClosedLoopOptions: (("closed_loop",), lambda spec: spec.closed_loop),
}


@pytest.mark.parametrize("cls", OPTION_SECTIONS, ids=lambda c: c.__name__)
def test_python_defaults_are_the_task_file_defaults(tmp_path, cls):
    get = OPTION_SECTIONS[cls][1]
    assert get(from_data(TaskSpec, parse_yaml(MINIMAL, "minimal.yaml"))) == cls()
    # a loaded task: the same, with the initial momentum where the class takes one
    path = tmp_path / "minimal.yaml"
    path.write_text(MINIMAL)
    expected = cls(h0=(0.0,) * 6) if "h0" in cls.__dataclass_fields__ else cls()
    assert get(load_task(path).spec) == expected


def test_output_steps_are_one_default():
    # the CLI's numbers stay those of a task file: 100 Hz output from Python too
    assert IntegrationOptions().output_step == 0.01
    assert SimulationOptions().output_dt == 0.01


def _file_keys(cls) -> dict[str, object]:
    """Key path (below the class's section) -> field, for every field a file sets."""
    out = {}
    for f in dataclasses.fields(cls):
        if not f.metadata["in_file"] or f.metadata["inline"]:
            continue
        key = (f.metadata["section"],) if f.metadata["section"] else ()
        out[".".join((*key, f.metadata["key"] or f.name))] = f
    return out


def _schema_at(schema: dict, path) -> dict:
    node = schema
    for key in path:
        node = node["properties"][key]
        ref = node.get("$ref") or (node.get("allOf") or [{}])[0].get("$ref")
        if ref:
            node = schema["$defs"][ref.rsplit("/", 1)[1]]
    return node


@pytest.mark.parametrize("cls", OPTION_SECTIONS, ids=lambda c: c.__name__)
def test_every_option_is_in_the_schema_and_the_reference(cls):
    section = OPTION_SECTIONS[cls][0]
    schema = task_json_schema()
    rows = {row[0]: row for row in reference_rows(TaskSpec)}
    keys = _file_keys(cls)
    assert keys
    for key, f in keys.items():
        path = (*section, *key.split("."))
        parent, name = _schema_at(schema, path[:-1]), path[-1]
        assert name in parent["properties"], path
        assert parent["properties"][name]["description"].startswith(f.metadata["doc"]), path
        assert ".".join(path) in rows, path
        assert f"`{'.'.join(path)}`" in task_reference_markdown()
    # fields set from elsewhere in the task are not keys of the file
    for f in dataclasses.fields(cls):
        if not f.metadata["in_file"]:
            assert f.name not in _schema_at(schema, section)["properties"]
            assert ".".join((*section, f.name)) not in rows


def test_option_keys_of_the_task_format():
    """The public format: keys and defaults of the option sections, as they have always been."""
    rows = {k: d for k, _, d, _ in reference_rows(TaskSpec) if k.split(".")[0] in OPTION_KEYS}
    assert rows == {k: d for k, d in OPTION_KEYS_DEFAULTS}


OPTION_KEYS = ("analytic", "optimal", "simulation", "robustness", "closed_loop")
OPTION_KEYS_DEFAULTS = [
    ("analytic", "see below"),
    ("analytic.damping_threshold", "0.001"),
    ("analytic.max_damping", "0.01"),
    ("analytic.null_space_gain", "1.0"),
    ("analytic.null_space_goal", "none"),
    ("analytic.attitude_gain", "0.0"),
    ("analytic.integrator", "'adaptive'"),
    ("analytic.rtol", "1e-10"),
    ("analytic.atol", "1e-12"),
    ("analytic.step", "none"),
    ("analytic.output_step", "0.01"),
    ("optimal", "see below"),
    ("optimal.objective", "'peak'"),
    ("optimal.intervals", "100"),
    ("optimal.transcription", "'hermite-simpson'"),
    ("optimal.control", "'acceleration'"),
    ("optimal.horizon", "none"),
    ("optimal.initial_guess", "'analytic'"),
    ("optimal.weights", "see below"),
    ("optimal.weights.omega", "100.0"),
    ("optimal.weights.terminal", "100.0"),
    ("optimal.weights.smoothness", "0.001"),
    ("optimal.weights.rest", "0.0"),
    ("optimal.weights.attitude", "300.0"),
    ("optimal.weights.peak", "100000.0"),
    ("optimal.weights.peak_terminal", "100000.0"),
    ("optimal.weights.regularisation", "0.01"),
    ("optimal.weights.jerk", "1.0"),
    ("optimal.rest_configuration", "none"),
    ("optimal.constraints", "see below"),
    ("optimal.constraints.position_limits", "true"),
    ("optimal.constraints.velocity_limits", "true"),
    ("optimal.constraints.acceleration_limits", "true"),
    ("optimal.constraints.jerk_limits", "true"),
    ("optimal.constraints.torque_limits", "false"),
    ("optimal.constraints.terminal_attitude_bound", "none"),
    ("optimal.constraints.path_attitude_bound", "none"),
    ("optimal.constraints.start", "'rest'"),
    ("optimal.constraints.end", "'rest'"),
    ("optimal.constraints.rest_at_end", "false"),
    ("optimal.constraints.final_configuration", "none"),
    ("optimal.collision", "see below"),
    ("optimal.collision.avoid", "true"),
    ("optimal.collision.margin", "0.03"),
    ("optimal.collision.ignore", "[]"),
    ("optimal.tolerance", "1e-08"),
    ("optimal.max_iterations", "1000"),
    ("optimal.resample_step", "0.01"),
    ("optimal.starts", "1"),
    ("optimal.seed", "0"),
    ("optimal.ipopt", "{}"),
    ("simulation", "see below"),
    ("simulation.integrator", "'rk4'"),
    ("simulation.dt", "0.001"),
    ("simulation.rtol", "1e-10"),
    ("simulation.atol", "1e-12"),
    ("simulation.max_step", "0.05"),
    ("simulation.output_dt", "0.01"),
    ("simulation.controller", "'pd'"),
    ("simulation.feedforward", "true"),
    ("simulation.kp", "none"),
    ("simulation.kd", "none"),
    ("simulation.bandwidth", "20.0"),
    ("simulation.damping_ratio", "1.0"),
    ("simulation.clip_torque", "false"),
    ("robustness", "see below"),
    ("robustness.enabled", "none"),
    ("robustness.samples", "50"),
    ("robustness.perturbation", "0.1"),
    ("robustness.seed", "0"),
    ("closed_loop", "see below"),
    ("closed_loop.period", "0.5"),
    ("closed_loop.samples", "20"),
    ("closed_loop.perturbation", "none"),
    ("closed_loop.seed", "none"),
    ("closed_loop.margin", "0.06"),
    ("closed_loop.position_margin", "0.002"),
    ("closed_loop.jerk", "15.0"),
    ("closed_loop.end_period", "0.2"),
    ("closed_loop.end_window", "3.0"),
]


def test_task_file_options_reach_the_library_objects(tmp_path):
    text = _edit(PAPER, "momentum: [0, 0, 0, 0, 0, 0]", "momentum: [0, 0, 0, 0, 0, 0.01]") + (
        "analytic: {attitude_gain: 0.5, integrator: rk4, step: 0.002}\n"
        "optimal:\n"
        "  intervals: 40\n"
        "  initial_guess: rest\n"
        "  weights: {omega: 3}\n"
        "  constraints: {torque_limits: true, path_attitude_bound: 0.1}\n"
        "  ipopt: {max_cpu_time: 5}\n"
    )
    path = tmp_path / "task.yaml"
    path.write_text(text)
    task = load_task(path)
    a, o = task.spec.analytic, task.spec.optimal
    assert a.law == BalanceLawOptions(attitude_gain=0.5, h0=(0, 0, 0, 0, 0, 0.01))
    assert a.integration == IntegrationOptions(method="rk4", step=0.002)
    assert o.initial_guess == "rest"
    assert o.planner == PlannerOptions(
        intervals=40,
        weights=CostWeights(omega=3.0),
        torque_limits=True,
        path_attitude_bound=0.1,
        ipopt={"max_cpu_time": 5},
    )
    assert task.spec.simulation == SimulationOptions(h0=(0, 0, 0, 0, 0, 0.01))
    # --solver-option entries override the task's, the others are kept
    merged = task.planner_options({"max_cpu_time": 9, "print_level": 5})
    assert merged.ipopt == {"max_cpu_time": 9, "print_level": 5}
    assert dataclasses.replace(merged, ipopt=o.planner.ipopt) == o.planner
    assert task.planner_options() is o.planner


def test_python_options_are_normalised():
    options = PlannerOptions(
        intervals=np.int64(20), rest_configuration=np.array([0.1, 0.2, 0.3]), tolerance=1
    )
    assert options.intervals == 20 and type(options.intervals) is int
    assert options.rest_configuration == (0.1, 0.2, 0.3)
    assert type(options.tolerance) is float
    assert hash(BalanceLawOptions(null_space_goal=np.zeros(3), h0=[0, 0, 1]))


def test_loading_the_package_imports_no_casadi_and_a_task_no_solver():
    """The package loads without CasADi; a task file's load reads its problem's size from the
    planner's terms (which are CasADi expressions: CasADi comes with them) but neither solves
    nor refines anything."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "import balance_opt\n"
        "print('casadi' in sys.modules)\n"
        "from balance_opt.tasks.task import load_task\n"
        f"load_task({str(EXAMPLES / 'capture_task.yaml')!r})\n"
        "print(sorted(m for m in sys.modules if m.startswith('balance_opt.optimal.')))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT
    ).stdout
    package, task = out.strip().splitlines()
    assert package == "False"
    assert "'balance_opt.optimal.terms'" in task and "'balance_opt.optimal.budget'" in task
    for module in ("solve", "refine", "guess", "replan"):
        assert f"'balance_opt.optimal.{module}'" not in task
