"""Posterior (NUTS), profile likelihood and experiment design (issue 11).

The default tests drive the same sampling, profile and design code with toy problems whose
answer is known in closed form (a linear-Gaussian model: posterior mean and covariance, the
profile interval, the best design), so they run without compiling the simulator; the tests
on the simulator itself (table1 scene: C_A, C_H, f0) are in the slow step.
"""

import itertools
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import fitting
import jaximpact
from fitting import _design
from fitting._bayesian import diagnostics, independence, programs
from fitting._bayesian import posterior as _posterior
from fitting._bayesian import result as _result
from fitting._bayesian.priors import Prior, parse_prior, priors_for
from fitting._bayesian.report import add_to_result_dict
from fitting._least_squares import profile as _profile
from jaximpact.cli import main as cli_main

NAMES = ("C_A", "C_H", "f0")
TRUTH = {"C_A": 0.75, "C_H": 0.25, "f0": 300.0}


def _linear_problem(seed=0, n=20):
    """Residuals ``A u - y`` (unit sigma), linear in ``u = ln p``: with the default
    log-uniform priors (flat in u, far wider than the likelihood) the posterior of u is
    Gaussian with mean ``(A^T A)^-1 A^T y`` and covariance ``(A^T A)^-1``."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, 3)) * np.array([1.0, 3.0, 0.5])
    A[:, 1] += 2.7 * A[:, 0]  # correlated, as C_A and f0 are
    u_true = np.log([TRUTH[k] for k in NAMES])
    y = A @ u_true + rng.standard_normal(n)

    def residuals(u):  # a JAX function, as the sampler's model residuals are
        return jnp.asarray(A) @ u - jnp.asarray(y)

    cov = np.linalg.inv(A.T @ A)
    return residuals, A, y, cov @ A.T @ y, cov


def _sample_toy(residuals, n, mean, cov, **kw):
    options = dict(
        likelihood="gaussian",
        nu=4.0,
        chains=4,
        draws=400,
        warmup=200,
        seed=0,
        jitter=0.5,
        target_accept=0.9,
        progress=False,
    )
    options.update(kw)
    return _posterior._sample(
        residuals,
        NAMES,
        mean,
        cov,
        priors_for(NAMES, None),
        np.full(n, -1),
        (),
        [],
        **options,
    )


@pytest.fixture(scope="module")
def toy_posterior():
    residuals, A, y, mean, cov = _linear_problem()
    return _sample_toy(residuals, len(y), mean, cov, draws=1000), mean, cov


def test_sampler_recovers_linear_gaussian_posterior(toy_posterior):
    """The default sampler (SMC) on the linear-Gaussian toy: the fit's t covers the
    posterior, so the particles start from it (said in ``reason``), and covers it so closely
    (Pareto k under 0.5, ESS over half the draws) that the weighted draws are the answer:
    one evaluation per particle, no moves."""
    result, mean, cov = toy_posterior
    assert result.sampler == "smc" and "from a t on the least-squares fit" in result.reason
    assert "importance sample" in result.reason and result.evaluations == 4 * 1000
    assert all(result.summary[n]["ess_tail"] >= _result.MIN_ESS for n in NAMES)
    _check_gaussian_posterior(result, mean, cov)


def test_independence_sampler_recovers_linear_gaussian_posterior():
    residuals, A, y, mean, cov = _linear_problem()
    result = _sample_toy(residuals, len(y), mean, cov, sampler="independence")
    assert result.sampler == "independence" and result.khat < 0.5
    _check_gaussian_posterior(result, mean, cov)


@pytest.mark.slow  # the HMC program's compilation
def test_hmc_recovers_linear_gaussian_posterior():
    residuals, A, y, mean, cov = _linear_problem()
    result = _sample_toy(residuals, len(y), mean, cov, sampler="hmc")
    assert result.sampler == "hmc"
    _check_gaussian_posterior(result, mean, cov)


def test_independence_proposal_that_misses_is_refused_and_smc_starts_from_the_prior():
    """A least-squares covariance 1e4 times too small: the independence proposal is far too
    narrow, its importance weights heavy-tailed (Pareto k > 0.7), and the run is refused; the
    default (SMC) sees from the same weights that the fit's t does not cover the posterior,
    starts from the prior instead, and recovers the closed form."""
    residuals, A, y, mean, cov = _linear_problem()
    narrow = dict(draws=60, warmup=20)
    refused = _sample_toy(residuals, len(y), mean, cov * 1e-4, sampler="independence", **narrow)
    assert refused.khat > 0.7 and not refused.converged
    assert any("Pareto k" in p for p in refused.problems)
    auto = _sample_toy(residuals, len(y), mean, cov * 1e-4, draws=1000)
    assert auto.sampler == "smc" and "from the prior" in auto.reason
    _check_gaussian_posterior(auto, mean, cov)


def test_independence_proposal_is_replaced_when_the_pilot_misses(monkeypatch):
    """A least-squares covariance 100 times too small (standard deviations 10x): the first
    main proposal's Pareto k is above 0.7 (without re-placing it the run is refused); placed
    again on its importance weights, wider, the sampler recovers the posterior by itself."""
    residuals, A, y, mean, cov = _linear_problem()
    monkeypatch.setattr(independence, "REFINEMENTS", 0)
    once = _sample_toy(residuals, len(y), mean, cov * 1e-2, sampler="independence")
    assert once.khat > 0.7 and not once.converged
    monkeypatch.undo()
    refined = _sample_toy(residuals, len(y), mean, cov * 1e-2, sampler="independence")
    assert refined.sampler == "independence" and refined.khat <= 0.7
    _check_gaussian_posterior(refined, mean, cov)


def test_independence_chains_just_above_the_rhat_limit_are_extended(monkeypatch):
    """Seed 32, 4 chains x 100 draws: split R-hat 1.020 (sampling noise of short chains; the
    proposal is right). Without extensions the run is refused; with them the chains are
    continued by 100 draws at a time until R-hat <= 1.01 (here after two), and the posterior
    is right. (Of 12 seeds refused at 100 draws, 10 converged extended.)"""
    residuals, A, y, mean, cov = _linear_problem()
    short = dict(sampler="independence", draws=100, warmup=50, seed=32)
    monkeypatch.setattr(independence, "EXTENSIONS", 0)
    refused = _sample_toy(residuals, len(y), mean, cov, **short)
    assert not refused.converged and any("R-hat" in p for p in refused.problems)
    assert refused.draws.shape[1] == 100
    monkeypatch.undo()
    extended = _sample_toy(residuals, len(y), mean, cov, **short)
    assert extended.draws.shape[1] in (200, 300)
    assert max(extended.summary[n]["rhat"] for n in NAMES) <= _posterior.MAX_RHAT
    _check_gaussian_posterior(extended, mean, cov)
    # not for chains that do not mix (R-hat above MAX_RHAT_TO_EXTEND) nor for short runs
    assert independence.MAX_RHAT_TO_EXTEND < 1.5 and independence.MIN_DRAWS_TO_EXTEND > 60


def _check_gaussian_posterior(result, mean, cov):
    assert result.converged, result.message
    assert result.divergences == 0
    u = np.log(result.draws.reshape(-1, 3))
    for i, name in enumerate(NAMES):
        sd = math.sqrt(cov[i, i])
        mc_error = sd / math.sqrt(result.summary[name]["ess"])
        assert abs(u[:, i].mean() - mean[i]) < 4 * mc_error, name
        # sd of a sample sd ~ sd / sqrt(2 ess); 5 such errors
        assert abs(u[:, i].std() / sd - 1) < 5 / math.sqrt(2 * result.summary[name]["ess"])
    corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    assert np.allclose(np.corrcoef(u, rowvar=False), corr, atol=0.05)
    # 90 % interval of the closed form (in u, mapped to physical) against the draws'
    for i, name in enumerate(NAMES):
        q05 = math.exp(mean[i] - 1.6449 * math.sqrt(cov[i, i]))
        s = result.summary[name]
        assert abs(math.log(s["q05"] / q05)) < 0.2 * math.sqrt(cov[i, i]), name


def test_log_density_gradient_matches_finite_differences():
    """The sampler's gradient: prior Jacobian terms and the residuals' derivative, against
    central differences of the same log density (Student-t, fitted noise factor, a normal
    prior, friction's bounded transform)."""
    residuals, A, y, mean, cov = _linear_problem()
    names = ("C_A", "friction", "f0")
    priors = {
        "C_A": Prior("normal", 1.0, 0.5),
        "friction": parse_prior("friction", "loguniform:0.01:1.4"),
        "f0": Prior("loguniform", 1.0, 1e4),
    }
    groups = np.zeros(len(y), int)
    groups[:5] = -1  # rows with their own sigma
    f = programs._log_density(residuals, names, priors, groups, 1, "student-t", 4.0)
    z = np.array([-0.3, -3.2, 5.6, math.log(1.7)])  # friction 10 sigmoid(-3.2) = 0.39
    grad = np.asarray(jax.jit(jax.grad(f))(z))
    f = jax.jit(f)
    h = 1e-5
    fd = [(float(f(z + h * e)) - float(f(z - h * e))) / (2 * h) for e in np.eye(4)]
    np.testing.assert_allclose(grad, fd, rtol=1e-6, atol=1e-6)


def test_refusal_on_rhat_and_divergences():
    """Split R-hat and the refusal rule on draws with a known answer: four chains from one
    normal distribution pass; shift one chain by one sd and R-hat rises far above 1.01 (a
    shift ``d`` in one of 8 half-chains gives ``R^2 ~ 1 + d^2 / 8``); one divergence refuses."""
    rng = np.random.default_rng(0)
    good = rng.standard_normal((4, 1000))
    assert abs(diagnostics.split_rhat(good) - 1) < 0.01
    assert diagnostics.ess(good) == pytest.approx(4000, rel=0.15)
    stats = {"C_A": {"rhat": diagnostics.split_rhat(good)}}
    assert _result.judge(stats, 0) == []
    assert "divergent" in _result.judge(stats, 1)[0]
    bad = good.copy()
    bad[0] += 1.0
    rhat = diagnostics.split_rhat(bad)
    assert 1.03 < rhat < 1.15
    assert "R-hat of f0" in _result.judge({"C_A": stats["C_A"], "f0": {"rhat": rhat}}, 0)[0]
    assert _result.judge({"C_A": {"rhat": math.nan}}, 0)


@pytest.mark.slow  # a second sampler compilation
def test_chains_stuck_in_separate_modes_are_refused():
    """Two modes at u = +-1 (r = (u^2 - 1) / 0.05 for C_A; the others linear): chains
    started in different modes never mix, so R-hat is far above 1.01 and the run is refused."""

    def residuals(u):
        return jnp.stack([(u[0] ** 2 - 1) / 0.05, u[1] / 0.1, (u[2] - 5) / 0.1])

    cov = np.diag([1e-4, 1e-2, 1e-2])
    result = _sample_toy(
        residuals,
        3,
        np.array([1.0, 0.0, 5.0]),
        cov,
        draws=60,
        warmup=60,
        z0=np.array([[1.0, 0, 5], [-1.0, 0, 5], [1.0, 0, 5], [-1.0, 0, 5]]),
    )
    assert not result.converged
    assert result.status == "not converged"
    assert result.summary["C_A"]["rhat"] > 1.5
    assert any("R-hat" in p for p in result.problems)


def test_posterior_json_fields(toy_posterior):
    result = toy_posterior[0]
    d = add_to_result_dict({"params": {n: {"value": 1.0, "stderr": 0.1} for n in NAMES}}, result)
    d = json.loads(json.dumps(d))  # JSON-safe
    flat = result.draws.reshape(-1, 3)
    for i, n in enumerate(NAMES):
        post = d["params"][n]["posterior"]
        assert set(post) == {"mean", "median", "sd", "q05", "q95", "rhat", "ess", "ess_tail"}
        assert post["q05"] < post["median"] < post["q95"]
        assert post["mean"] == pytest.approx(flat[:, i].mean(), rel=1e-12)
        assert post["q05"] == pytest.approx(np.quantile(flat[:, i], 0.05), rel=1e-12)
    corr = np.array(d["posterior"]["correlation"])
    assert corr.shape == (3, 3) and np.allclose(np.diag(corr), 1)
    assert d["posterior"]["divergences"] == 0 and d["posterior"]["chains"] == 4
    assert d["posterior"]["priors"]["f0"] == "loguniform:0.1:100000"


def test_profile_interval_equals_gaussian_on_linear_problem():
    residuals, A, y, mean, cov = _linear_problem(seed=3)

    def evaluate(U):
        r = np.einsum("ij,...j->...i", A, U) - y
        return r, np.broadcast_to(A, r.shape + (3,)).copy(), np.zeros((len(U), 1))

    cost_min = 0.5 * float(np.sum(np.asarray(residuals(mean)) ** 2))
    for k in range(3):
        se = math.sqrt(cov[k, k])
        grid = mean[k] + np.linspace(-3.5, 3.5, 9) * se
        costs, others, ok = _profile.profile_costs(evaluate, 4, mean, k, grid)
        assert ok.all()
        _, lo, hi = _profile.likelihood_ratio_interval(grid, costs, cost_min, 1.0, mean[k])
        assert lo == pytest.approx(mean[k] - 1.959964 * se, abs=1e-4 * se)
        assert hi == pytest.approx(mean[k] + 1.959964 * se, abs=1e-4 * se)


def test_greedy_design_finds_the_best_pair_and_beats_random():
    """Rank-one candidates ``a a^T``: det of a pair is ``(|a||b| sin angle)^2``. The best pair
    (by brute force) is two strong, nearly orthogonal candidates among many weak or parallel
    ones; the greedy choice must find it and beat random pairs by far."""
    rng = np.random.default_rng(0)
    angles = rng.uniform(0, np.pi, 40)
    lengths = rng.uniform(0.2, 1.0, 40)
    lengths[7], angles[7] = 3.0, 0.1
    lengths[23], angles[23] = 2.8, 0.1 + np.pi / 2 - 0.05
    a = np.stack([lengths * np.cos(angles), lengths * np.sin(angles)], 1)
    info = np.einsum("ci,cj->cij", a, a)
    chosen, gains, _, _ = _design.greedy_d_optimal(info, np.arange(40), 2, ridge=1e-6)
    best = max(
        itertools.combinations(range(40), 2), key=lambda s: fitting.log_det_information(info, s)
    )
    assert set(chosen) == set(best) == {7, 23}
    assert np.all(gains > 0)
    designed = fitting.log_det_information(info, chosen)
    random = [
        fitting.log_det_information(info, rng.choice(40, 2, replace=False)) for _ in range(50)
    ]
    assert designed - np.median(random) > math.log(5)


def test_greedy_design_over_draws_maximizes_the_mean_log_det():
    """With the information at several parameter draws, each pick maximizes the mean log-det
    over the draws; identical draws give the point design."""
    rng = np.random.default_rng(1)
    a = rng.standard_normal((2, 30, 3))  # rank-one candidates at two draws
    info = np.einsum("sci,scj->scij", a, a)
    point = _design.greedy_d_optimal(info[0], np.arange(30), 4)
    same = _design.greedy_d_optimal(np.stack([info[0]] * 3), np.arange(30), 4)
    assert list(same[0]) == list(point[0])
    np.testing.assert_allclose(same[2], point[2], rtol=1e-12)
    chosen, gains, log_det, ridge = _design.greedy_d_optimal(info, np.arange(30), 4)
    m = ridge * np.eye(3)
    for k, pick in enumerate(chosen):  # each pick is the best given the earlier ones
        trial = [
            np.mean(
                [
                    np.linalg.slogdet(m + sum(info[s, j] for j in [*chosen[:k], c]))[1]
                    for s in range(2)
                ]
            )
            if c not in chosen[:k]
            else -np.inf
            for c in range(30)
        ]
        assert pick == int(np.argmax(trial))
        assert log_det[k] == pytest.approx(max(trial), rel=1e-10)
    assert np.all(gains > 0)


def test_prior_specs_and_bad_input():
    assert parse_prior("f0", "loguniform:10:1e4") == Prior("loguniform", 10.0, 1e4)
    assert parse_prior("C_A", "normal:0.8:0.2") == Prior("normal", 0.8, 0.2)
    for bad in ("uniform:1:2", "loguniform:5:1", "normal:1:0", "normal:1", "loguniform:a:2"):
        with pytest.raises(fitting.FitError, match="prior of f0"):
            parse_prior("f0", bad)
    with pytest.raises(fitting.FitError, match="not fitted"):
        priors_for(NAMES, {"K": "loguniform:1:2"})


def test_scene_priors_are_read_and_overridden(tmp_path):
    """A scene file's [priors] table gives the prior of a fitted name unless the caller gives
    one; entries of names not fitted are ignored; a bad entry names the scene key."""
    text = jaximpact.scene_path("table1").read_text()
    path = tmp_path / "s.toml"
    path.write_text(text + '\n[priors]\nf0 = "normal:300:50"\nK = "loguniform:1e9:1e12"\n')
    scene = jaximpact.load_scene(path)
    assert dict(scene.priors) == {"f0": "normal:300:50", "K": "loguniform:1e9:1e12"}
    got = priors_for(NAMES, None, scene.priors)
    assert got["f0"] == Prior("normal", 300.0, 50.0)
    assert got["C_A"] == fitting._bayesian.priors.default_prior("C_A")
    assert priors_for(NAMES, {"f0": "normal:1:2"}, scene.priors)["f0"] == Prior("normal", 1, 2)
    with pytest.raises(fitting.FitError, match="scene priors.f0"):
        priors_for(NAMES, None, (("f0", "normal:300"),))
    # the simulator ignores the priors: same program, same numbers
    base = jaximpact.simulate(jaximpact.load_scene("table1"), 1.0, 30.0, 0.0)
    assert float(jaximpact.simulate(scene, 1.0, 30.0, 0.0).cor_n) == float(base.cor_n)
    for bad, field in (
        ("[priors]\nf0 = 3.0\n", "priors.f0 must be a string"),
        ('[priors]\nzeta_A = "normal:1:1"\n', "priors.zeta_A"),
    ):
        path.write_text(text + "\n" + bad)
        with pytest.raises(jaximpact.SceneError, match=field):
            jaximpact.load_scene(path)


def test_every_fittable_name_has_a_default_prior():
    from fitting._bayesian.priors import ETA_N_PRIORS, default_prior

    for name in fitting.FITTABLE:
        if name == "eta_n":  # its unit, and so its prior, is the scene's damping model's
            for damping in ETA_N_PRIORS:
                prior = default_prior(name, damping)
                assert 0 < prior.a < prior.b
            continue
        prior = default_prior(name)
        assert 0 < prior.a < prior.b


def test_cli_bad_scene_prior_exit_2_before_fitting(tmp_path, capsys):
    scene = tmp_path / "s.toml"
    scene.write_text(
        jaximpact.scene_path("table1").read_text() + '\n[priors]\nf0 = "loguniform:5:1"\n'
    )
    data = tmp_path / "d.csv"
    data.write_text("speed,angle_deg,observable,value\n1.0,0.0,cor_n,0.5\n")
    code = cli_main(["fit", str(scene), str(data), "--params", "f0", "--posterior"])
    err = capsys.readouterr().err
    assert code == 2
    assert "scene priors.f0" in err and "Traceback" not in err


@pytest.mark.parametrize(
    "extra, field",
    [
        (["--posterior", "--prior", "f0=loguniform:5:1"], "prior of f0"),
        (["--posterior", "--prior", "K=normal:1:1"], "--prior K"),
        (["--posterior", "--prior", "f0"], "--prior expects"),
        (["--draws", "x.nc"], "--draws needs --posterior"),
        (["--posterior", "--chains", "0"], "--chains"),
        (["--posterior", "--samples", "2"], "--samples"),
        (["--profile", "K"], "--profile K"),
        (["--profile-plot", "p.png"], "--profile-plot needs --profile"),
        (["--compare", "kharaz2001"], "--compare needs --posterior"),
        (["--posterior", "--compare-plot", "c.png"], "--compare-plot needs --compare"),
        (["--posterior", "--compare", "nosuch.toml"], "nosuch.toml"),
        (["--posterior", "--compare", "table1"], "--compare table1: the same model twice"),
        (["--posterior", "--compare", "kharaz2001=mu"], "mu"),
        (["--posterior", "--compare", "kharaz2001="], "no parameters to fit"),
    ],
)
def test_cli_bad_posterior_options_exit_2(extra, field, tmp_path, capsys):
    data = tmp_path / "d.csv"
    data.write_text("speed,angle_deg,observable,value\n1.0,0.0,cor_n,0.5\n")
    code = cli_main(["fit", str(data), "--params", *NAMES, *extra])
    err = capsys.readouterr().err
    assert code == 2
    assert field in err and "Traceback" not in err


@pytest.mark.parametrize(
    "extra, field",
    [
        (["--observables", "captured"], "observables"),
        (["--sigma", "cor_n=-1"], "sigma of cor_n"),
        (["--sigma", "vt_out=0.1"], "sigma given for 'vt_out'"),
        (["--n", "0"], "--n"),
        # the normal impact's line named, before anything is compiled
        (["--observables", "cor_t"], "cand.csv, line 2: angle_deg = 0, where cor_t"),
    ],
)
def test_cli_design_bad_input_exit_2(extra, field, tmp_path, capsys):
    cand = tmp_path / "cand.csv"
    cand.write_text("speed,angle_deg\n1.0,0.0\n2.0,30.0\n")
    args = [
        "design",
        "--params",
        *NAMES,
        "--candidates",
        str(cand),
        "--n",
        "1",
        "-o",
        str(tmp_path / "design.csv"),
        *extra,
    ]
    code = cli_main(args)
    err = capsys.readouterr().err
    assert code == 2
    assert field in err and "Traceback" not in err


def test_cli_design_bad_draws_exit_2(tmp_path, capsys):
    az = pytest.importorskip("arviz")
    cand = tmp_path / "cand.csv"
    cand.write_text("speed,angle_deg\n1.0,0.0\n2.0,30.0\n")
    draws = tmp_path / "draws.nc"
    az.from_dict(posterior={"C_A": np.ones((2, 5)), "f0": np.ones((2, 5))}).to_netcdf(str(draws))
    base = ["design", "--params", *NAMES, "--candidates", str(cand), "--n", "1"]
    for extra, field in (
        (["--draws", str(draws)], "no draws of C_H"),
        (["--draws", str(tmp_path / "none.nc")], "none.nc"),
        (["--draws", str(cand)], "not a draws file"),
        (["--max-draws", "0"], "--max-draws"),
    ):
        code = cli_main([*base, "-o", str(tmp_path / "d.csv"), *extra])
        err = capsys.readouterr().err
        assert code == 2, extra
        assert field in err and "Traceback" not in err
    assert not (tmp_path / "d.csv").exists()


def test_cli_design_missing_candidates_exit_2(tmp_path, capsys):
    code = cli_main(
        [
            "design",
            "--params",
            "f0",
            "--candidates",
            str(tmp_path / "none.csv"),
            "--n",
            "2",
            "-o",
            str(tmp_path / "d.csv"),
        ]
    )
    assert code == 2
    assert "none.csv" in capsys.readouterr().err


# -- on the simulator (slow) ---------------------------------------------------------------


def _write_data(path, speed, angle, values, sigma):
    rows = ["speed,angle_deg,observable,value,sigma"]
    rows += [
        f"{float(s)!r},{float(a)!r},cor_n,{float(v)!r},{sigma}"
        for s, a, v in zip(speed, angle, values, strict=True)
    ]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.slow  # compiles the simulator's residual program (about a minute on 2 cores)
def test_design_on_table1_beats_random_and_drops_captures(tmp_path):
    scene = fitting.Objective(
        jaximpact.table1_scene(),
        _write_data(tmp_path / "p.csv", [1.0], [0.0], [0.5], 0.01),
        NAMES,
    ).scene_at(TRUTH)
    speed = np.geomspace(0.05, 5.0, 12)
    angle = np.array([0.0, 30.0, 60.0])
    s, a = np.meshgrid(speed, angle)
    cand = tmp_path / "cand.csv"
    cand.write_text(
        "speed,angle_deg\n"
        + "\n".join(
            f"{x!r},{y!r}" for x, y in zip(s.ravel().tolist(), a.ravel().tolist(), strict=True)
        )
        + "\n"
    )
    result = fitting.design(scene, cand, NAMES, 6, sigma={"cor_n": 0.003})
    # the slowest impacts are captured by the Table 1 sphere: dropped, not chosen
    assert len(result.dropped_captured) > 0
    assert not set(result.chosen) & set(result.dropped_captured)
    assert not set(result.chosen) & set(result.dropped_near_capture)
    assert np.all(np.diff(result.log_det) > 0)
    rng = np.random.default_rng(0)
    random = [
        fitting.log_det_information(result.information, rng.choice(result.usable, 6, replace=False))
        for _ in range(50)
    ]
    assert fitting.log_det_information(result.information, result.chosen) > np.median(random)
    out = tmp_path / "design.csv"
    code = cli_main(
        [
            "design",
            "table1",
            "--params",
            *NAMES,
            "--candidates",
            str(cand),
            "--n",
            "6",
            "--sigma",
            "cor_n=0.003",
            "-o",
            str(out),
        ]
    )
    assert code == 0
    lines = [x for x in out.read_text().splitlines() if not x.startswith("#")]
    assert lines[0] == "order,speed,angle_deg,omega0,gain_logdet,log_det"
    assert len(lines) == 7
    # Over posterior draws: draws all at the design's values give the point design; spread
    # draws (C_A and f0 +-20 % along their ridge) give a design over all of them, from the CLI.
    theta = np.array([TRUTH[n] for n in NAMES])
    same = fitting.design(scene, cand, NAMES, 6, sigma={"cor_n": 0.003}, draws=[theta] * 3)
    assert same.draws == 3 and list(same.chosen) == list(result.chosen)
    spread = theta * np.array([[1.0, 1.0, 1.0], [1.2, 1.0, 0.8], [0.8, 1.0, 1.2]])
    az = pytest.importorskip("arviz")
    draws_file = tmp_path / "draws.nc"
    az.from_dict(posterior={n: spread[None, :, i] for i, n in enumerate(NAMES)}).to_netcdf(
        str(draws_file)
    )
    out2 = tmp_path / "design2.csv"
    args = ["design", "table1", "--params", *NAMES, "--candidates", str(cand), "--n", "6"]
    code = cli_main([*args, "--sigma", "cor_n=0.003", "--draws", str(draws_file), "-o", str(out2)])
    assert code == 0
    over = fitting.design(scene, cand, NAMES, 6, sigma={"cor_n": 0.003}, draws=spread)
    assert over.draws == 3
    # a candidate captured at any draw is not chosen
    assert len(over.dropped_near_capture) >= len(result.dropped_near_capture)
    assert not set(over.chosen) & set(over.dropped_near_capture)
    picked = [x.split(",")[1:3] for x in out2.read_text().splitlines()[2:]]
    assert [[float(v) for v in row] for row in picked] == [
        [float(over.candidates.speed[i]), float(over.candidates.angle_deg[i])] for i in over.chosen
    ]


@pytest.mark.slow  # a fit, a short posterior run and a profile through the CLI
def test_cli_short_posterior_is_refused_with_exit_3_and_writes_json(tmp_path, capsys):
    speed = np.geomspace(0.3, 5.0, 10)
    angle = np.tile([0.0, 30.0], 5)
    truth = fitting.Objective(
        jaximpact.table1_scene(), _write_data(tmp_path / "p.csv", [1.0], [0.0], [0.5], 0.01), NAMES
    ).scene_at(TRUTH)
    clean = np.asarray(jaximpact.simulate(truth, speed, angle, 0.0).cor_n)
    noisy = clean + 0.003 * np.random.default_rng(2).standard_normal(clean.size)
    data = _write_data(tmp_path / "d.csv", speed, angle, noisy, 0.003)
    out = tmp_path / "fit.json"
    args = [
        "fit",
        "table1",
        str(data),
        "--params",
        *NAMES,
        "--init",
        "C_A=0.75",
        "C_H=0.25",
        "f0=300",
        "--starts",
        "1",
        "--posterior",
        "--warmup",
        "3",
        "--samples",
        "6",
        "--profile",
        "f0",
        "--profile-points",
        "5",
        "-o",
        str(out),
        "--no-progress",
        "--draws",
        str(tmp_path / "draws.nc"),
        "--corner",
        str(tmp_path / "corner.png"),
    ]
    code = cli_main(args)
    captured = capsys.readouterr()
    assert code == 3, captured.err
    assert "posterior not converged" in captured.err
    d = json.loads(out.read_text())
    assert d["posterior"]["status"] == "not converged"
    for n in NAMES:
        assert set(d["params"][n]["posterior"]) == {
            "mean",
            "median",
            "sd",
            "q05",
            "q95",
            "rhat",
            "ess",
            "ess_tail",
        }
    assert d["profile"]["name"] == "f0"
    # The posterior's fit time is the CLI's fit's own (it was 0: timed from the posterior's
    # start), and its total includes it.
    post_t, fit_t = d["posterior"]["timings"], d["timings"]
    assert post_t["fit"] == pytest.approx(fit_t["total"], abs=1e-3) and post_t["fit"] > 0
    assert post_t["total"] >= post_t["fit"] + post_t["warmup"] + post_t["sampling"] - 1e-3
    assert (tmp_path / "draws.nc").stat().st_size > 0
    assert (tmp_path / "corner.png").stat().st_size > 0


def test_smc_finds_the_posterior_from_a_misplaced_fit():
    """A least-squares centre 5 standard errors off and a covariance 100 times too small: the
    reference (a t on it mixed with the prior) does not cover the posterior, tempering
    carries the particles there anyway, and the result is the closed form."""
    residuals, A, y, mean, cov = _linear_problem()
    off = mean + 5 * np.sqrt(np.diag(cov))
    result = _sample_toy(residuals, len(y), off, cov * 1e-2, sampler="smc", draws=1000)
    assert np.max(result.stages) > 1
    _check_gaussian_posterior(result, mean, cov)


def test_stuck_verdict_sees_copies_not_a_heavy_tail():
    """The verdict on moves that reached MAX_MOVES: copies that moved apart in a coordinate
    with a heavy tail (a posterior against a bound, in logit) keep a Pearson correlation above
    DECORRELATION through three tail particles, not a rank correlation; copies that did not
    move apart keep both; independent positions are never judged stuck."""
    from fitting._bayesian import smc

    rng = np.random.default_rng(5)
    n = 500
    bulk = rng.standard_normal((n, 3))
    anchor, moved = bulk.copy(), rng.standard_normal((n, 3))  # every particle moved
    # three particles far out in the tail at the resampling and still out there (elsewhere)
    anchor[:3, 2] = -rng.uniform(8.0, 12.0, 3)
    moved[:3, 2] = -rng.uniform(8.0, 12.0, 3)
    assert smc._correlation(anchor, moved) > 2 * smc.DECORRELATION
    assert not smc._copies_stuck(anchor, moved)
    # copies still near where they were: a rank correlation of 0.9
    stuck = anchor + 0.5 * rng.standard_normal((n, 3))
    assert smc._copies_stuck(anchor, stuck)
    # independent positions: at 500 particles, chance alone would put the largest |r| of three
    # coordinates above DECORRELATION in 7 % of populations (here: 1 in 40); never judged stuck
    fresh = [smc._rank_correlation(anchor, rng.standard_normal((n, 3))) for _ in range(40)]
    assert max(fresh) > smc.DECORRELATION
    assert not any(smc._copies_stuck(anchor, rng.standard_normal((n, 3))) for _ in range(40))


def test_sampling_space_round_trip_and_normalized_prior():
    """The sampler's coordinates: physical values -> x -> u are the fit's transforms; a
    log-uniform coordinate's prior is the standard logistic (integrates to 1 over x), and a
    normal prior's normalized density integrates to 1 over u; prior draws follow it."""
    from scipy import integrate

    from fitting._bayesian.space import SamplingSpace
    from fitting._least_squares.transforms import to_unbounded

    names = ("C_A", "friction", "f0")
    priors = priors_for(names, {"C_A": "loguniform:0.01:10", "f0": "normal:300:100"})
    space = SamplingSpace(names, ("sigma_factor[cor_n]",), priors)
    theta, log_noise = [0.7, 0.3, 250.0], [math.log(2.0)]
    x = space.from_physical(theta, log_noise)
    u, log_s = space.to_u(jnp.asarray(x))
    assert np.allclose(np.asarray(u), to_unbounded(names, theta), atol=1e-9)
    assert np.allclose(np.asarray(log_s), log_noise, atol=1e-9)

    def marginal_mass(i, grid):
        X = np.tile(x, (grid.size, 1))
        X[:, i] = grid
        # the prior is a product over coordinates: the others' factors divided out at x
        own = space.log_prior_normalized(X) - space.log_prior_normalized(x[None])[0]
        return integrate.trapezoid(np.exp(own + _own(space, x, i)), grid)

    for i, grid in ((0, np.linspace(-40, 40, 40001)), (2, np.linspace(-10.0, 8.0, 80001))):
        assert marginal_mass(i, grid) == pytest.approx(1.0, abs=1e-4), names[i]
    draws = space.sample_prior(np.random.default_rng(0), 20000)
    f0 = np.exp(draws[:, 2])
    assert np.mean(f0) == pytest.approx(300.0, abs=3.0) and np.std(f0) == pytest.approx(
        100.0, abs=3.0
    )
    assert np.std(draws[:, 0]) == pytest.approx(math.pi / math.sqrt(3), rel=0.03)


def _own(space, x, i):
    """Log prior density of coordinate ``i`` alone at ``x`` (the product's factor)."""
    if space._box(i) is None:
        name = space.names[i]
        from scipy import stats

        prior = space.priors[name]
        lo, hi = space._normal_support(name)
        mass = stats.norm.cdf(hi, prior.a, prior.b) - stats.norm.cdf(lo, prior.a, prior.b)
        return float(prior.log_density_u(name, x[i])) - math.log(mass)
    return float(jax.nn.log_sigmoid(x[i]) + jax.nn.log_sigmoid(-x[i]))


@pytest.mark.parametrize("moves, seed", [("values", 0), ("mala", 1)])
def test_smc_matches_a_grid_posterior_on_a_curved_ridge(moves, seed):
    """A curved ridge (ln f0 follows ln C_A quadratically, 0.1 thick against 0.3 along) with
    ln C_H apart: the sampler's mean, sd and 5/50/95 % quantiles of every physical parameter
    against the same density on a 3-D grid (`_bayesian.grid`), with the default moves and
    with MALA moves (whose uncapped drift left this ridge's tail particles where they were:
    sd 30 % wide at seed 1)."""
    from scipy.stats import norm

    from fitting._bayesian.grid import compare, grid_posterior

    def curved(u):  # numpy or JAX
        return [
            (u[0] - 0.3) / 0.3,
            (u[2] - 5.7 - 1.5 * (u[0] - 0.3) ** 2) / 0.1,
            (u[1] + 1.4) / 0.2,
        ]

    def residuals(u):
        return jnp.stack(curved(u))

    centre = np.array([0.3, -1.4, 5.7])
    cov = np.diag([0.3, 0.2, 0.1]) ** 2
    result = _sample_toy(residuals, 3, centre, cov, draws=1000, moves=moves, seed=seed)
    assert result.converged, result.message
    assert ("local moves: MALA" in result.reason) == (moves == "mala")

    def log_density(U):
        r = curved(U.T)
        return -0.5 * sum(x**2 for x in r)

    lower, upper = centre - [2.4, 1.6, 0.6], centre + [2.4, 1.6, 2.4]
    grid = grid_posterior(log_density, lower, upper, names=NAMES, points=48,
                          to_physical=lambda i, u: np.exp(u))  # fmt: skip
    errors = compare(result.summary, grid)
    # Within 3.5 Monte Carlo standard errors (of a Gaussian's mean and quantiles at the run's
    # ESS, in sd units: 0.07 for the mean, 0.15 for q05 and q95 at an ESS of 2,300) and 10 %.
    for n in NAMES:
        ess = min(result.summary[n]["ess"], result.summary[n]["ess_tail"])
        assert errors[n]["mean"] < 3.5 / math.sqrt(ess), (n, errors[n])
        for key, p in (("q05", 0.05), ("median", 0.5), ("q95", 0.95)):
            se = math.sqrt(p * (1 - p) / ess) / norm.pdf(norm.ppf(p))
            assert errors[n][key] < 3.5 * se, (n, key, errors[n])
        assert 0.9 < errors[n]["sd_ratio"] < 1.1, (n, errors[n])


def test_smc_samples_a_thin_banana_that_the_priors_leave_whole():
    """``x2 ~ N(x1^2, 0.1^2)``, ``x1 ~ N(0, 1)`` (and ``x3 ~ N(0, 1)``), SMC from the prior:
    the sd of ``x2`` within 5 % of the exact value (1-D quadrature over ``x1``). C_H's prior
    is wide enough not to cut the ridge's ends: with its default range the ridge is cut at
    x2 = 8.8 and the exact sd is 1.311, not 1.409 (SMC gave 1.335 and 1.303 there, 2 seeds),
    which is how a banana "too narrow" (1.22 against 1.41) had been recorded before."""
    from scipy import stats

    names = ("C_A", "C_H", "f0")
    centre = np.array([math.log(0.316), -6.0, math.log(316.0)])

    def residuals(u):
        x = u - jnp.asarray(centre)
        return jnp.stack([x[0], (x[1] - x[0] ** 2) / 0.1, x[2]])

    priors = priors_for(names, {"C_H": "loguniform:1e-9:1e4"})
    result = _posterior._sample(
        residuals, names, centre, np.eye(3), priors, np.full(3, -1), (), [],
        likelihood="gaussian", nu=4.0, chains=4, draws=1000, warmup=1, seed=0, jitter=0.5,
        target_accept=0.9, progress=False,
    )  # fmt: skip
    assert result.converged, result.message
    x = np.log(result.draws.reshape(-1, 3)) - centre
    x1 = np.linspace(-8.0, 8.0, 160_001)
    w = stats.norm.pdf(x1)
    exact_mean = np.trapezoid(w * x1**2, x1)  # the prior's ends lie 8.7 sd and more away
    exact_sd = math.sqrt(np.trapezoid(w * (x1**4 + 0.01), x1) - exact_mean**2)
    assert exact_sd == pytest.approx(math.sqrt(2.01), rel=1e-6)
    assert x[:, 1].std() == pytest.approx(exact_sd, rel=0.05)
    assert x[:, 0].std() == pytest.approx(1.0, rel=0.05)
    assert abs(x[:, 1].mean() - exact_mean) < 4 * exact_sd / math.sqrt(result.summary["C_H"]["ess"])


@pytest.mark.slow  # a fit and a posterior through the CLI
def test_cli_posterior_answers_where_the_fit_is_undetermined(tmp_path, capsys):
    """Six normal impacts (0.6-8 m/s) leave C_A and f0 on a ridge: the least-squares
    uncertainty is undefined (fit status "undetermined", which alone exits 3), the posterior
    converges and is the answer: exit 0, the reason on stderr, both statuses in the JSON."""
    truth = {"C_A": 1.1528318808167861, "C_H": 0.38847317692962374, "f0": 81.4828931222503}
    speed = np.geomspace(0.6, 8.0, 6)
    scene = fitting.Objective(
        jaximpact.table1_scene(), _write_data(tmp_path / "p.csv", [1.0], [0.0], [0.5], 0.01), NAMES
    ).scene_at(truth)
    clean = np.asarray(jaximpact.simulate(scene, speed, 0.0, 0.0).cor_n)
    noisy = clean + 0.003 * np.random.default_rng(200).standard_normal(clean.size)
    data = _write_data(tmp_path / "d.csv", speed, np.zeros(6), noisy, 0.003)
    out = tmp_path / "fit.json"
    # the calibration's prior (benchmarks/posterior_sbc.py): a factor ~4 about Table 1's values
    priors = ["C_A=loguniform:0.2:3", "C_H=loguniform:0.06:1", "f0=loguniform:75:1200"]
    centre = ["C_A=0.7746", "C_H=0.2449", "f0=300"]
    args = ["fit", "table1", str(data), "--params", *NAMES, "--init", *centre, "--starts", "1",
            "--posterior", "--prior", *priors, "-o", str(out), "--no-progress"]  # fmt: skip
    code = cli_main(args)
    captured = capsys.readouterr()
    d = json.loads(out.read_text())
    assert d["status"] == "undetermined", captured.out
    assert d["posterior"]["status"] == "converged", captured.err
    assert code == 0, captured.err
    assert "the posterior describes it" in captured.err
    for n in NAMES:  # the truth inside the posterior's 5-95 % interval, widened by its sd
        post = d["params"][n]["posterior"]
        assert post["q05"] - post["sd"] < truth[n] < post["q95"] + post["sd"], (n, post)


def test_predictive_plot_shows_a_model_the_posterior_leaves_certain(monkeypatch, tmp_path):
    """Rolling impacts below the sliding angle have cor_t = 5/7 at every posterior draw: the
    model's 90 % band has zero width there, and the plot still shows the model (its median
    line through those values) beside the data."""
    from types import SimpleNamespace

    from fitting._bayesian import report

    angle = np.array([10.0, 20.0, 40.0, 60.0])
    obs = SimpleNamespace(
        speed=np.full(4, 1.0), angle_deg=angle, observable=np.array(["cor_t"] * 4),
        value=np.array([0.71, 0.72, 0.6, 0.5]), sigma=np.full(4, 0.01),
    )  # fmt: skip
    rng = np.random.default_rng(0)
    model = np.tile([5 / 7, 5 / 7, 0.6, 0.5], (50, 1))
    model[:, 2:] += 0.02 * rng.standard_normal((50, 2))
    predicted = model + 0.01 * rng.standard_normal(model.shape)
    monkeypatch.setattr(report, "posterior_predictive", lambda result, n: (model, predicted))
    figures = []
    monkeypatch.setattr(report, "_atomic_savefig", lambda fig, path: figures.append(fig))
    summary = {"friction": {"median": 0.3, "q05": 0.25, "q95": 0.35}}
    result = SimpleNamespace(
        fit=SimpleNamespace(objective=SimpleNamespace(observations=obs)),
        params=("friction",), summary=summary,
    )  # fmt: skip
    report.plot_predictive(tmp_path / "p.png", result)
    (ax,) = figures[0].axes
    lines = {line.get_label(): line for line in ax.get_lines()}
    median = lines["model median"]
    np.testing.assert_allclose(median.get_xdata(), angle)
    np.testing.assert_allclose(median.get_ydata()[:2], 5 / 7)
    assert median.get_visible() and median.get_linewidth() > 0


def test_predictive_plot_labels_stay_inside_and_apart(monkeypatch, tmp_path):
    """Three stacked panels (cor_n, cor_t, rebound angle): each y label inside the figure and
    clear of its neighbours' (one-line labels were cut to "angential restitution ..." and ran
    into each other)."""
    from types import SimpleNamespace

    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from fitting._bayesian import report

    kinds = np.repeat(["cor_n", "cor_t", "rebound_angle_deg"], 4)
    obs = SimpleNamespace(
        speed=np.full(12, 1.0), angle_deg=np.tile([10.0, 20.0, 40.0, 60.0], 3),
        observable=kinds, value=np.linspace(0.5, 0.8, 12), sigma=np.full(12, 0.01),
    )  # fmt: skip
    model = np.tile(np.linspace(0.5, 0.8, 12), (50, 1))
    monkeypatch.setattr(report, "posterior_predictive", lambda result, n: (model, model))
    figures = []
    monkeypatch.setattr(report, "_atomic_savefig", lambda fig, path: figures.append(fig))
    result = SimpleNamespace(
        fit=SimpleNamespace(objective=SimpleNamespace(observations=obs)), params=("friction",),
        summary={"friction": {"median": 0.3, "q05": 0.25, "q95": 0.35}},
    )  # fmt: skip
    report.plot_predictive(tmp_path / "p.png", result)
    fig = figures[0]
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    renderer = canvas.get_renderer()
    boxes = [ax.yaxis.label.get_window_extent(renderer) for ax in fig.axes]
    assert len(boxes) == 3
    for box in boxes:
        assert box.x0 >= 0 and box.y0 >= 0 and box.y1 <= fig.bbox.y1, (box, fig.bbox)
    for a, b in itertools.combinations(boxes, 2):
        assert not a.overlaps(b), (a, b)


def test_plots_leave_the_callers_matplotlib_alone(tmp_path):
    """Writing a corner plot neither switches pyplot's backend (it switched to Agg, so a
    notebook's inline figures stopped showing after the first plot file) nor leaves a pyplot
    figure open; the file is written."""
    from types import SimpleNamespace

    import matplotlib
    import matplotlib.pyplot as plt

    from fitting._bayesian import report

    before = matplotlib.get_backend()
    plt.switch_backend("pdf")  # not Agg, so that a switch to Agg shows
    backend, open_figures = matplotlib.get_backend(), plt.get_fignums()
    draws = np.random.default_rng(0).lognormal(size=(2, 50, 2))
    summary = {
        n: {"median": 1.0, "q05": 0.5, "q95": 2.0} for n in ("C_A", "f0")
    }  # fmt: skip
    result = SimpleNamespace(
        params=("C_A", "f0"), draws=draws, summary=summary, fit=None, chains=2,
        converged=True, sampler="smc",
    )  # fmt: skip
    try:
        report.plot_corner(tmp_path / "corner.png", result)
        after = matplotlib.get_backend()
    finally:
        plt.switch_backend(before)
    assert (tmp_path / "corner.png").stat().st_size > 0
    assert after == backend and plt.get_fignums() == open_figures
