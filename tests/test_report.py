"""Outputs and report pieces: limit margins against a hand computation, JSON conversion, the
NPZ round trip, the Ipopt version, and the 3D scene's magnified view of the base rotation."""

import json
import math
import re

import numpy as np
import pytest

from balance_opt.dynamics.inverse_dynamics import free_floating_torques, plan_joint_torques
from balance_opt.motion.result import LIMIT_TOLERANCE, BalanceResult
from balance_opt.motion.so3 import matrix_from_quaternion, quaternion_from_rotvec
from balance_opt.report.outputs import (
    effort_metrics,
    limit_margins,
    method_metrics,
    read_npz_result,
    to_json,
    write_trajectory_csv,
    write_trajectory_npz,
)
from balance_opt.report.report import (
    MOMENTUM_TOLERANCE,
    TORQUE_TOLERANCE,
    comparison_table,
    format_angle,
    format_value,
    margin_class,
    render_report,
    torque_sparkline,
    torque_table,
)
from balance_opt.report.scene_poses import magnification, magnified_rotation
from balance_opt.report.style import method_label
from balance_opt.solvers.ipopt_options import ipopt_version


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


# ----------------------------------------------------------------------------------- report
def test_values_below_their_tolerance_read_zero():
    assert format_value(2.935e-19, MOMENTUM_TOLERANCE) == "0 (< 1e-09)"
    assert format_value(3.2e-8, MOMENTUM_TOLERANCE) == "3.2e-08"
    assert format_value(-4e-9, TORQUE_TOLERANCE, "N m") == "-4e-09 N m"
    assert format_value(4e-10, 1e-9, "N m") == "0 (< 1e-09 N m)"
    assert format_angle(math.radians(8.9e-14)) == "0 (< 1e-12 rad)"
    assert format_angle(0.09291) == "0.09291 rad (5.323 deg)"
    assert format_angle(0.02, per="/s") == "0.02 rad/s (1.146 deg/s)"


def test_margin_colours_by_meaning():
    assert margin_class(1.8e-7, 1.8e-7, LIMIT_TOLERANCE) == "at-limit"  # sitting on the limit
    assert margin_class(0.005, 0.005, LIMIT_TOLERANCE) == "at-limit"  # inside the 1 % band
    assert margin_class(0.03, 0.03, LIMIT_TOLERANCE) == "inside"
    assert margin_class(1.07, 0.5, LIMIT_TOLERANCE) == "inside"
    assert margin_class(-0.2, -0.1, LIMIT_TOLERANCE) == "broken"
    assert margin_class(-5e-7, -5e-7, LIMIT_TOLERANCE) == "at-limit"  # within the tolerance
    assert margin_class(math.inf, None, LIMIT_TOLERANCE) == ""  # no limit


def test_comparison_table_colours_margins_and_flags_failures():
    methods = {
        "analytic": {
            "max_drift_rad": 0.01,
            "balance_limit_margin": {"velocity": -0.2},
            "balance_relative_limit_margin": {"velocity": -0.2},
        },
        "optimal": {
            "max_drift_rad": 1e-15,
            "balance_limit_margin": {"velocity": 1.8e-7},
            "balance_relative_limit_margin": {"velocity": 1.8e-7},
        },
        "mission-only": {
            "max_drift_rad": 0.0929,
            "balance_limit_margin": {"velocity": 1.0},
            "balance_relative_limit_margin": {"velocity": 1.0},
        },
    }
    table = comparison_table(methods, {"optimal": "Ipopt: Maximum_Iterations_Exceeded"})
    assert (
        "<td>velocity limit margin [rad/s or m/s]</td>"
        '<td class="inside">1; 100 % of the limit</td>'
        '<td class="broken">-0.2; -20 % of the limit</td>'
        '<td class="at-limit failed">0 (&lt; 1e-06)</td>'
    ) in table
    assert (
        '<td>max attitude drift</td><td class="">0.0929 rad (5.323 deg)</td>'
        '<td class="">0.01 rad (0.573 deg)</td><td class="failed">0 (&lt; 1e-12 rad)</td>'
    ) in table
    # one name per method, the style module's; the failed one flagged in its header
    heads = re.findall(r"<th[^>]*>(.*?)</th>", table)[1:]
    assert [re.sub("<[^>]+>", "", h) for h in heads] == [
        method_label("mission-only"),
        method_label("analytic"),
        method_label("optimal") + "FAILED",
    ]
    assert '<th class="failed">' in table and table.count("FAILED") == 1
    assert "Forward-dynamics simulation" not in table  # empty sections are left out


def _feedforward_torques(robot, res):
    """Joint torques from the simulation's computed-torque feedforward, an implementation
    of its own (composite inertia of the base, RNEA), at the base twist of zero momentum."""
    from balance_opt.dynamics.simulation import _Dynamics
    from balance_opt.model.maps import NumericMaps

    dyn, maps = _Dynamics(robot, 0.0, 0.0, "computed-torque", False), NumericMaps(robot)
    q = np.hstack([res.q_M, res.q_B])
    qd = np.hstack([res.q_dot_M, res.q_dot_B])
    qdd = np.hstack([res.q_ddot_M, res.q_ddot_B])
    assert robot.joint_names == (*res.mission_joints, *res.balance_joints)
    return np.array(
        [
            dyn.feedforward(
                robot.pin_q(q[k]), robot.pin_v(qd[k], maps.base_twist(q[k], qd[k])), qdd[k]
            )
            for k in range(res.t.size)
        ]
    )


def test_effort_margins_against_an_independent_inverse_dynamics(paper):
    res = _result(paper, samples=41)
    tau = _feedforward_torques(paper, res)
    effort = effort_metrics(res, paper)
    for k, joint in enumerate(paper.joint_names):
        e, peak = effort["joints"][joint], np.abs(tau[:, k]).max()
        limit = paper.limits.effort[k]
        assert e["peak_Nm"] == pytest.approx(peak, rel=1e-10)
        assert e["peak_time_s"] == res.t[np.argmax(np.abs(tau[:, k]))]
        assert e["margin_Nm"] == pytest.approx(limit - peak, rel=1e-10)
        assert e["relative_margin"] == pytest.approx((limit - peak) / limit, rel=1e-10)
        assert e["status"] == "inside"
    assert effort["violations"] == []


def test_effort_violations_are_counted_and_no_limit_said():
    from test_inverse_dynamics import WHEELS

    from balance_opt.model.robot import FloatingRobot

    robot = FloatingRobot(WHEELS, ["w1_joint"], ["w2_joint"])
    t = np.linspace(0.0, 0.6, 101)
    q = np.column_stack([0.5 * np.sin(4 * t), np.sin(t)])  # w1: up to 3.7 N m > 1.5 N m, once
    qd = np.column_stack([2 * np.cos(4 * t), np.cos(t)])
    qdd = np.column_stack([-8 * np.sin(4 * t), -np.sin(t)])
    res = BalanceResult.from_arm_vectors(
        robot, "x", t, q, qd, qdd, quaternion_from_rotvec(np.zeros((101, 3))),
        np.zeros((101, 3)), np.zeros(101), np.ones(101),
    )  # fmt: skip
    metrics = method_metrics(res, robot)
    w1, w2 = metrics["effort"]["joints"]["w1_joint"], metrics["effort"]["joints"]["w2_joint"]
    c1, c2, Ib = 0.5, 0.8, 6.0  # closed form of the coaxial wheels (see test_inverse_dynamics)
    wdot = -(c1 * qdd[:, 0] + c2 * qdd[:, 1]) / (Ib + c1 + c2)
    peak = np.abs(c1 * (wdot + qdd[:, 0])).max()
    assert peak > 1.5 and w1["peak_Nm"] == pytest.approx(peak, rel=1e-12)
    assert w1["status"] == "broken" and w1["margin_Nm"] == pytest.approx(1.5 - peak, rel=1e-12)
    assert w2 == {
        "peak_Nm": w2["peak_Nm"], "peak_time_s": w2["peak_time_s"], "limit_Nm": None,
        "margin_Nm": None, "relative_margin": None, "status": "no limit",
    }  # fmt: skip
    assert metrics["effort"]["min_relative_margin"] == w1["relative_margin"]
    assert metrics["effort"]["balance_min_relative_margin"] is None
    (violation,) = metrics["violations"]
    assert violation.startswith("w1_joint: effort limit exceeded by up to ")
    assert metrics["limit_violations"] == 1
    table = torque_table(metrics["effort"])
    assert '<td>w2_joint</td><td class="">' in table and "no limit" in table
    margin = 1.5 - w1["peak_Nm"]
    assert (
        f'<td class="broken">{margin:.4g}</td><td class="broken">{100 * margin / 1.5:.4g} %</td>'
        in table
    )


# ------------------------------------------------------------------------ magnified rotation
def test_magnification_and_magnified_rotation(paper):
    assert magnification(0.0929) == 5 and magnification(0.01) == 50
    assert magnification(0.6) == 1 and magnification(0.0) == 1
    res = _result(paper)
    ref = matrix_from_quaternion(res.quaternion[0])
    mag = magnified_rotation(res.quaternion, 10.0)
    for k in (5, 20):
        turned = ref.T @ mag[k]  # R0^T R_mag
        angle = math.acos((np.trace(turned) - 1) / 2)
        assert angle == pytest.approx(10 * res.angle[k], rel=1e-9)


def test_torque_sparkline_keeps_the_peak_and_draws_the_limit():
    t = np.linspace(0.0, 10.0, 1001)
    tau = np.sin(t) * 0.5
    tau[537] = -3.0  # one sample: the binning must keep it
    svg = torque_sparkline(t, tau, 4.0, "inside", width=240, height=30)
    top = 1.05 * 4.0
    ys = [float(p.split(",")[1]) for p in re.search(r'points="([^"]+)"', svg).group(1).split()]
    assert min(ys) == pytest.approx(29 - 28 * 3.0 / top, abs=0.051)  # the spike, to 0.1 px
    (limit_y,) = re.findall(r'<line x1="0" y1="([\d.]+)"', svg)
    assert float(limit_y) == pytest.approx(29 - 28 * 4.0 / top, abs=0.051)
    assert "<line" not in torque_sparkline(t, tau, None, "")  # no limit, no line


def test_plan_joint_torques_are_the_plans_columns_and_given_torques_are_used(paper):
    res = _result(paper)
    tau = plan_joint_torques(res, paper)
    columns = [paper.joint_index(j) for j in (*res.mission_joints, *res.balance_joints)]
    assert np.abs(tau).max() > 0
    motion = [np.zeros((res.t.size, paper.n)) for _ in range(3)]
    parts = ((res.q_M, res.q_B), (res.q_dot_M, res.q_dot_B), (res.q_ddot_M, res.q_ddot_B))
    for full, part in zip(motion, parts):
        full[:, columns] = np.hstack(part)
    reference = free_floating_torques(paper, *motion, res.quaternion).tau[:, columns]
    np.testing.assert_array_equal(tau, reference)
    moving = plan_joint_torques(res, paper, np.array([0, 0, 0, 1.0, 0, 0]))
    assert np.abs(moving - tau).max() > 1e-6  # another momentum, other torques
    # the metrics take the caller's torques as they are (a run computes them once)
    assert effort_metrics(res, paper, torques=moving) == effort_metrics(
        res, paper, np.array([0, 0, 0, 1.0, 0, 0])
    )
    assert effort_metrics(res, paper, torques=moving) != effort_metrics(res, paper)


def test_report_is_offline_and_flags_a_failed_method(paper):
    res = _result(paper)
    methods = {"analytic": method_metrics(res, paper), "optimal": method_metrics(res, paper)}
    metrics = {"task": {"name": "t"}, "methods": methods, "failures": {"optimal": "Ipopt: x"}}
    torques = {name: (res.t, plan_joint_torques(res, paper)) for name in methods}
    page = render_report(metrics, torques=torques)
    assert "http" not in page and "src=" not in page  # nothing to fetch
    assert '<p class="failure">FAILED: optimal plan: Ipopt: x</p>' in page
    assert '<h3>optimal plan <span class="flag">FAILED</span></h3>' in page
    assert page.count("<polyline") == 2 * len(res.mission_joints + res.balance_joints)


def test_report_opens_with_a_headline_and_shows_figures_at_the_columns_width(tmp_path):
    from balance_opt.report.report import headline, render_report

    metrics = {
        "task": {"name": "t"},
        "methods": {
            "mission-only": {"max_drift_rad": 0.0929},
            "optimal": {
                "max_drift_rad": 0.0211,
                "peak_balance_rate_rad_s": 0.512,
                "effort": {"balance_min_relative_margin": 0.25},
                "solver": {"iterations": 120, "solve_time_s": 3.4},
                "limit_violations": 0,
            },
        },
    }
    line = headline(metrics)
    assert line == (
        "The optimal plan keeps the base 4.4x stiller than the mission arm alone (peak drift "
        "0.0211 vs 0.0929 rad), at these costs: balance joints up to 0.512 rad/s; smallest "
        "effort margin 25 % of the limit; 120 Ipopt iterations in 3.4 s."
    )
    png = tmp_path / "f.png"
    png.write_bytes(b"\x89PNG fake")
    page = render_report(metrics, [("a figure", png)])
    assert page.index(f'<p class="headline">{line}</p>') < page.index("<h2>Comparison</h2>")
    assert "figure img { width: 100%; height: auto;" in page
    assert headline({"methods": {"optimal": metrics["methods"]["optimal"]}}) is None
    # an analytic law stiller than the optimal plan (a redundant balance arm it cancels
    # exactly; two Pandas: 5e-16 against 7.8e-5 rad) is said, with its violations if any
    metrics["methods"]["analytic"] = {"max_drift_rad": 4.86e-16, "limit_violations": 0}
    assert (
        headline(metrics)
        == line + " The analytic law keeps it stiller still (peak drift 4.86e-16 rad)."
    )
    metrics["methods"]["analytic"].update(
        limit_violations=2, limit_violations_by_kind={"velocity": 2}
    )
    assert headline(metrics).endswith(
        " The analytic law keeps it stiller still (peak drift 4.86e-16 rad, with 2 (2 "
        "position/velocity/acceleration, 0 effort) limit violations)."
    )
    metrics["methods"]["analytic"]["max_drift_rad"] = 0.05
    assert headline(metrics) == line


def test_a_penetrating_plan_counts_as_a_violation(paper):
    """A motion whose bodies penetrate is flagged where its limit violations are counted: in
    ``violations``, ``limit_violations``, by kind, and in the words of the CLI and the report."""
    from balance_opt.app.scenarios import capture_task
    from balance_opt.geometry.clearance import ClearanceReport, PairClearance, Penetration
    from balance_opt.motion.replay import phase_one
    from balance_opt.report.outputs import method_metrics
    from balance_opt.report.report import violation_count_text

    scenario = capture_task()
    plan = phase_one(scenario.robot, scenario.mission, scenario.q_B0)
    pair = PairClearance("balance_link3 / base_link", 0, -0.39, 5.0, -0.4)
    report = ClearanceReport((pair,), Penetration(pair.pair, 3.5, 0.39), "collision", 10)
    m = method_metrics(plan, scenario.robot, clearance=report)
    assert m["clearance"]["collision_free"] is False
    assert (
        m["violations"][-1] == "balance_link3 / base_link: collision from t = 3.500 s, 0.39 m deep"
    )
    assert m["limit_violations_by_kind"]["collision"] == 1
    assert m["limit_violations"] == len(m["violations"])
    text = violation_count_text(m["limit_violations"], m["limit_violations_by_kind"])
    assert text.endswith(", 1 collision)")
