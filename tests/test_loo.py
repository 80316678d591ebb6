"""Model comparison by PSIS-LOO (fitting.loo, fitting.compare_models) on simulated data: the
pointwise log likelihood against an independent computation, and the generating model ahead of
a wrong one; exact leave-one-out refits (``refit=``) against PSIS where PSIS is reliable and
against a posterior of the data set without the observation, sampled apart."""

import math

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.special import logsumexp
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
        "--loo-refits", "1",
    ])  # fmt: skip
    printed = capsys.readouterr()
    assert code == 0, printed.err
    assert "model comparison by PSIS-LOO" in printed.out
    loo_rows = json.loads(out.read_text())["comparison"]["loo"]
    assert [r["name"] for r in loo_rows] == [str(right), str(wrong)]
    assert loo_rows[1]["elpd_diff"] < -2 * loo_rows[1]["se_diff"]
    # the misfit has observations with k above 0.7: one refitted exactly (the cap), said
    misfit = loo_rows[1]
    assert misfit["refitted"] == 1 and f"refitting model {wrong} without observation" in printed.err
    assert "(1 of 1)" in printed.err and any("refitted exactly" in p for p in misfit["problems"])
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


# -- exact leave-one-out refits ---------------------------------------------------------------


def _log_mean_exp(ll):
    ll = np.asarray(ll, float).ravel()
    return float(logsumexp(ll) - math.log(ll.size))


def _monte_carlo_sd(ll, ess=400):
    """Standard deviation of ``log mean p`` over ``ess`` independent draws: the coefficient of
    variation of ``p = exp(ll)`` over sqrt(ess) (delta method). 400 is the bulk and tail ESS
    that a converged SMC run has at least (posterior.MIN_ESS); its particles are correlated,
    so the 2,000 draws are not worth more."""
    p = np.exp(np.asarray(ll, float).ravel() - np.max(ll))
    return float(np.std(p) / np.mean(p) / math.sqrt(ess))


def _held_out_log_likelihood(full, draws, y_i, i):
    """Gaussian log density of ``y_i`` at the model value of observation ``i`` for each draw
    ``(C_A, f0)``: the full posterior's model program (model values, no residual or noise
    code of the LOO module), scipy's density."""
    U = np.stack([fitting.to_unbounded(full.params, t) for t in draws.reshape(-1, 2)])
    model = np.asarray(full.program(jnp.asarray(U)))[:, i]
    return norm.logpdf(y_i, model, SIGMA)


@pytest.mark.slow  # three refits of a posterior of the simulator
def test_exact_refits_agree_with_psis_where_psis_is_reliable(two_models):
    _, _, _, posts = two_models
    post = posts["true C_H"]
    psis = fitting.loo(post)
    rows = [int(i) for i in np.argsort(psis.khat)[:3]]
    assert np.all(psis.khat[rows] < 0.5)  # PSIS reliable (finite variance) there
    exact = fitting.loo(post, refit=True, rows=rows)
    assert sorted(rows) == exact.refitted.tolist() and not exact.refits_not_converged.size
    assert exact.problems[0].startswith("3 observation(s) refitted exactly")
    ll = fitting.pointwise_log_likelihood(post)
    for i in rows:
        # both estimate log p(y_i | y_-i); each is off by its Monte Carlo error (about the
        # same: the same draws, PSIS's weights near 1 where k < 0.5): 4 sd of the difference
        tol = 4 * math.sqrt(2) * _monte_carlo_sd(ll[..., i])
        assert abs(exact.pointwise[i] - psis.pointwise[i]) < tol, (i, tol)
    others = np.setdiff1d(np.arange(10), rows)
    np.testing.assert_array_equal(exact.pointwise[others], psis.pointwise[others])
    np.testing.assert_array_equal(exact.pointwise_psis, psis.pointwise)
    assert exact.elpd == pytest.approx(np.sum(exact.pointwise), rel=1e-12)
    assert exact.se == pytest.approx(math.sqrt(10 * np.var(exact.pointwise)), rel=1e-12)
    assert exact.p_loo - psis.p_loo == pytest.approx(psis.elpd - exact.elpd, abs=1e-9)


@pytest.mark.slow  # a refit, and a fit and posterior of the reduced data set
def test_exact_refit_equals_the_posterior_of_the_data_without_the_observation(two_models, tmp_path):
    truth, speed, y, posts = two_models
    post = posts["true C_H"]
    assert np.array_equal(post.fit.objective.observations.speed, speed)  # rows in file order
    i = 6
    without = fitting.refit_without(post, i)
    assert without.converged and without.left_out == (i,)
    everything = without.draws.shape[0] * without.draws.shape[1]
    ll = fitting.pointwise_log_likelihood(without, max_draws=everything)[..., i]
    expected = _held_out_log_likelihood(post, without.draws, y[i], i)
    np.testing.assert_allclose(ll.ravel(), expected, atol=1e-8)
    exact = fitting.loo(post, max_draws=everything, refit=lambda k: without, rows=[i])
    assert exact.pointwise[i] == pytest.approx(_log_mean_exp(expected), abs=1e-8)
    # the same posterior sampled apart: the data file without row i, its own fit and program
    path = tmp_path / "without.csv"
    keep = [k for k in range(speed.size) if k != i]
    rows = [f"{float(speed[k])!r},0.0,cor_n,{float(y[k])!r},{SIGMA}" for k in keep]
    path.write_text("speed,angle_deg,observable,value,sigma\n" + "\n".join(rows) + "\n")
    apart = fitting.sample_posterior(
        truth, path, ["C_A", "f0"], priors=post.priors, draws=500, starts=1, progress=False
    )
    assert apart.converged
    ll_apart = _held_out_log_likelihood(post, apart.draws, y[i], i)
    tol = 4 * math.hypot(_monte_carlo_sd(expected), _monte_carlo_sd(ll_apart))
    assert abs(exact.pointwise[i] - _log_mean_exp(ll_apart)) < tol, tol
    # and the refit is not the full posterior: the held-out row's density falls without it
    assert exact.pointwise[i] < _log_mean_exp(fitting.pointwise_log_likelihood(post)[..., i])


def test_exact_loo_refits_replace_the_terms_and_recompute_the_totals(monkeypatch):
    """The bookkeeping, on a stand-in posterior: each refit's log likelihood is given."""
    from fitting._bayesian import loo as loo_module

    n, S = 5, 8
    rng = np.random.default_rng(0)
    held = {i: rng.normal(-1.0, 0.5, (2, S // 2, n)) for i in (1, 3)}

    class Refit:
        def __init__(self, i, converged=True):
            self.i, self.left_out, self.converged = i, (i,), converged

    monkeypatch.setattr(loo_module, "pointwise_log_likelihood", lambda r, m: held[r.i])
    psis = fitting.LOO(
        elpd=-6.0, se=1.0, p_loo=2.0, pointwise=np.array([-1.0, -2.0, -1.0, -1.5, -0.5]),
        khat=np.array([0.1, 0.9, 0.2, 0.8, 0.75]), draws=S, problems=[],
    )  # fmt: skip
    said = []
    out = fitting.exact_loo_refits(
        psis, [3, 1], lambda i: Refit(i, converged=i != 3), 1000,
        announce=lambda i, k, total: said.append((i, k, total)),
    )  # fmt: skip
    assert said == [(3, 1, 2), (1, 2, 2)]
    expected = psis.pointwise.copy()
    for i in (1, 3):
        expected[i] = _log_mean_exp(held[i][..., i])
    np.testing.assert_allclose(out.pointwise, expected, rtol=1e-14)
    assert out.elpd == pytest.approx(expected.sum()) and out.p_loo == pytest.approx(
        2.0 - 6.0 - expected.sum()
    )
    assert out.se == pytest.approx(math.sqrt(n * np.var(expected)))
    assert out.refitted.tolist() == [1, 3] and out.refits_not_converged.tolist() == [3]
    assert out.unreliable.tolist() == [3, 4]  # row 4: k 0.75, not refitted
    problems = loo_module._problems(out)
    assert problems[0].startswith("1 observation(s) refitted exactly (rows 2;")
    assert "1 exact refit(s) did not converge (rows 4)" in problems[1]
    assert problems[2].startswith("1 observation(s) with Pareto k above 0.7 (rows 5)")
    # the default choice: k above 0.7, highest first, capped
    assert loo_module._rows_to_refit(psis.khat, 2) == [1, 3]
    assert loo_module._rows_to_refit(psis.khat, 0) == []
    with pytest.raises(fitting.FitError, match="must lie in"):
        fitting.exact_loo_refits(psis, [5], lambda i: Refit(i))
    with pytest.raises(fitting.FitError, match="left out"):
        fitting.exact_loo_refits(psis, [1], lambda i: Refit(2))


def test_leaving_out_an_observation_gives_the_posterior_of_the_rest():
    """A linear-Gaussian toy (residuals ``A u - y``, unit sigma) through the sampler's path with
    one observation's likelihood weight 0: the closed-form posterior of the other rows."""
    from fitting._bayesian import posterior as _posterior
    from fitting._bayesian import programs
    from fitting._bayesian.priors import priors_for

    names = ("C_A", "f0")
    rng = np.random.default_rng(3)
    A = rng.standard_normal((8, 2))
    A[0] = [4.0, -3.0]  # a high-leverage row: leaving it out moves the posterior far
    y = A @ np.log([0.75, 300.0]) + rng.standard_normal(8)
    y[0] += 15.0
    cov_all = np.linalg.inv(A.T @ A)
    cov = np.linalg.inv(A[1:].T @ A[1:])
    mean = cov @ A[1:].T @ y[1:]
    post = _posterior._sample(
        lambda u: jnp.asarray(A) @ u - jnp.asarray(y), names, cov_all @ A.T @ y, cov_all,
        priors_for(names, None), np.full(8, -1), (), [], likelihood="gaussian", nu=4.0,
        chains=4, draws=500, warmup=1, seed=0, jitter=0.5, target_accept=0.9, progress=False,
        weight=programs._weights(8, [0]),
    )  # fmt: skip
    u = np.log(post.draws.reshape(-1, 2))
    sd = np.sqrt(np.diag(cov))
    # 2,000 draws, ESS at least 400: the mean within 5 / sqrt(400) posterior sd
    np.testing.assert_array_less(np.abs(u.mean(0) - mean), 0.25 * sd)
    np.testing.assert_allclose(u.std(0), sd, rtol=0.15)
    # with the row, the posterior sits elsewhere (many sd away): the weight mattered
    assert np.max(np.abs(cov_all @ A.T @ y - mean) / sd) > 3


def test_a_noise_factor_whose_only_observation_is_left_out_follows_its_prior():
    """Two noise groups, the second with one row: left out, its factor is still sampled (the
    held-out term needs it at the refit's draws), from its log-uniform prior on [1e-3, 1e3]."""
    from fitting._bayesian import posterior as _posterior
    from fitting._bayesian import programs
    from fitting._bayesian.priors import priors_for

    names = ("C_A", "f0")
    rng = np.random.default_rng(4)
    A = rng.standard_normal((9, 2))
    y = A @ np.log([0.75, 300.0]) + rng.standard_normal(9)
    groups = np.array([1] + [0] * 8)
    cov = np.linalg.inv(A.T @ A)
    post = _posterior._sample(
        lambda u: jnp.asarray(A) @ u - jnp.asarray(y), names, cov @ A.T @ y, cov,
        priors_for(names, None), groups, ("sigma_factor[a]", "sigma_factor[b]"), [0.0, 0.0],
        likelihood="gaussian", nu=4.0, chains=4, draws=500, warmup=1, seed=0, jitter=0.5,
        target_accept=0.9, progress=False, weight=programs._weights(9, [0]),
    )  # fmt: skip
    assert post.noise_draws.shape[-1] == 2
    log_s = np.log(post.noise_draws[..., 1]).ravel()
    # uniform on [-ln 1e3, ln 1e3]: mean 0, sd 2 ln(1e3) / sqrt(12) = 3.99 (ESS >= 400)
    assert abs(np.mean(log_s)) < 5 * 3.99 / math.sqrt(400)
    assert np.std(log_s) == pytest.approx(2 * math.log(1e3) / math.sqrt(12), rel=0.15)
    assert np.max(log_s) > 5 and np.min(log_s) < -5
    # the other group's factor is determined by its 8 rows (unit noise): near 1
    assert 0.5 < np.median(post.noise_draws[..., 0]) < 2


def test_leave_out_and_refit_options_are_checked(tmp_path, capsys):
    from fitting._bayesian.loo import MAX_REFITS
    from fitting._bayesian.posterior import _check_leave_out
    from fitting.cli import LOO_REFITS
    from jaximpact.cli import main

    assert LOO_REFITS == MAX_REFITS
    assert _check_leave_out([3, 1, 3], 5) == (1, 3)
    for bad, match in (([5], "must lie in"), ([-1], "must lie in"), (range(4), "no observation"),
                       ([1.5], "integers")):  # fmt: skip
        with pytest.raises(fitting.FitError, match=match):
            _check_leave_out(bad, 4)
    data = tmp_path / "data.csv"
    data.write_text("speed,angle_deg,observable,value,sigma\n1.0,0.0,cor_n,0.8,0.01\n")
    for extra, says in (
        (["--posterior", "--compare", "dmt", "--loo-refits", "-1"], "--loo-refits must be"),
        (["--posterior", "--loo-refits", "2"], "--loo-refits needs --compare"),
    ):
        code = main(["fit", str(data), "--params", "f0", *extra])
        err = capsys.readouterr().err
        assert code == 2 and says in err and "Traceback" not in err, err
