"""The figure style and the figure functions: one look per method, readable in greyscale, no
titles, curves labelled with the methods' display names, nothing written unless asked, every
text inside the figure and no legend over the data."""

from itertools import combinations
from types import SimpleNamespace

import matplotlib as mpl
import numpy as np
import pytest
from conftest import curve_labels
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from PIL import Image

from balance_opt.report import style
from balance_opt.report.plots import attitude_figure, reaction_torque_figure

#: The methods a reader compares in one figure: plans, or their simulations.
PLANS = ("mission-only", "analytic", "optimal")
SIMS = tuple(f"{m}:sim" for m in PLANS)
#: Smallest luma difference between methods drawn together (0 black, 1 white).
MIN_LUMA_STEP = 0.25
#: Smallest PNG resolution a journal accepts for line art [dpi].
MIN_DPI = 200


def fake_attitude(rng, T=60, scale=1e-2):
    t = np.linspace(0.0, 2.0, T)
    rpy = np.cumsum(rng.normal(scale=scale, size=(T, 3)), axis=0)
    return SimpleNamespace(t=t, rpy=rpy, angle=np.linalg.norm(rpy, axis=1))


def fake_simulation(rng, scale, T=60):
    t = np.linspace(0.0, 2.0, T)
    wrenches = {
        "mission": scale * rng.normal(size=(T, 6)),
        "balance": scale * rng.normal(size=(T, 6)),
    }
    return SimpleNamespace(
        t=t, arm_wrenches=wrenches, total_wrench=wrenches["mission"] + wrenches["balance"]
    )


def luminance(colour):
    """ITU-R 601 luma, 0 (black) to 1 (white): the grey of a colour in greyscale print."""
    r, g, b = to_rgb(colour)
    return 0.299 * r + 0.587 * g + 0.114 * b


def look(name):
    s = style.method_style(name)
    return (
        round(luminance(s["color"]), 2),
        str(s["linestyle"]),
        s["marker"],
        s.get("fillstyle"),
    )


# ------------------------------------------------------------------------------ the style
def test_every_method_has_its_own_look():
    looks = [look(m) for m in style.METHODS]
    assert len(set(looks)) == len(looks)
    assert len({style.method_label(m) for m in style.METHODS}) == len(style.METHODS)


@pytest.mark.parametrize("group", [PLANS, SIMS])
def test_methods_drawn_together_differ_in_grey_dash_and_marker(group):
    for a, b in combinations(group, 2):
        la, lb = look(a), look(b)
        assert abs(la[0] - lb[0]) >= MIN_LUMA_STEP, (a, b)
        assert la[1] != lb[1] and la[2] != lb[2], (a, b)


def test_a_simulation_keeps_its_plans_colour_and_reads_as_a_simulation():
    for plan in PLANS:
        assert style.method_colour(f"{plan}:sim") == style.method_colour(plan)
        assert look(f"{plan}:sim")[1] != look(plan)[1]
    assert style.method_label("optimal:sim") == "optimal plan (forward dynamics)"
    assert style.method_label("mission-only:kinematic") == "mission arm alone (momentum model)"
    assert style.method_label("my plan") == "my plan"


def test_the_sum_of_arms_does_not_look_like_a_plan():
    for plan in PLANS + SIMS:
        assert look("sum") != look(plan)
    assert style.method_style("sum")["linewidth"] > style.method_style("analytic")["linewidth"]


def test_unknown_width_is_refused():
    with pytest.raises(ValueError, match="figure width must be one of column, page, got 'wide'"):
        style.figure("wide")


# ------------------------------------------------------------------------------ figures
def texts_inside_and_legend_above(fig):
    """Every text inside the figure; the legend above every panel (never over data)."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    box = fig.bbox
    for ax in fig.axes:
        tight = ax.get_tightbbox(renderer)
        assert tight.x0 >= box.x0 - 1 and tight.x1 <= box.x1 + 1, ax.get_ylabel()
        assert tight.y0 >= box.y0 - 1 and tight.y1 <= box.y1 + 1, ax.get_ylabel()
    (legend,) = fig.legends
    lbox = legend.get_window_extent(renderer)
    assert lbox.y1 <= box.y1 + 1 and lbox.x0 >= box.x0 - 1 and lbox.x1 <= box.x1 + 1
    for ax in fig.axes:
        assert lbox.y0 >= ax.get_tightbbox(renderer).y1 - 1


def titles(fig):
    suptitle = fig._suptitle.get_text() if fig._suptitle is not None else ""
    return suptitle, [ax.get_title() for ax in fig.axes]


def test_attitude_figure_writes_nothing_unless_asked(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rng = np.random.default_rng(3)
    results = {"optimal": fake_attitude(rng), "analytic": fake_attitude(rng)}
    fig = attitude_figure({**results, "mission-only": fake_attitude(rng)})
    assert list(tmp_path.iterdir()) == []
    assert titles(fig) == ("", ["", "", ""])
    expected = ["optimal plan", "analytic law", "mission arm alone"]
    assert curve_labels(fig) == [expected] * 3
    for ax in fig.axes:
        for line, name in zip(ax.get_lines(), ["optimal", "analytic", "mission-only"]):
            assert line.get_color() == style.method_colour(name)
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert sorted(x for x in legend if x.strip()) == sorted(expected)
    texts_inside_and_legend_above(fig)


def test_attitude_figure_files_are_one_column_png_and_pdf(tmp_path):
    rng = np.random.default_rng(4)
    stem = tmp_path / "sub" / "fig.v2"
    paths = style.save(attitude_figure({"analytic:sim": fake_attitude(rng)}), stem, ("png", "pdf"))
    assert [p.name for p in paths] == ["fig.v2.png", "fig.v2.pdf"]
    png = Image.open(paths[0])
    assert png.info["dpi"][0] >= MIN_DPI
    assert png.size[0] / png.info["dpi"][0] == pytest.approx(style.WIDTHS["column"], abs=0.02)
    assert paths[1].read_bytes()[:5] == b"%PDF-"


def test_torque_figure_gives_each_plan_its_own_scale():
    rng = np.random.default_rng(6)
    sims = {"analytic": fake_simulation(rng, 0.3), "optimal": fake_simulation(rng, 8.0)}
    fig = reaction_torque_figure(sims)
    assert fig.get_size_inches()[0] == pytest.approx(style.WIDTHS["page"])
    suptitle, panel_titles = titles(fig)
    assert suptitle == "" and set(panel_titles) == {"", "analytic law", "optimal plan"}
    analytic, optimal = fig.axes[0], fig.axes[1]  # first row: x torque of each plan
    assert analytic.get_title() == "analytic law" and optimal.get_title() == "optimal plan"
    span = [np.ptp(ax.get_ylim()) for ax in (analytic, optimal)]
    assert span[0] < span[1] / 10
    assert curve_labels(fig)[0] == ["sum of arms", "mission arm", "analytic law: balance arm"]
    line = {x.get_label(): x for x in analytic.get_lines()}["sum of arms"]
    np.testing.assert_allclose(line.get_ydata(), sims["analytic"].total_wrench[:, 3])
    texts_inside_and_legend_above(fig)


def test_figures_leave_global_state_alone(tmp_path):
    before = dict(mpl.rcParams)
    fig = attitude_figure({"analytic": fake_attitude(np.random.default_rng(0))})
    style.save(fig, tmp_path / "a", ("png",))
    assert dict(mpl.rcParams) == before
    assert not (tmp_path / "a.pdf").exists() and (tmp_path / "a.png").exists()


def fake_plan(joints, rng, T=40):
    t = np.linspace(0.0, 4.0, T)
    n = len(joints)
    q = np.cumsum(rng.normal(scale=0.05, size=(T, n)), axis=0)
    return SimpleNamespace(
        t=t, balance_joints=tuple(joints), q_B=q, q_dot_B=np.gradient(q, t, axis=0), q_ddot_B=q
    )


def test_joint_figure_draws_each_plan_against_the_robots_limits(paper, tmp_path):
    from balance_opt.report.plots import joint_limits_figure

    joints = [j for j in paper.joint_names if "balance" in j]
    rng = np.random.default_rng(7)
    plans = {"analytic": fake_plan(joints, rng), "optimal": fake_plan(joints, rng)}
    fig = joint_limits_figure(plans, paper)
    assert list(tmp_path.iterdir()) == []
    assert titles(fig) == ("", joints + [""] * (2 * len(joints)))
    top = fig.axes[0]
    labels = [line.get_label() for line in top.get_lines()]
    assert labels[:2] == ["analytic law", "optimal plan"]
    i = paper.joint_index(joints[0])
    limit = top.get_lines()[2].get_ydata()
    np.testing.assert_allclose(limit[[0, 3]], [paper.limits.lower[i], paper.limits.upper[i]])
    lo, hi = top.get_ylim()
    assert lo <= paper.limits.lower[i] and hi >= paper.limits.upper[i]
    texts_inside_and_legend_above(fig)
    [path] = style.save(fig, tmp_path / "joints", ("png",), style.SCREEN_DPI)
    assert Image.open(path).info["dpi"][0] == pytest.approx(style.SCREEN_DPI, abs=0.5)


def test_joint_figure_titles_of_long_joint_names_stay_apart():
    """Talos's seven ``arm_right_N_joint`` columns: each title names its joint (broken at an
    underscore), inside its own column's share of the width, and every text in the figure."""
    from balance_opt.model.library import example_urdf
    from balance_opt.model.robot import FloatingRobot
    from balance_opt.report.plots import joint_limits_figure

    arm = [f"arm_right_{i}_joint" for i in range(1, 8)]
    talos = FloatingRobot(example_urdf("talos"), [a.replace("right", "left") for a in arm], arm)
    rng = np.random.default_rng(7)
    fig = joint_limits_figure(
        {"analytic": fake_plan(arm, rng), "optimal": fake_plan(arm, rng)}, talos
    )
    shown = [t for t in titles(fig)[1] if t]
    assert [t.replace("\n", "") for t in shown] == arm
    assert all("\n" in t for t in shown)
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    boxes = [ax.title.get_window_extent(renderer) for ax in fig.axes[: len(arm)]]
    for left, right in zip(boxes, boxes[1:]):
        assert left.x1 < right.x0
    texts_inside_and_legend_above(fig)


def test_sweep_plots_use_the_method_styles(monkeypatch, tmp_path):
    from balance_opt.sweep import report

    figures = []
    monkeypatch.setattr(report, "_save", lambda fig, path: figures.append(fig) or path)
    rng = np.random.default_rng(8)
    records = [
        {
            "index": 2 * k + m,
            "method": method,
            "status": "ok",
            "parameters": {"mission.duration": 5.0 + k},
            "metrics": {"max_drift_rad": rng.uniform(0.01, 0.05), "final_drift_rad": 0.01},
        }
        for k in range(4)
        for m, method in enumerate(("analytic", "optimal"))
    ]
    report.plot_drift_distribution(records, tmp_path / "d.png")
    report.plot_drift_against_parameter(records, "mission.duration", tmp_path / "p.png")
    distribution, against = figures
    steps = distribution.axes[0].get_lines()
    assert [line.get_color() for line in steps] == [
        style.method_colour("analytic"),
        style.method_colour("optimal"),
    ]
    assert [line.get_label() for line in steps] == ["analytic law (4)", "optimal plan (4)"]
    for fig in figures:
        assert titles(fig)[0] == "" and not any(titles(fig)[1])
    scatter = against.axes[0].collections
    assert [c.get_label() for c in scatter] == ["analytic law", "optimal plan"]


# ------------------------------------------------------------------ issue 26: figures
def _rgb(colour):
    return np.array(mpl.colors.to_rgb(colour))


def test_arm_colours_are_no_method_colour_and_the_scenes_use_them():
    from balance_opt.report import scene

    plans = {style.method_colour(m) for m in PLANS}
    others = {style.method_colour(m) for m in style.METHODS} - plans  # the torque parts' grey
    for arm in style.ARM_COLOURS:
        for method in plans:  # far apart in RGB (orange #E69F00 vs vermillion #D55E00: 0.27)
            assert np.linalg.norm(_rgb(arm) - _rgb(method)) > 0.35, (arm, method)
        for other in others:
            assert np.linalg.norm(_rgb(arm) - _rgb(other)) > 0.25, (arm, other)
    assert scene.ARM_COLOURS is style.ARM_COLOURS


def test_joint_figure_keeps_the_limits_in_view_past_a_runaway_plan(paper):
    from balance_opt.report.plots import OFF_SCALE, joint_limits_figure

    joints = [j for j in paper.joint_names if "balance" in j]
    rng = np.random.default_rng(7)
    runaway, optimal = fake_plan(joints, rng), fake_plan(joints, rng)
    runaway.q_dot_B = runaway.q_dot_B.copy()
    runaway.q_dot_B[20, 0] = 5e4
    fig = joint_limits_figure({"analytic": runaway, "optimal": optimal}, paper)
    rate = fig.axes[len(joints)]  # second row, first joint
    limit = paper.limits.velocity[paper.joint_index(joints[0])]
    np.testing.assert_allclose(rate.get_ylim(), [-OFF_SCALE * limit, OFF_SCALE * limit])
    notes = [t.get_text() for t in rate.texts]
    assert notes == ["analytic law off scale (to 5e+04)"]
    assert not fig.axes[0].texts  # the positions stay inside: no clipping, no note


def test_torque_caption_says_how_far_apart_the_scales_are():
    from balance_opt.app.run_files import _torque_scales

    rng = np.random.default_rng(3)
    sims = {"analytic": fake_simulation(rng, 0.01), "optimal": fake_simulation(rng, 0.3)}
    peaks = [max(np.abs(w[:, 3:]).max() for w in s.arm_wrenches.values()) for s in sims.values()]
    text = _torque_scales(sims)
    assert text == (
        f" (analytic law up to {peaks[0]:.3g} N m, optimal plan up to {peaks[1]:.3g} N m: "
        f"the scales differ {peaks[1] / peaks[0]:.3g}x)"
    )


def test_sweep_plots_of_one_case_and_of_a_planner_parameter(monkeypatch, tmp_path):
    from balance_opt.sweep import report

    figures = []
    monkeypatch.setattr(report, "_save", lambda fig, path: figures.append(fig) or path)
    records = [
        {
            "index": m,
            "method": method,
            "status": "ok",
            "parameters": {"optimal.intervals": 40},
            "metrics": {"max_drift_rad": 0.02 + 0.01 * m, "final_drift_rad": 0.01},
        }
        for m, method in enumerate(("analytic", "optimal"))
    ]
    report.plot_drift_distribution(records, tmp_path / "d.png")
    report.plot_drift_against_parameter(records, "optimal.intervals", tmp_path / "p.png")
    distribution, against = figures
    # one case per method: a step through one point draws nothing, its marker does
    assert [line.get_marker() for line in distribution.axes[0].get_lines()] == ["^", "o"]
    # the analytic law does not depend on optimal.* parameters: not drawn against them
    assert [c.get_label() for c in against.axes[0].collections] == ["optimal plan"]


def test_balance_arm_torque_reads_apart_from_the_sum_it_carries():
    """In the optimal plan's panel the balance arm makes most of the sum: it is drawn wide and
    pale under the thin sum, so both read apart in greyscale (issue 26)."""
    rng = np.random.default_rng(4)
    fig = reaction_torque_figure({"optimal": fake_simulation(rng, 1.0)})
    lines = {line.get_label(): line for line in fig.axes[0].get_lines()}
    total, balance = lines["sum of arms"], lines["optimal plan: balance arm"]
    assert balance.get_linewidth() >= 1.5 * total.get_linewidth()
    assert balance.get_zorder() < total.get_zorder()
    grey = luminance(balance.get_color()) * balance.get_alpha() + (1 - balance.get_alpha())
    assert grey - luminance(total.get_color()) >= MIN_LUMA_STEP
