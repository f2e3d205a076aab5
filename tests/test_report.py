"""Outputs and report pieces: limit margins against a hand computation, JSON conversion, the
NPZ round trip, the Ipopt version, and the report's 3D animation (geometry and its script)."""

import json
import math
import re
import shutil
import subprocess

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.io.animation import ANIMATION_FPS, animation_data, animation_html, skeleton
from balance_opt.io.outputs import (
    ipopt_version,
    limit_margins,
    read_npz_result,
    to_json,
    write_trajectory_csv,
    write_trajectory_npz,
)
from balance_opt.io.report import comparison_table
from balance_opt.motion.so3 import quaternion_from_rotvec
from balance_opt.result import BalanceResult

ATOL = 1e-9


def _result(robot, seed=0, samples=21):
    """A random smooth motion of every arm joint with a random attitude history."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 2.0, samples)
    n = robot.n
    a, w = rng.uniform(-0.5, 0.5, n), rng.uniform(0.5, 2.0, n)
    q = robot.neutral() + a * np.sin(np.outer(t, w))
    q_dot = a * w * np.cos(np.outer(t, w))
    q_ddot = -a * w**2 * np.sin(np.outer(t, w))
    phi = np.outer(t, rng.uniform(-0.05, 0.05, 3))
    M, B = robot.mission_indices, robot.balance_indices
    return BalanceResult(
        method="test", t=t, mission_joints=tuple(robot.joint_names[i] for i in M),
        balance_joints=tuple(robot.joint_names[i] for i in B),
        q_M=q[:, M], q_dot_M=q_dot[:, M], q_ddot_M=q_ddot[:, M],
        q_B=q[:, B], q_dot_B=q_dot[:, B], q_ddot_B=q_ddot[:, B],
        quaternion=quaternion_from_rotvec(phi), omega=np.zeros((samples, 3)),
        momentum_residual=np.zeros(samples), sigma_min=np.ones(samples), info={"x": np.arange(3)},
    )  # fmt: skip


def test_limit_margins_by_hand(paper):
    res = _result(paper)
    margins = limit_margins(res, paper)
    lim = paper.limits
    j = res.balance_joints[1]
    i = paper.joint_index(j)
    q = res.q_B[:, 1]
    assert margins[j]["position"] == pytest.approx(
        min(lim.upper[i] - q.max(), q.min() - lim.lower[i]), abs=1e-15
    )
    assert margins[j]["velocity"] == pytest.approx(
        lim.velocity[i] - np.abs(res.q_dot_B[:, 1]).max(), abs=1e-15
    )
    assert margins[j]["acceleration"] == math.inf  # the URDF has no acceleration limits


def test_to_json_is_strict_json():
    data = to_json(
        {"a": np.float64(1.5), "b": np.arange(2), "c": math.inf, "d": (np.bool_(True), None)}
    )
    assert json.loads(json.dumps(data, allow_nan=False)) == {
        "a": 1.5,
        "b": [0, 1],
        "c": None,
        "d": [True, None],
    }


def test_npz_and_csv_round_trip(paper, tmp_path):
    res = _result(paper)
    back = read_npz_result(write_trajectory_npz(tmp_path / "r.npz", res))
    for name in ("t", "q_M", "q_dot_B", "q_ddot_B", "quaternion"):
        np.testing.assert_array_equal(getattr(back, name), getattr(res, name))
    assert back.balance_joints == res.balance_joints and back.info == {"x": [0, 1, 2]}
    rows = write_trajectory_csv(tmp_path / "r.csv", res).read_text()
    values = np.array([line.split(",") for line in rows.splitlines()[1:]], dtype=float)
    np.testing.assert_array_equal(values[:, 1:4], res.q_M)  # full precision
    np.testing.assert_allclose(values[:, -4:-1], res.rpy, rtol=0, atol=1e-15)


def test_ipopt_version_is_read_from_the_library():
    assert re.fullmatch(r"\d+\.\d+\.\d+", ipopt_version())


def test_comparison_table_marks_broken_limits():
    methods = {
        "analytic": {"max_drift_rad": 0.01, "balance_limit_margin": {"position": -0.2}},
        "optimal": {"max_drift_rad": 0.02, "balance_limit_margin": {"position": 1e-9}},
    }
    table = comparison_table(methods)
    assert '<td class="bad">-0.2</td><td class="good">1e-09</td>' in table
    assert (
        '<td>max attitude drift [deg]</td><td class="">0.573</td><td class="">1.146</td>' in table
    )
    assert "Forward-dynamics simulation" not in table  # empty sections are left out


# ----------------------------------------------------------------------------------- animation
def test_animation_keeps_the_centre_of_mass_and_the_arm_shape(paper):
    res = _result(paper)
    data = animation_data(paper, {"test": res}, fps=5)
    frames = data["methods"]["test"]["frames"]
    points, segments = skeleton(paper)
    assert len(segments) == len(points) - 1  # a tree: every point but the base hangs from one other
    model, pdata = paper.model, paper.model.createData()
    c0 = None
    for k, frame in enumerate(frames):
        i = np.searchsorted(res.t, data["methods"]["test"]["t"][k])
        q = np.r_[res.q_M[i], res.q_B[i]]
        R = np.array(
            pin.Quaternion(res.quaternion[i][3], *res.quaternion[i][:3]).toRotationMatrix()
        )
        base = pin.SE3(R, frame["points"][0])
        com = pin.centerOfMass(model, pdata, paper.pin_q(q, base))
        c0 = com if c0 is None else c0
        np.testing.assert_allclose(com, c0, rtol=0, atol=ATOL)  # zero momentum: the CoM stays put
        # the end effectors, seen from the base, are where forward kinematics at the identity puts them
        pin.framesForwardKinematics(model, pdata, paper.pin_q(q))
        for arm, p in zip(paper.arms, frame["points"][-len(paper.arms) :]):
            expected = pdata.oMf[model.getFrameId(arm.ee_frame)].translation
            np.testing.assert_allclose(R.T @ (p - frame["points"][0]), expected, rtol=0, atol=ATOL)
        # the base box (1 m cube centred on the base origin) turns with the base
        np.testing.assert_allclose(
            np.linalg.norm(frame["box"] - frame["points"][0], axis=1),
            math.sqrt(3) / 2,
            rtol=0,
            atol=ATOL,
        )


@pytest.mark.skipif(shutil.which("node") is None, reason="node is not installed")
def test_animation_script_runs(paper, tmp_path):
    fragment = animation_html(
        paper, {"a": _result(paper, 1), "b": _result(paper, 2)}, element_id="anim"
    )
    script = re.search(r"<script>(.*)</script>", fragment, re.DOTALL).group(1)
    harness = (
        """
const drawn = [];
const ctx = {clearRect() { drawn.length = 0; }, beginPath() {}, moveTo() {}, lineTo() {},
             stroke() { drawn.push(this.strokeStyle); }};
const els = {};
function el(id) { return els[id] || (els[id] = {value: '', width: 400, height: 400, getContext: () => ctx}); }
globalThis.document = {getElementById: el};
globalThis.window = {addEventListener() {}};
globalThis.requestAnimationFrame = () => {};
el('anim-method').value = 'b';
"""
        + script
        + """
el('anim-t').value = 3; el('anim-t').oninput();
console.log(JSON.stringify({label: el('anim-label').textContent, max: el('anim-t').max, lines: drawn.length}));
"""
    )
    path = tmp_path / "h.js"
    path.write_text(harness)
    proc = subprocess.run(
        ["node", str(path)], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    _points, segments = skeleton(paper)
    assert out["lines"] == 12 + len(segments) + 3  # box edges, the stick figure, the base axes
    assert out["max"] == round(2.0 * ANIMATION_FPS)  # frames of 2 s, from 0
    assert out["label"].startswith("t = ")
