"""MCMC convergence diagnostics: agreement with ArviZ and the properties they are built for."""

import warnings

import numpy as np
import pytest
from scipy.signal import lfilter

from fitting._bayesian.diagnostics import (
    ess,
    ess_bulk,
    ess_tail,
    mcse_quantile,
    pareto_khat,
    rank_rhat,
    split_rhat,
)


@pytest.fixture(scope="module")
def az():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)  # ArviZ announces its refactor on import
        return pytest.importorskip("arviz")


def ar1(rng, chains, draws, phi):
    """Stationary AR(1) chains with unit innovations."""
    noise = rng.normal(size=(chains, draws))
    noise[:, 0] /= np.sqrt(1 - phi**2)
    return lfilter([1.0], [1.0, -phi], noise, axis=1)


def split(x):
    half = x.shape[1] // 2
    return np.concatenate([x[:, :half], x[:, x.shape[1] - half :]])


CASES = {
    "iid normal": lambda rng: rng.normal(size=(4, 1000)),
    "AR(1) phi=0.9": lambda rng: ar1(rng, 4, 1000, 0.9),
    "shifted means": lambda rng: rng.normal(size=(4, 500)) + 0.5 * np.arange(4)[:, None],
    "Cauchy": lambda rng: rng.standard_cauchy(size=(4, 800)),
    "odd draws": lambda rng: ar1(rng, 3, 301, 0.5),
    "ties": lambda rng: rng.integers(0, 4, size=(4, 200)).astype(float),
}


@pytest.mark.parametrize("name", CASES)
def test_agrees_with_arviz(az, name):
    rng = np.random.default_rng(sum(map(ord, name)))
    x = CASES[name](rng)
    pairs = [
        (split_rhat(x), az.rhat(x, method="split")),
        (rank_rhat(x), az.rhat(x, method="rank")),
        (ess_bulk(x), az.ess(x, method="bulk")),
        (ess_tail(x), az.ess(x, method="tail")),
        # ArviZ's "mean" ESS splits the chains; ours takes them as given.
        (ess(split(x)), az.ess(x, method="mean")),
        (mcse_quantile(x, 0.3), az.mcse(x, method="quantile", prob=0.3)),
        (mcse_quantile(x, 0.97), az.mcse(x, method="quantile", prob=0.97)),
    ]
    for ours, theirs in pairs:
        assert ours == pytest.approx(float(theirs), rel=1e-9)


def test_degenerate_input_like_arviz(az):
    const = np.full((4, 50), 2.5)
    assert np.isnan(split_rhat(const)) and np.isnan(rank_rhat(const))
    for f in (ess, ess_bulk, ess_tail):
        assert f(const) == const.size
    assert float(az.ess(const, method="bulk")) == const.size

    x = np.random.default_rng(0).normal(size=(4, 100))
    x[2, 7] = np.nan
    for f in (split_rhat, rank_rhat, ess, ess_bulk, ess_tail):
        assert np.isnan(f(x))
    assert np.isnan(mcse_quantile(x, 0.5))
    for f in (split_rhat, rank_rhat, ess, ess_bulk, ess_tail):  # fewer than 4 draws per chain
        assert np.isnan(f(np.arange(12.0).reshape(4, 3)))
    with pytest.raises(ValueError, match="chains, draws"):
        ess(np.zeros((2, 3, 4)))


def test_single_chain():
    # ArviZ gives NaN for the R-hat of one chain; the R-hat of its two halves is still defined.
    x = ar1(np.random.default_rng(1), 1, 10000, 0.5)
    assert 0.99 < split_rhat(x) < 1.01 and 0.99 < rank_rhat(x) < 1.01
    expected = x.size * (1 - 0.5) / (1 + 0.5)
    for f in (ess, ess_bulk):
        assert f(x) == pytest.approx(expected, rel=0.25)
    assert ess(x[0]) == ess(x)  # a 1-D array is one chain


def test_rhat_near_one_for_iid_draws():
    x = np.random.default_rng(2).normal(size=(4, 1000))
    assert abs(split_rhat(x) - 1) < 0.01
    assert abs(rank_rhat(x) - 1) < 0.01


def test_rank_rhat_sees_a_chain_with_larger_scale():
    x = np.random.default_rng(3).normal(size=(4, 1000))
    x[0] *= 3  # same mean, three times the spread: invisible to the classic R-hat
    assert split_rhat(x) < 1.01
    assert rank_rhat(x) > 1.05


def test_rhat_sees_shifted_chains():
    x = np.random.default_rng(4).normal(size=(4, 1000)) + 0.5 * np.arange(4)[:, None]
    assert split_rhat(x) > 1.05 and rank_rhat(x) > 1.05


def test_ess_of_iid_draws_is_the_number_of_draws():
    # At this size the estimates stay within about 6 % of S (200 seeds tried).
    x = np.random.default_rng(5).normal(size=(4, 10000))
    for f in (ess, ess_bulk, ess_tail):
        assert f(x) == pytest.approx(x.size, rel=0.1)


def test_ess_of_ar1_chains():
    phi = 0.9
    x = ar1(np.random.default_rng(6), 4, 10000, phi)
    expected = x.size * (1 - phi) / (1 + phi)  # S / (1 + 2 sum_t phi^t)
    assert ess(x) == pytest.approx(expected, rel=0.25)
    assert ess_bulk(x) == pytest.approx(expected, rel=0.25)


def test_tail_ess_sees_chains_that_disagree_in_the_tails():
    x = np.random.default_rng(7).normal(size=(4, 1000))
    a = np.abs(x[2:])
    x[2:] = np.sign(x[2:]) * np.where(a > 1, 1 + 0.2 * (a - 1), a)  # same bulk, short tails
    assert ess_bulk(x) > 0.75 * x.size
    assert ess_tail(x) < 0.2 * ess_bulk(x)


def test_mcse_quantile_of_iid_draws():
    # The asymptotic standard error of the p quantile is sqrt(p (1 - p) / S) / density(q_p).
    x = np.random.default_rng(8).normal(size=(4, 5000))
    p, q = 0.5, 0.0
    expected = np.sqrt(p * (1 - p) / x.size) * np.sqrt(2 * np.pi) * np.exp(q**2 / 2)
    assert mcse_quantile(x, p) == pytest.approx(expected, rel=0.3)


@pytest.mark.parametrize("shape", [0.2, 0.5, 0.9])
def test_pareto_khat_recovers_the_shape_of_pareto_weights(shape):
    """Weights with a Pareto tail of shape k (survival x^(-1/k)): the estimate is k."""
    rng = np.random.default_rng(3)
    weights = rng.uniform(size=200_000) ** -shape
    assert pareto_khat(weights) == pytest.approx(shape, abs=0.03)


def test_pareto_khat_agrees_with_blackjax():
    """The numpy estimator against blackjax's (JAX) one, which the thresholds were set with."""
    import jax
    from blackjax import pareto_khat as blackjax_khat

    assert jax.config.jax_enable_x64  # (the suite's conftest)
    rng = np.random.default_rng(4)
    for n, scale in [(50, 1.0), (1000, 2.0), (4000, 0.5), (4000, 4.0)]:
        log_w = scale * rng.standard_normal(n)
        w = np.exp(log_w - log_w.max())
        expected = float(blackjax_khat(jax.numpy.asarray(w), tail="upper"))
        assert pareto_khat(w) == pytest.approx(expected, abs=1e-9)
    assert pareto_khat(np.ones(100)) == 0.0
