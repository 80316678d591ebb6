"""Model comparison by PSIS-LOO (fitting.loo, fitting.compare_models) on simulated data: the
pointwise log likelihood against an independent computation, and the generating model ahead of
a wrong one."""

import math

import numpy as np
import pytest
from scipy.stats import norm

import fitting
import jaximpact as ji

SIGMA = 0.003


@pytest.fixture(scope="module")
def two_models(tmp_path_factory):
    """Ten normal impacts of the Table 1 sphere (C_H 0.25 s/m), posteriors of C_A and f0 with
    C_H at its true value and at a wrong one (0.4 s/m)."""
    truth = ji.table1_scene().replace(contact=dict(C_A=0.75, C_H=0.25, f0=300.0))
    speed = np.geomspace(0.2, 5.0, 10)
    clean = np.asarray(ji.simulate(truth, speed, 0.0, 0.0).cor_n)
    y = clean + SIGMA * np.random.default_rng(1).standard_normal(speed.size)
    path = tmp_path_factory.mktemp("loo") / "data.csv"
    rows = [f"{float(s)!r},0.0,cor_n,{float(v)!r},{SIGMA}" for s, v in zip(speed, y, strict=True)]
    path.write_text("speed,angle_deg,observable,value,sigma\n" + "\n".join(rows) + "\n")
    priors = {"C_A": "loguniform:0.2:3", "f0": "loguniform:75:1200"}
    posts = {
        # 4 x 500 draws: PSIS-LOO's Pareto k is stable from about 1,000 draws
        label: fitting.sample_posterior(
            scene, path, ["C_A", "f0"], priors=priors, draws=500, starts=1, progress=False
        )
        for label, scene in (
            ("true C_H", truth),
            ("C_H 0.4", truth.replace(contact=dict(C_H=0.4))),
        )
    }
    return truth, speed, y, posts


@pytest.mark.slow  # two posteriors of the simulator
def test_pointwise_log_likelihood_is_the_gaussian_density_of_each_observation(two_models):
    truth, speed, y, posts = two_models
    post = posts["true C_H"]
    ll = fitting.pointwise_log_likelihood(post, max_draws=40)
    assert ll.shape == (post.chains, 10, 10)
    for c, d in ((0, 0), (3, 9)):
        k = np.linspace(0, post.draws.shape[1] - 1, 10).astype(int)[d]
        C_A, f0 = post.draws[c, k]
        # as the sampler integrates (rtol 1e-7, atol 1e-9, the motion only): against defaults the
        # log densities of tail draws differ by a few 1e-3 (cor_n by ~1e-6, times r / sigma^2)
        scene = truth.replace(
            contact=dict(C_A=C_A, f0=f0), solver=dict(rtol=1e-7, atol=1e-9, outputs="rebound")
        )
        model = ji.simulate(scene, speed, 0.0, 0.0).cor_n
        expected = norm.logpdf(y, np.asarray(model), SIGMA)
        np.testing.assert_allclose(ll[c, d], expected, atol=1e-6)


@pytest.mark.slow  # two posteriors of the simulator
def test_compare_models_puts_the_generating_model_first(two_models):
    _, _, _, posts = two_models
    rows = fitting.compare_models(posts)
    assert [r["name"] for r in rows] == ["true C_H", "C_H 0.4"]
    best, wrong = rows
    assert best["elpd_diff"] == 0.0 and wrong["elpd_diff"] < -2 * wrong["se_diff"]
    # the true model's elpd: n (-log sigma - log sqrt(2 pi) - 1/2), give or take its spread
    n = 10
    expected = n * (-math.log(SIGMA) - 0.5 * math.log(2 * math.pi) - 0.5)
    assert abs(best["elpd"] - expected) < 4 * math.sqrt(n / 2)
    assert wrong["problems"]  # a misfit's influential points: Pareto k above 0.7, said
    with pytest.raises(fitting.FitError, match="at least two"):
        fitting.compare_models({"one": posts["true C_H"]})


def _scene_file(path, C_H):
    """The Table 1 sphere as a scene file with C_A, C_H and f0 given directly."""
    text = ji.default_scene_path().read_text()
    text = text.replace("f0 = 325.0", f"f0 = 300.0\nC_A = 0.75\nC_H = {C_H}")
    text = "\n".join(ln for ln in text.splitlines() if not ln.startswith(("zeta_", "reference_")))
    path.write_text(text + "\n")
    assert ji.load_scene(path).contact.C_H == pytest.approx(C_H)
    return path


@pytest.mark.slow  # two fits and posteriors through the command line
def test_cli_compare_ranks_the_generating_scene_first(two_models, tmp_path, capsys):
    import json

    from jaximpact.cli import main

    truth, speed, y, _ = two_models
    data = tmp_path / "data.csv"
    rows = [f"{float(s)!r},0.0,cor_n,{float(v)!r},{SIGMA}" for s, v in zip(speed, y, strict=True)]
    data.write_text("speed,angle_deg,observable,value,sigma\n" + "\n".join(rows) + "\n")
    right, wrong = _scene_file(tmp_path / "right.toml", 0.25), _scene_file(tmp_path / "w.toml", 0.4)
    out, plot = tmp_path / "fit.json", tmp_path / "compare.png"
    code = main([
        "fit", str(wrong), str(data), "--params", "C_A,f0", "--posterior", "--samples", "500",
        "--prior", "C_A=loguniform:0.2:3", "f0=loguniform:75:1200", "--compare", str(right),
        "--compare-plot", str(plot), "-o", str(out), "--no-progress", "--starts", "1",
    ])  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "model comparison by PSIS-LOO" in printed.out
    loo_rows = json.loads(out.read_text())["comparison"]["loo"]
    assert [r["name"] for r in loo_rows] == [str(right), str(wrong)]
    assert loo_rows[1]["elpd_diff"] < -2 * loo_rows[1]["se_diff"]
    assert f"{right} predicts better than {wrong}" in printed.out
    assert plot.stat().st_size > 0


def test_comparison_summary_says_which_differences_exceed_two_standard_errors():
    from fitting._bayesian.report import comparison_summary

    def row(name, elpd, diff, se_diff, problems=()):
        return dict(name=name, elpd=elpd, se=3.0, elpd_diff=diff, se_diff=se_diff, p_loo=2.0,
                    max_khat=0.3, problems=list(problems))  # fmt: skip

    text = comparison_summary([
        row("a.toml", 40.0, 0.0, 0.0), row("b.toml", 30.0, -10.0, 4.0),
        row("c.toml", 38.0, -2.0, 1.5, ["1 observation(s) with Pareto k above 0.7 (rows 3)"]),
    ])  # fmt: skip
    assert "a.toml predicts better than b.toml" in text
    assert "a.toml and c.toml: within 2 standard errors" in text
    flagged = comparison_summary([
        row("a.toml", 40.0, 0.0, 0.0), row("d.toml", 30.0, -10.0, 4.0, ["k above 0.7"]),
    ])  # fmt: skip
    assert "a.toml predicts better than d.toml (more than 2 standard errors of the " \
        "difference), but the estimate includes observations with Pareto k above 0.7" \
        in flagged  # fmt: skip
    assert "c.toml: 1 observation(s) with Pareto k above 0.7" in text
    assert text.splitlines()[2].split()[:2] == ["a.toml", "40.00"]
