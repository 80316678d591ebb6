"""Noise factors integrated out (issue 52, item 1): the closed-form marginal likelihood against
quadrature, its derivative, the conditional draws, and the posterior of the integrated form
against the sampled form and against a grid of the marginal posterior.

Every reference here is computed independently of ``fitting._bayesian.likelihood``: the
integral over the noise factor by the trapezoid rule in ``ln s`` on a fine grid.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from fitting._bayesian import posterior as _posterior
from fitting._bayesian import programs
from fitting._bayesian.grid import compare, grid_posterior
from fitting._bayesian.likelihood import (
    NOISE_FACTOR_RANGE,
    draw_noise_factors,
    log_marginal_gaussian,
)
from fitting._bayesian.priors import priors_for
from fitting._least_squares.objective import FitError

LO, HI = (math.log(v) for v in NOISE_FACTOR_RANGE)


def _log_integrand(S, n, log_s):
    """ln of s^-n exp(-S / 2 s^2) / ln(b/a) (the likelihood times the log-uniform prior, per
    unit of ln s)."""
    return -n * log_s - S / (2.0 * np.exp(2.0 * log_s)) - math.log(HI - LO)


def _quadrature(S, n, points=400_001):
    """ln of the integral over ln s in [ln a, ln b] (trapezoid rule, in logs)."""
    log_s = np.linspace(LO, HI, points)
    f = _log_integrand(S, n, log_s)
    top = f.max()
    return top + math.log(np.trapezoid(np.exp(f - top), log_s))


# (S, n): typical fits, residuals far below the smallest factor (mass against its end, and
# S = 0: a perfect fit), far above the largest, a single observation.
CASES = [(24.0, 24), (3.1, 10), (1e-3, 10), (1e-12, 5), (0.0, 3), (5e6, 3), (3e7, 24), (1.0, 1)]


@pytest.mark.parametrize("S, n", CASES)
def test_closed_form_marginal_equals_quadrature(S, n):
    assert float(log_marginal_gaussian(S, n)) == pytest.approx(_quadrature(S, n), abs=1e-7)


def test_marginal_of_no_observation_is_the_prior_mass():
    assert float(log_marginal_gaussian(7.0, 0)) == 0.0


@pytest.mark.parametrize("S, n", [(24.0, 24), (3.1, 10), (1e-3, 10), (5e6, 3), (2e8, 4)])
def test_marginal_derivative_matches_central_differences(S, n):
    h = 1e-5 * S
    expected = (_quadrature(S + h, n) - _quadrature(S - h, n)) / (2 * h)
    got = float(jax.grad(log_marginal_gaussian)(S, float(n)))
    assert got == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("S", [0.0, 1e-30])
def test_marginal_derivative_is_finite_at_a_perfect_fit(S):
    """As S -> 0 the marginal tends to a finite limit with slope -(a / (a + 1)) / (2 lo^2)
    (a = n / 2, from P(a, t) ~ t^a (1 + t / (a + 1)) / Gamma(a + 1)); no NaN or inf."""
    n, lo = 30.0, NOISE_FACTOR_RANGE[0]
    slope = float(jax.grad(log_marginal_gaussian)(S, n))
    assert slope == pytest.approx(-(15.0 / 16.0) / (2 * lo**2), rel=1e-9)


@pytest.mark.parametrize("S, n", [(24.0, 24), (1e-14, 5), (3.1, 2), (0.0, 0), (2e12, 4)])
def test_conditional_draws_follow_the_exact_conditional(S, n):
    """The draws of s given S against the conditional's CDF by quadrature (KS test), including
    mass piled against either end of the prior and no observation at all (the prior)."""
    rng = np.random.default_rng(5)
    s = draw_noise_factors(np.full(20_000, S), n, rng)
    assert np.all((s >= NOISE_FACTOR_RANGE[0]) & (s <= NOISE_FACTOR_RANGE[1]))
    log_s = np.linspace(LO, HI, 400_001)
    f = _log_integrand(S, n, log_s)
    density = np.exp(f - f.max())
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(log_s))])
    cdf /= cdf[-1]
    if S == 2e12:  # all the mass within 1e-6 of ln b: the draws sit at b
        assert np.all(s == NOISE_FACTOR_RANGE[1])
        return
    p = stats.kstest(np.log(s), lambda x: np.interp(x, log_s, cdf)).pvalue
    assert p > 1e-3


# -- the posterior: integrated against sampled, and against a grid ---------------------------

NAMES = ("C_A", "f0")


def _two_group_problem(rows=(12, 8)):
    """Residuals ``A u - y`` of two observables without sigmas (``rows``: 12 rows with noise
    0.5, 8 rows with noise 2, in default scales): two noise factors, a posterior of ``u = ln
    p`` that is a product of t-like factors (heavier tails than a Gaussian)."""
    rng = np.random.default_rng(11)
    n = sum(rows)
    A = rng.standard_normal((n, 2)) * np.array([4.0, 2.0])
    A[:, 1] += 1.5 * A[:, 0]
    u_true = np.log([0.75, 300.0])
    noise = np.r_[np.full(rows[0], 0.5), np.full(rows[1], 2.0)]
    y = A @ u_true + noise * rng.standard_normal(n)
    groups = np.r_[np.zeros(rows[0], int), np.ones(rows[1], int)]
    cov = np.linalg.inv(A.T @ A) * 1.2
    return A, y, groups, np.linalg.solve(A.T @ A, A.T @ y), cov


def _sample(A, y, groups, centre, cov, noise, draws=1000):
    return _posterior._sample(
        lambda u: jnp.asarray(A) @ u - jnp.asarray(y), NAMES, centre, cov,
        priors_for(NAMES, None), groups, ("sigma_factor[a]", "sigma_factor[b]"), [0.0, 0.0],
        likelihood="gaussian", nu=4.0, chains=4, draws=draws, warmup=1, seed=3, jitter=0.5,
        target_accept=0.9, progress=False, noise_treatment=noise,
    )  # fmt: skip


@pytest.fixture(scope="module")
def two_group_posteriors():
    """Both forms on 40 + 30 rows (a posterior near enough to Gaussian that the sampled
    form's 4-D SMC is right too: on 12 + 8 rows it came out 4-5 % wide in sd against the
    exact posterior, over 6 seeds, where the integrated form was within 0.5 %)."""
    A, y, groups, centre, cov = _two_group_problem((40, 30))
    return (
        _sample(A, y, groups, centre, cov, "auto"),
        _sample(A, y, groups, centre, cov, "sampled"),
    )


def _within_monte_carlo_error(summary, reference, ess, names, factor=3.5):
    """Mean and 5/50/95 % quantiles of ``summary`` within ``factor`` Monte Carlo standard
    errors (of a Gaussian's, at ``ess``, in units of the reference's sd) of ``reference``, and
    the sd within 10 %."""
    for n in names:
        sd = reference[n]["sd"]
        assert abs(summary[n]["mean"] - reference[n]["mean"]) / sd < factor / math.sqrt(ess[n])
        for key, p in (("q05", 0.05), ("median", 0.5), ("q95", 0.95)):
            se = math.sqrt(p * (1 - p) / ess[n]) / stats.norm.pdf(stats.norm.ppf(p))
            assert abs(summary[n][key] - reference[n][key]) / sd < factor * se, (n, key)
        assert summary[n]["sd"] / sd == pytest.approx(1.0, abs=0.1), n


def test_integrated_form_runs_on_the_parameters_alone_and_says_so(two_group_posteriors):
    integrated, sampled = two_group_posteriors
    assert integrated.converged and sampled.converged, (integrated.message, sampled.message)
    assert integrated.noise_treatment == "integrated" and sampled.noise_treatment == "sampled"
    assert "integrated out in closed form" in integrated.reason
    assert "noise factors sampled" in sampled.reason
    assert integrated.noise == sampled.noise == ("sigma_factor[a]", "sigma_factor[b]")
    assert integrated.noise_draws.shape == integrated.draws.shape[:2] + (2,)
    # the true noise levels (0.5 and 2) inside the factors' 90 % intervals
    for name, truth in (("sigma_factor[a]", 0.5), ("sigma_factor[b]", 2.0)):
        assert integrated.summary[name]["q05"] < truth < integrated.summary[name]["q95"]


def test_integrated_and_sampled_forms_give_the_same_posterior(two_group_posteriors):
    """Parameters and noise factors: the two forms agree within the Monte Carlo error of two
    independent runs (sqrt(2) times one run's), the integrated one in under half the
    evaluations."""
    integrated, sampled = two_group_posteriors
    assert integrated.evaluations < 0.5 * sampled.evaluations
    names = NAMES + integrated.noise
    ess = {
        n: min(integrated.summary[n]["ess"], sampled.summary[n]["ess"],
               integrated.summary[n]["ess_tail"], sampled.summary[n]["ess_tail"])
        for n in names
    }  # fmt: skip
    _within_monte_carlo_error(integrated.summary, sampled.summary, ess, names, 3.5 * math.sqrt(2))


def test_integrated_form_matches_a_grid_of_the_marginal_posterior():
    """12 + 8 rows (t-like tails): the physical parameters' marginal posterior on a 2-D grid
    in ``u = ln p``, each grid point's noise factors integrated by quadrature (not the closed
    form); the factors' posterior mean and sd from the same quadrature (their conditional
    moments at each point, weighted by the grid's mass)."""
    A, y, groups, centre, cov = _two_group_problem()
    integrated = _sample(A, y, groups, centre, cov, "auto")
    assert integrated.converged, integrated.message
    log_s = np.linspace(LO, HI, 4_001)  # 0.0035 apart: the integrand is about 0.2 wide

    def terms(U):
        """ln of each point's marginal density, and each factor's conditional mean and mean
        square there."""
        R = U @ A.T - y
        total, moments = np.zeros(len(U)), []
        for j in (0, 1):
            S = np.sum(R[:, groups == j] ** 2, axis=1)
            n = int(np.sum(groups == j))
            f = -n * log_s[None] - S[:, None] / (2.0 * np.exp(2.0 * log_s[None]))
            w = np.exp(f - f.max(axis=1, keepdims=True))
            z = np.trapezoid(w, log_s, axis=1)
            total += f.max(axis=1) + np.log(z)
            moments.append(
                [np.trapezoid(w * np.exp(k * log_s)[None], log_s, axis=1) / z for k in (1, 2)]
            )
        return total, moments

    sd = np.sqrt(np.diag(cov))
    grid = grid_posterior(lambda U: terms(U)[0], centre - 9 * sd, centre + 9 * sd, names=NAMES,
                          points=60, to_physical=lambda i, u: np.exp(u))  # fmt: skip
    errors = compare(integrated.summary, grid)
    ess = {n: min(integrated.summary[n]["ess"], integrated.summary[n]["ess_tail"]) for n in NAMES}
    _within_monte_carlo_error(integrated.summary, grid.summary, ess, NAMES)
    assert errors["worst"] < 0.1
    mesh = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, 2)
    mass = grid.mass.reshape(-1) / grid.mass.sum()
    for j, name in enumerate(integrated.noise):
        m1, m2 = (mass @ m for m in terms(mesh)[1][j])
        exact_sd = math.sqrt(m2 - m1 * m1)
        got = integrated.summary[name]
        ess = min(got["ess"], got["ess_tail"])
        assert abs(got["mean"] - m1) / exact_sd < 3.5 / math.sqrt(ess), (name, got["mean"], m1)
        assert got["sd"] / exact_sd == pytest.approx(1.0, abs=0.1), (name, got["sd"], exact_sd)


def test_student_t_cannot_integrate_its_noise_factors():
    A, y, groups, centre, cov = _two_group_problem()
    with pytest.raises(FitError, match="needs likelihood='gaussian'"):
        _posterior._sample(
            lambda u: jnp.asarray(A) @ u - jnp.asarray(y), NAMES, centre, cov,
            priors_for(NAMES, None), groups, ("a", "b"), [0.0, 0.0], likelihood="student-t",
            nu=4.0, chains=2, draws=10, warmup=1, seed=0, jitter=0.5, target_accept=0.9,
            progress=False, noise_treatment="integrated",
        )  # fmt: skip
    with pytest.raises(FitError, match="noise must be one of"):
        programs._integrates("marginal", "gaussian", ("a",))
