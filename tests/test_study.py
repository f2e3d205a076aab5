"""The figure functions and the paper's study: files written, curves named, physics of the
numbers the study reports."""

import json

import numpy as np
import pytest
from conftest import curve_labels
from PIL import Image

from balance_opt.app.study import FIGURE_STEMS, paper_study
from balance_opt.errors import InputError
from balance_opt.report.style import WIDTHS

#: Smallest PNG resolution a journal accepts for line art [dpi].
MIN_DPI = 200
#: The study's own check: relative momentum residual of every simulation (issue 5).
MOMENTUM_TOLERANCE = 1e-8
#: Attitude gap between a plan and its simulation left when the tracking is exact (the plan's
#: own torques as feedforward): the two integrations' own errors [rad].
INTEGRATION_FLOOR = 1e-9

ATTITUDE_LABELS = ["roll [deg]", "pitch [deg]", "yaw [deg]"]
TORQUE_LABELS = ["torque x [N m]", "torque y [N m]", "torque z [N m]"]


def check_files(paths, stem, width="column"):
    assert sorted(p.suffix for p in paths) == [".pdf", ".png"]
    for p in paths:
        assert p.with_suffix("") == stem and p.stat().st_size > 5000
    png = Image.open(stem.with_suffix(".png"))
    dpi = png.info["dpi"][0]
    assert dpi >= MIN_DPI
    assert png.size[0] / dpi == pytest.approx(WIDTHS[width], abs=0.05)  # a column or a page
    assert stem.with_suffix(".pdf").read_bytes()[:5] == b"%PDF-"


# ------------------------------------------------------------------------------ the study
#: What the paper's Fig. 5 shows, asked of the law on paper_fig5 in the forward-dynamics
#: simulation (joint PD tracking): final attitude error this many times below the mission arm's.
FIG5_RATIO = 20.0


@pytest.fixture(scope="module")
def paper(tmp_path_factory):
    out = tmp_path_factory.mktemp("study")
    return paper_study(out)


@pytest.fixture(scope="module")
def study(paper):
    """The capture-task part: the law against the optimal plan."""
    return paper.parts["capture_task"]


@pytest.mark.slow
def test_study_writes_every_figure(paper):
    summary = json.loads((paper.output_dir / "study.json").read_text())
    assert set(summary) == set(paper.parts) == {"paper_fig5", "capture_task"}
    for name, part in paper.parts.items():
        out = paper.output_dir / name
        assert part.output_dir == out
        for key, stem in FIGURE_STEMS.items():
            # Fig. 4: a column of panels per plan, a page wide for two plans or more
            wide = key == "fig4" and len(summary[name]["plans"]) > 1
            check_files(part.figures[key], out / stem, "page" if wide else "column")
            assert paper.figures[f"{name}/{key}"] == part.figures[key]
        assert summary[name]["figures"]["fig4"] == [
            f"{FIGURE_STEMS['fig4']}.png",
            f"{FIGURE_STEMS['fig4']}.pdf",
        ]
        assert json.loads((out / "study.json").read_text()) == summary[name]
    assert set(summary["capture_task"]["plans"]) == {"analytic", "optimal"}
    assert set(summary["paper_fig5"]["plans"]) == {"analytic"}


@pytest.mark.slow
def test_study_figures_show_both_plans(study):
    figs = study.figure_objects
    sim = " (forward dynamics)"
    assert (
        curve_labels(figs["fig2"])
        == [[f"mission arm alone{sim}", "mission arm alone (momentum model)"]] * 3
    )
    assert curve_labels(figs["fig3"]) == [[f"analytic law{sim}", f"optimal plan{sim}"]] * 3
    assert (
        curve_labels(figs["fig5"])
        == [[f"analytic law{sim}", f"optimal plan{sim}", f"mission arm alone{sim}"]] * 3
    )
    parts = ["sum of arms", "mission arm"]
    assert curve_labels(figs["fig4"]) == [
        [*parts, f"{plan}: balance arm"]
        for _ in range(3)
        for plan in ("analytic law", "optimal plan")
    ]
    for name in ("fig2", "fig3", "fig5"):
        assert [ax.get_ylabel() for ax in figs[name].axes] == ATTITUDE_LABELS
    assert [ax.get_ylabel() for ax in figs["fig4"].axes[::2]] == TORQUE_LABELS


@pytest.mark.slow
def test_study_numbers(study):
    """The study's simulations conserve momentum, reproduce their plans' attitude within their
    tracking error, and Phase I turns the base by the known ~0.093 rad."""
    summary = study.summary
    assert {m: p["status"] for m, p in summary["plans"].items()} == {
        "analytic": "ok",
        "optimal": "ok",
    }
    assert summary["mission_only"]["max_drift_rad"] == pytest.approx(0.093, abs=0.002)
    sims = [study.mission_only, *study.balance_only.values(), *study.balanced.values()]
    assert max(s.momentum_residual.max() for s in sims) <= MOMENTUM_TOLERANCE
    for method, plan in study.plans.items():
        sim = study.balanced[method]
        np.testing.assert_allclose(sim.t, plan.t, rtol=0, atol=1e-9)
        gap = np.abs(sim.angle - plan.angle).max()
        assert gap <= sim.max_tracking_error + INTEGRATION_FLOOR, method
        assert summary["plans"][method]["limit_violations"] == [str(v) for v in plan.violations]
        torque = summary["plans"][method]["balanced"]["peak_torque_on_base_Nm"]
        assert set(torque) == {"mission", "balance", "total"}
        rate = summary["plans"][method]["balanced"]["peak_base_rate_rad_s"]
        assert rate == pytest.approx(np.linalg.norm(sim.omega, axis=1).max(), rel=1e-12)
    # the balance arm alone does not simply undo the mission arm (non-holonomic)
    fig3 = study.balance_only["analytic"].rpy[-1]
    assert np.abs(fig3 + study.mission_only.rpy[-1]).max() > 1e-3


@pytest.mark.slow
def test_paper_fig5_part_shows_what_the_papers_fig5_shows(paper):
    """Forward dynamics with both arms tracking exact Eq. 31: the base ends at least 20 times
    closer to its start than with the mission arm alone, momentum conserved, every balance
    limit held by the plan."""
    part = paper.parts["paper_fig5"]
    assert part.summary["plans"]["analytic"]["status"] == "ok"
    assert part.plans["analytic"].info["law"]["damping_threshold"] == 0
    alone, balanced = part.mission_only, part.balanced["analytic"]
    assert alone.angle[-1] > 0.05
    assert alone.angle[-1] / balanced.angle[-1] >= FIG5_RATIO
    assert max(s.momentum_residual.max() for s in (alone, balanced)) <= MOMENTUM_TOLERANCE
    assert part.plans["analytic"].violations == []


def test_study_rejects_unknown_methods(tmp_path):
    with pytest.raises(
        InputError, match=r"study methods must be among analytic, optimal, got \['exact'\]"
    ):
        paper_study(tmp_path, methods=("exact",))


@pytest.mark.slow
def test_study_progress_names_what_each_simulation_simulates(tmp_path, caplog):
    import logging

    from balance_opt.app.scenarios import capture_task
    from balance_opt.app.study import scenario_study
    from balance_opt.dynamics.options import SimulationOptions

    caplog.set_level(logging.INFO, logger="balance_opt")
    fast = SimulationOptions(dt=0.002, output_dt=0.05)
    scenario_study(
        capture_task(), tmp_path, methods=("analytic",), simulation=fast, formats=("png",)
    )
    done = [r.getMessage() for r in caplog.records if r.getMessage().endswith(" ...")]
    assert [m for m in done if "simulation" in m] == [
        "capture_task: forward-dynamics simulation of the mission arm alone (Fig. 2) ...",
        "capture_task: forward-dynamics simulation of the analytic plan's balance arm alone "
        "(Fig. 3) ...",
        "capture_task: forward-dynamics simulation of the analytic plan (Figs. 4, 5) ...",
    ]
