"""Mission trajectories: the quintic point-to-point move, via points, CSV files, sampled arrays
(replays) and Cartesian goals solved by inverse kinematics.

Derivatives are checked against Richardson-extrapolated central differences of the positions
(and velocities); Cartesian goals against forward kinematics computed here with Pinocchio.
"""

import itertools

import numpy as np
import pinocchio as pin
import pytest

from balance_opt.errors import TrajectoryError
from balance_opt.motion.trajectories import (
    IK_POSITION_TOLERANCE,
    CsvTrajectory,
    PointToPoint,
    SampledTrajectory,
    ViaPoints,
    cartesian_goal,
    solve_cartesian_goal,
)

#: Richardson-extrapolated central differences with step FD_STEP [s]: truncation O(h^4) ~ 1e-12,
#: rounding ~ 1e-16 / h ~ 1e-12.
FD_STEP = 1e-4
FD_ATOL = 1e-8


def _derivative(f, t, h=FD_STEP):
    d1 = (f(t + h) - f(t - h)) / (2 * h)
    d2 = (f(t + 2 * h) - f(t - 2 * h)) / (4 * h)
    return (4 * d1 - d2) / 3


def _check_consistent(traj, t):
    """q_dot and q_ddot are the time derivatives of q and q_dot."""
    _q, q_dot, q_ddot = traj.sample(t)
    np.testing.assert_allclose(
        q_dot, _derivative(lambda s: traj.sample(s)[0], t), rtol=0, atol=FD_ATOL
    )
    np.testing.assert_allclose(
        q_ddot, _derivative(lambda s: traj.sample(s)[1], t), rtol=0, atol=FD_ATOL
    )


def _fk(robot, arm, q_arm):
    """End-effector pose of ``arm`` at its joints ``q_arm``, base at the identity."""
    q = robot.neutral()
    q[robot.arm(arm).indices] = q_arm
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, robot.pin_q(q))
    return data.oMf[robot.model.getFrameId(robot.arm(arm).ee_frame)]


# ---------------------------------------------------------------------------------- joint space
def test_point_to_point_is_quintic_rest_to_rest():
    q0, qf = np.array([0.0, 0.3, -0.6]), np.array([1.2, 0.9, -1.6])
    traj = PointToPoint(q0, qf, 10.0)
    q, q_dot, q_ddot = traj.sample(np.array([0.0, 5.0, 10.0]))
    np.testing.assert_allclose(q[[0, 2]], [q0, qf], rtol=0, atol=1e-15)
    np.testing.assert_allclose(q[1], 0.5 * (q0 + qf), rtol=0, atol=1e-15)
    np.testing.assert_allclose(q_dot[[0, 2]], 0.0, rtol=0, atol=0)
    np.testing.assert_allclose(q_ddot[[0, 1, 2]], 0.0, rtol=0, atol=1e-15)
    np.testing.assert_allclose(
        q_dot[1], 1.875 * (qf - q0) / 10.0, rtol=0, atol=1e-15
    )  # peak of 30 s^2(1-s)^2
    _check_consistent(traj, np.linspace(0.1, 9.9, 37))


def test_via_points_pass_through_points_smoothly():
    times = [0.0, 1.0, 2.5, 4.0]
    points = np.array([[0.0, 0.0], [0.5, -0.2], [0.3, 0.4], [1.0, 0.1]])
    traj = ViaPoints(times, points)
    q, q_dot, q_ddot = traj.sample(np.array(times))
    np.testing.assert_allclose(q, points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q_dot[[0, -1]], 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(q_ddot[[0, -1]], 0.0, rtol=0, atol=1e-12)
    _check_consistent(traj, np.linspace(0.05, 3.95, 41))
    # C2 at the via points: accelerations just before and after agree
    eps = 1e-7
    for t in times[1:-1]:
        np.testing.assert_allclose(
            traj.sample(np.array([t - eps]))[2],
            traj.sample(np.array([t + eps]))[2],
            rtol=0,
            atol=1e-5,
        )


def test_csv_trajectory_reads_columns_by_name(tmp_path):
    t = np.linspace(0.0, 2.0, 21)
    path = tmp_path / "mission.csv"
    rows = ["time,other,j2,j1"] + [f"{ti},{9.0},{np.cos(ti)},{np.sin(ti)}" for ti in t]
    path.write_text("\n".join(rows) + "\n")
    traj = CsvTrajectory(path, ["j1", "j2"])
    assert traj.duration == 2.0 and traj.dof == 2
    q, _, _ = traj.sample(t)
    np.testing.assert_allclose(q, np.c_[np.sin(t), np.cos(t)], rtol=0, atol=1e-12)
    q_mid, q_dot_mid, _ = traj.sample(np.array([1.05]))
    np.testing.assert_allclose(
        q_mid[0], [np.sin(1.05), np.cos(1.05)], rtol=0, atol=1e-5
    )  # cubic, h = 0.1
    np.testing.assert_allclose(q_dot_mid[0], [np.cos(1.05), -np.sin(1.05)], rtol=0, atol=1e-3)


def test_csv_errors_name_file_line_and_column(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("time,j1\n0,0.0\n0.1,abc\n0.2,0.3\n")
    with pytest.raises(
        TrajectoryError, match=r"bad\.csv: line 3, column 'j1': not a number: 'abc'"
    ):
        CsvTrajectory(path, ["j1"])
    with pytest.raises(TrajectoryError, match=r"bad\.csv: line 1: missing column\(s\) j2"):
        CsvTrajectory(path, ["j2"])


# ---------------------------------------------------------------------------------- sampled arrays
def test_sampled_quintic_hermite_reproduces_a_quintic_exactly():
    """The PTP is one quintic polynomial: quintic Hermite through 6 of its samples is exact."""
    ptp = PointToPoint([0.0, 1.0], [2.0, -1.0], 3.0)
    t = np.linspace(0.0, 3.0, 6)
    sampled = SampledTrajectory(t, *ptp.sample(t))
    t_fine = np.random.default_rng(0).uniform(0.0, 3.0, 200)
    for a, b in zip(sampled.sample(t_fine), ptp.sample(t_fine)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_sampled_interpolation_orders():
    t = np.linspace(0.0, 1.0, 101)
    q, q_dot = np.sin(3 * t)[:, None], 3 * np.cos(3 * t)[:, None]
    t_mid = t[:-1] + 0.005
    cubic = SampledTrajectory(t, q, q_dot).sample(t_mid)[0][:, 0]
    spline = SampledTrajectory(t, q).sample(t_mid)[0][:, 0]
    # cubic Hermite: error h^4 |d4q| / 384 ~ 2e-9; natural spline: ~h^4 away from the ends
    np.testing.assert_allclose(cubic, np.sin(3 * t_mid), rtol=0, atol=1e-8)
    np.testing.assert_allclose(spline[10:-10], np.sin(3 * t_mid[10:-10]), rtol=0, atol=1e-7)
    # outside the samples the arm rests at the end
    q_out, q_dot_out, q_ddot_out = SampledTrajectory(t, q, q_dot).sample(np.array([1.5]))
    np.testing.assert_allclose(q_out, q[-1:], rtol=0, atol=1e-15)
    assert q_dot_out[0, 0] == 0.0 and q_ddot_out[0, 0] == 0.0


def test_sampled_trajectory_errors():
    with pytest.raises(TrajectoryError, match="times must start at 0 and increase strictly"):
        SampledTrajectory([0.0, 0.2, 0.1], np.zeros((3, 2)))
    with pytest.raises(
        TrajectoryError, match=r"velocities have shape \(3, 1\), positions \(3, 2\)"
    ):
        SampledTrajectory([0.0, 0.1, 0.2], np.zeros((3, 2)), np.zeros((3, 1)))
    with pytest.raises(TrajectoryError, match="accelerations given without velocities"):
        SampledTrajectory([0.0, 0.1], np.zeros((2, 2)), None, np.zeros((2, 2)))


# ---------------------------------------------------------------------------------- Cartesian goals
def test_cartesian_position_goal_reached(paper):
    target = np.array([1.2, 0.9, -1.6])
    goal = _fk(paper, "mission", target).translation
    start = np.array([0.0, 0.3, -0.6])
    traj = cartesian_goal(paper, start, goal, 10.0)
    assert isinstance(traj, PointToPoint) and traj.duration == 10.0
    np.testing.assert_allclose(traj.start, start, rtol=0, atol=0)
    assert (
        np.linalg.norm(_fk(paper, "mission", traj.end).translation - goal) <= IK_POSITION_TOLERANCE
    )
    lim = paper.limits.subset(paper.mission_indices)
    assert np.all(traj.end >= lim.lower) and np.all(traj.end <= lim.upper)


def test_cartesian_pose_goal_on_a_7_dof_arm(baxter):
    target = np.array([0.3, -0.5, 0.2, 1.0, 0.1, 0.5, 0.2])
    pose = _fk(baxter, "mission", target)
    start = baxter.neutral()[baxter.mission_indices]
    q_goal = solve_cartesian_goal(baxter, start, pose.translation, pose.rotation)
    reached = _fk(baxter, "mission", q_goal)
    assert np.linalg.norm(reached.translation - pose.translation) <= IK_POSITION_TOLERANCE
    assert np.linalg.norm(pin.log3(reached.rotation.T @ pose.rotation)) <= 1e-6
    # the same goal given as a quaternion (x, y, z, w)
    quat = pin.Quaternion(pose.rotation).coeffs()
    q_goal2 = solve_cartesian_goal(baxter, start, pose.translation, quat)
    np.testing.assert_allclose(
        _fk(baxter, "mission", q_goal2).homogeneous, pose.homogeneous, rtol=0, atol=1e-6
    )


def test_unreachable_goal_reports_remaining_distance(paper):
    """The remaining distance is no worse than the best of many random configurations, and no
    better than the distance from the arm's first joint minus the arm's reach (the sum of the
    distances between its joints and end effector bounds it)."""
    lim = paper.limits.subset(paper.mission_indices)
    rng = np.random.default_rng(1)
    samples = rng.uniform(lim.lower, lim.upper, (400, 3))
    points = np.array([_fk(paper, "mission", q).translation for q in samples])
    data = paper.model.createData()
    pin.framesForwardKinematics(paper.model, data, paper.pin_q(paper.neutral()))
    chain = [data.oMi[paper.model.getJointId(j)].translation for j in paper.mission.joints]
    chain.append(data.oMf[paper.model.getFrameId(paper.mission.ee_frame)].translation)
    shoulder = chain[0]
    reach = sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(chain))
    goal = shoulder + np.array([3.0, 1.0, 2.0])
    with pytest.raises(
        TrajectoryError, match=r"unreachable within the joint limits: remaining distance [0-9.]+ m"
    ) as err:
        cartesian_goal(paper, [0.0, 0.3, -0.6], goal, 5.0)
    assert err.value.distance <= np.linalg.norm(points - goal, axis=1).min() + 1e-9
    assert err.value.distance >= np.linalg.norm(goal - shoulder) - reach - 1e-9
    assert f"{err.value.distance:.6g} m" in str(err.value)
    # where the end effector got to, and where it started (issue 26)
    closest = err.value.closest
    assert np.linalg.norm(goal - closest) == pytest.approx(err.value.distance, rel=1e-9)
    assert "the closest point reached is [" + ", ".join(f"{x:.4g}" for x in closest) in str(
        err.value
    )
    start = _fk(paper, "mission", np.array([0.0, 0.3, -0.6])).translation
    said = str(err.value).split("the end effector starts at [")[1].removesuffix("] m")
    np.testing.assert_allclose([float(x) for x in said.split(", ")], start, rtol=1e-3, atol=1e-12)


def test_cartesian_goal_input_errors(paper):
    with pytest.raises(TrajectoryError, match="position must be 3 finite numbers"):
        solve_cartesian_goal(paper, [0.0, 0.0, 0.0], (1.0, 2.0))
    with pytest.raises(TrajectoryError, match="orientation matrix is not a rotation"):
        solve_cartesian_goal(paper, [0.0, 0.0, 0.0], (1.0, 2.0, 3.0), 2 * np.eye(3))
    with pytest.raises(TrajectoryError, match="the mission arm has 3 joints, start has 2"):
        solve_cartesian_goal(paper, [0.0, 0.0], (1.0, 2.0, 3.0))
