"""The stage form of ``benchmarks/stage_form.py`` (fatrop's structure) is the planner's NLP:
the same cost, and the same rows up to order plus the gap rows, at any point."""

import sys
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))


@pytest.fixture(scope="module")
def problems():
    from bench_solvers import _problems

    return _problems(intervals=6, compile_kernels=False)


@pytest.mark.parametrize("name", ["integral", "epigraph"])
def test_stage_form_has_the_planners_cost_and_rows(problems, name):
    from stage_form import stage_form

    problem, w0, captured = problems[name]
    form = stage_form(problem, captured)
    original = cs.Function("nlp", [captured["x"], captured["p"]], [captured["f"], captured["g"]])
    staged = cs.Function("staged", [form.nlp["x"]], [form.nlp["f"], form.nlp["g"]])
    rng = np.random.default_rng(3)
    w = w0 + 0.05 * rng.standard_normal(w0.size)
    f, g = (np.array(v).ravel() for v in original(w, problem.parameters))
    f_s, g_s = (np.array(v).ravel() for v in staged(form.to_stages(w)))
    assert f_s[0] == pytest.approx(f[0], rel=1e-12)
    # the gap rows vanish at a consistent point; the others are the planner's, reordered
    n_gap = sum(form.structure["nx"][1:])
    assert g_s.size == g.size + n_gap
    gap = np.zeros(g_s.size, bool)
    pos = 0
    for k, ng in enumerate(form.structure["ng"]):
        if k < form.structure["N"]:
            gap[pos : pos + form.structure["nx"][k + 1]] = True
            pos += form.structure["nx"][k + 1]
        pos += ng
    np.testing.assert_allclose(g_s[gap], 0.0, atol=1e-14)
    np.testing.assert_allclose(np.sort(g_s[~gap]), np.sort(g), rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(form.from_stages(form.to_stages(w)), w)
    # fatrop accepts the declared structure (it checks the Jacobian's block pattern)
    cs.nlpsol("check", "fatrop", form.nlp, {"structure_detection": "manual", **form.structure})
