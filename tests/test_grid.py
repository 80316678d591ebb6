"""Exact grid posterior (``fitting._bayesian.grid``) against closed forms: Gaussians,
a truncated exponential piled against a bound, a log-normal through ``to_physical``."""

import math

import numpy as np
import pytest
from scipy.stats import norm

from fitting._bayesian.grid import GridPosterior, compare, grid_posterior

Q = {"q05": 0.05, "median": 0.5, "q95": 0.95}


def gaussian(mu, cov):
    mu, prec = np.asarray(mu, float), np.linalg.inv(np.asarray(cov, float))
    return lambda U: -0.5 * np.einsum("ni,ij,nj->n", U - mu, prec, U - mu)


def covariance(sd, corr):
    sd = np.asarray(sd, float)
    return np.asarray(corr, float) * np.outer(sd, sd)


def gaussian_errors(grid, mu, sd):
    """Largest |error| / sd per name of mean, sd and quantiles against N(mu, sd^2)."""
    out = {}
    for name, m, s in zip(grid.names, mu, sd, strict=True):
        got = grid.summary[name]
        errs = [abs(got["mean"] - m), abs(got["sd"] - s)]
        errs += [abs(got[k] - (m + s * norm.ppf(q))) for k, q in Q.items()]
        out[name] = max(errs) / s
    return out


def truncated_exp_quantile(q, rate, upper):
    return -math.log1p(-q * -math.expm1(-rate * upper)) / rate


def test_correlated_gaussian_2d():
    mu, sd = np.array([1.0, -2.0]), np.array([0.5, 2.0])
    cov = covariance(sd, [[1, 0.8], [0.8, 1]])
    grid = grid_posterior(gaussian(mu, cov), mu - 20 * sd, mu + 20 * sd, names=("a", "b"))
    assert isinstance(grid, GridPosterior)
    assert grid.mass.shape == grid.log_density.shape == (40, 40)
    assert grid.mass.sum() == pytest.approx(1.0, abs=1e-12)
    # pass 2 is ~+-8 sd: 40 cells of ~0.4 sd, not 1 sd
    for i in range(2):
        h = grid.axes[i][1] - grid.axes[i][0]
        assert 0.3 * sd[i] < h < 0.5 * sd[i]
        centres, mass = grid.marginal(i)
        assert centres is grid.axes[i] and mass.sum() == pytest.approx(1.0)
    for name, err in gaussian_errors(grid, mu, sd).items():
        assert err < 0.01, (name, err)


def test_strongly_correlated_gaussian_3d():
    mu, sd = np.array([0.0, 3.0, -1.0]), np.array([1.0, 0.1, 5.0])
    corr = [[1, 0.97, 0.2], [0.97, 1, 0.2], [0.2, 0.2, 1]]
    grid = grid_posterior(
        gaussian(mu, covariance(sd, corr)), mu - 20 * sd, mu + 20 * sd, names=("x", "y", "z")
    )
    assert grid.mass.shape == (40, 40, 40)
    for name, err in gaussian_errors(grid, mu, sd).items():
        assert err < 0.02, (name, err)


@pytest.mark.parametrize("dims", [1, 2])
def test_mass_against_a_bound(dims):
    # exp(-u) on [0, 10] (times N(0, 1) in a second dimension): the mode is at the bound
    if dims == 1:
        log_p, lower, upper = (lambda U: -U[:, 0]), [0.0], [10.0]
    else:
        log_p, lower, upper = (lambda U: -U[:, 0] - 0.5 * U[:, 1] ** 2), [0.0, -20.0], [10, 20]
    grid = grid_posterior(log_p, lower, upper, names=("u", "w")[:dims])
    h = grid.axes[0][1] - grid.axes[0][0]
    assert grid.axes[0][0] - h / 2 == pytest.approx(0.0, abs=1e-12)
    for k, q in Q.items():
        exact = truncated_exp_quantile(q, 1.0, 10.0)
        assert grid.summary["u"][k] == pytest.approx(exact, rel=1e-3), k
    if dims == 2:
        assert grid.axes[1][0] > -8.0  # the Gaussian dimension was refined


def test_refinement_keeps_the_bound():
    # exp(-3u) on [0, 40]: pass 2 shrinks the upper edge to ~8 but leaves the lower one at 0
    grid = grid_posterior(lambda U: -3.0 * U[:, 0], [0.0], [40.0], names=("u",))
    h = grid.axes[0][1] - grid.axes[0][0]
    assert grid.axes[0][0] - h / 2 == pytest.approx(0.0, abs=1e-12)
    assert 7.0 < grid.axes[0][-1] + h / 2 < 10.0
    for k, q in Q.items():
        exact = truncated_exp_quantile(q, 3.0, 40.0)
        assert grid.summary["u"][k] == pytest.approx(exact, rel=1e-3), k
    coarse = grid_posterior(lambda U: -3.0 * U[:, 0], [0.0], [40.0], names=("u",), refine=False)
    assert coarse.axes[0][1] - coarse.axes[0][0] == pytest.approx(1.0)


def test_log_normal_through_to_physical():
    mu, s = 0.3, 0.4
    grid = grid_posterior(
        lambda U: -0.5 * ((U[:, 0] - mu) / s) ** 2,
        [mu - 20 * s],
        [mu + 20 * s],
        names=("k",),
        to_physical=lambda i, u: np.exp(u),
    )
    got = grid.summary["k"]
    assert got["mean"] == pytest.approx(math.exp(mu + s**2 / 2), rel=1e-3)
    assert got["median"] == pytest.approx(math.exp(mu), rel=1e-3)
    assert got["q05"] == pytest.approx(math.exp(mu + s * norm.ppf(0.05)), rel=1e-3)
    sd = math.exp(mu + s**2 / 2) * math.sqrt(math.expm1(s**2))
    assert got["sd"] == pytest.approx(sd, rel=1e-3)


def test_compare():
    mu, sd = np.array([0.0, 5.0]), np.array([1.0, 3.0])
    grid = grid_posterior(
        gaussian(mu, np.diag(sd**2)), mu - 20 * sd, mu + 20 * sd, names=("a", "b")
    )
    sampled = {name: dict(grid.summary[name]) for name in grid.names}
    sd_b = grid.summary["b"]["sd"]
    sampled["b"]["mean"] += 0.2 * sd_b
    sampled["a"]["q95"] -= 0.1 * grid.summary["a"]["sd"]
    sampled["a"]["sd"] *= 1.5
    out = compare(sampled, grid)
    assert out["b"]["mean"] == pytest.approx(0.2)
    assert out["a"]["q95"] == pytest.approx(0.1)
    assert out["a"]["sd_ratio"] == pytest.approx(1.5)
    assert out["b"]["sd_ratio"] == pytest.approx(1.0)
    for name, key in [("a", "mean"), ("a", "q05"), ("a", "median"), ("b", "q05"), ("b", "q95")]:
        assert out[name][key] == pytest.approx(0.0, abs=1e-12)
    assert out["worst"] == pytest.approx(0.2)


@pytest.mark.parametrize("block", [7, 1000, 4096])
def test_blocks_have_one_shape(block, capsys):
    mu, sd = np.array([0.5, -1.0, 2.0]), np.array([1.0, 0.5, 2.0])
    cov = covariance(sd, [[1, 0.5, 0], [0.5, 1, -0.3], [0, -0.3, 1]])
    dens, calls = gaussian(mu, cov), []

    def log_p(U):
        assert U.shape == (block, 3)
        calls.append(U.copy())
        return dens(U)

    kw = dict(names=("a", "b", "c"), points=12, progress=True)
    grid = grid_posterior(log_p, mu - 20 * sd, mu + 20 * sd, block=block, **kw)
    assert len(calls) == 2 * math.ceil(12**3 / block)
    # the padding repeats the first row of the last block
    last = calls[-1]
    tail = 12**3 - (len(calls) // 2 - 1) * block
    np.testing.assert_array_equal(last[tail:], np.repeat(last[:1], block - tail, axis=0))
    assert "grid pass 2/" in capsys.readouterr().err
    ref = grid_posterior(dens, mu - 20 * sd, mu + 20 * sd, block=12**3, **kw)
    np.testing.assert_array_equal(grid.log_density, ref.log_density)
    np.testing.assert_array_equal(grid.mass, ref.mass)
    assert grid.summary == ref.summary


def test_nan_is_minus_inf():
    # NaN and -inf outside u in (1, 3): the same posterior; a uniform density there
    def log_p(bad):
        return lambda U: np.where((U[:, 0] > 1) & (U[:, 0] < 3), 0.0, bad)

    nan = grid_posterior(log_p(np.nan), [0.0], [4.0], names=("u",), refine=False)
    inf = grid_posterior(log_p(-np.inf), [0.0], [4.0], names=("u",), refine=False)
    np.testing.assert_array_equal(nan.mass, inf.mass)
    assert np.all(nan.mass[nan.axes[0] < 1] == 0)
    assert nan.summary["u"]["median"] == pytest.approx(2.0)
    assert nan.summary["u"]["q05"] == pytest.approx(1.1)


@pytest.mark.parametrize("bad", [-np.inf, np.nan])
def test_no_mass_anywhere(bad):
    with pytest.raises(ValueError, match="-inf on every grid point"):
        grid_posterior(lambda U: np.full(len(U), bad), [0, 0], [1, 1], names=("a", "b"))


def test_bad_arguments():
    log_p = lambda U: np.zeros(len(U))
    with pytest.raises(ValueError, match="1, 2 or 3 dimensions"):
        grid_posterior(log_p, [0] * 4, [1] * 4, names="abcd")
    with pytest.raises(ValueError, match="one entry per dimension"):
        grid_posterior(log_p, [0, 0], [1, 1], names=("a",))
    with pytest.raises(ValueError, match="upper > lower"):
        grid_posterior(log_p, [0, 1], [1, 1], names=("a", "b"))
    with pytest.raises(ValueError, match="expected"):
        grid_posterior(lambda U: np.zeros(3), [0], [1], names=("a",))


def test_a_narrow_posterior_in_a_wide_box_is_refined_until_resolved():
    """A Gaussian of sd 0.02 in a box of width 20 (pass 1 cells: 25 sd wide): the refinement
    goes on while the box shrinks, and ends with the sd and quantiles to 1e-3 sd."""
    sd, centre = 0.02, 1.234

    def log_density(U):
        return -0.5 * ((U[:, 0] - centre) / sd) ** 2

    grid = grid_posterior(log_density, [-10.0], [10.0], names=("a",), points=40)
    s = grid.summary["a"]
    assert s["sd"] == pytest.approx(sd, rel=1e-3)
    assert s["q05"] == pytest.approx(centre - 1.6448536 * sd, abs=1e-3 * sd)
    assert s["q95"] == pytest.approx(centre + 1.6448536 * sd, abs=1e-3 * sd)
    assert grid.axes[0][1] - grid.axes[0][0] < sd
