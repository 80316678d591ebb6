"""Several minima (issue 52, item 4): the fit reports each distinct end point of its starts,
and SMC's reference covers every minimum with posterior mass, so that a two-mode posterior is
sampled right (against a grid of the same density)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from fitting._bayesian import posterior as _posterior
from fitting._bayesian.grid import compare, grid_posterior
from fitting._bayesian.priors import priors_for
from fitting._least_squares.fit import StartResult, distinct_minima

NAMES = ("C_A", "f0")


def _start(cost, c_a, f0, converged=True):
    return StartResult({}, {"C_A": c_a, "f0": f0}, cost, converged, 10, "")


def test_distinct_minima_one_per_end_point_lowest_first():
    starts = [
        _start(32.7, 0.1, 300.0),
        _start(32.70001, 0.1 * (1 + 1e-6), 300.0),  # the same minimum again
        _start(322.2, 0.5, 100.0),
        _start(40.0, 0.1, 900.0),
        _start(1.0, 2.0, 2.0, converged=False),  # not converged: not a minimum
    ]
    minima = distinct_minima(starts, NAMES)
    assert [m.cost for m in minima] == [32.7, 40.0, 322.2]


# A two-mode posterior in u = ln p: u0 at c +- h (each mode sd w / 2h = 0.125), tilted so that
# the modes carry unequal mass, and u1 Gaussian apart.
C, H, W, TILT, U1 = math.log(0.75), 0.6, 0.15, 1.0, math.log(300.0)


def _two_modes(u):  # numpy or JAX
    return [((u[0] - C) ** 2 - H**2) / W, (u[0] - C - 0.3) / TILT, (u[1] - U1) / 0.2]


def test_two_mode_posterior_is_covered_from_the_fits_minima_and_matches_a_grid():
    """The fit's answer at one mode, its other minimum given: the reference covers both (said
    in ``reason``) and SMC's mean, sd and quantiles match a grid of the same density."""
    mode_a = np.array([C + H, U1])
    mode_b = np.array([C - H, U1])
    cov = np.diag([0.125, 0.2]) ** 2
    result = _posterior._sample(
        lambda u: jnp.stack(_two_modes(u)), NAMES, mode_a, cov, priors_for(NAMES, None),
        np.full(3, -1), (), [], likelihood="gaussian", nu=4.0, chains=4, draws=1000, warmup=1,
        seed=2, jitter=0.5, target_accept=0.9, progress=False, minima=[mode_b],
    )  # fmt: skip
    assert result.converged, result.message
    assert "on 2 of the fit's 2 distinct minima" in result.reason

    def log_density(U):
        return -0.5 * sum(r**2 for r in _two_modes(U.T))

    grid = grid_posterior(log_density, [C - 1.6, U1 - 1.6], [C + 1.6, U1 + 1.6], names=NAMES,
                          points=80, to_physical=lambda i, u: np.exp(u))  # fmt: skip
    # the lower mode's mass, about 0.4 on the grid (what makes the test two-mode), by SMC
    lower = float(np.sum(grid.mass[np.asarray(grid.axes[0]) < C]))
    assert 0.3 < lower < 0.5
    ess = min(result.summary["C_A"]["ess"], result.summary["C_A"]["ess_tail"])
    u0 = np.log(result.draws[..., 0]).ravel()
    assert abs(np.mean(u0 < C) - lower) < 3.5 * math.sqrt(lower * (1 - lower) / ess)
    errors = compare(result.summary, grid)
    for i, n in enumerate(NAMES):
        ess = min(result.summary[n]["ess"], result.summary[n]["ess_tail"])
        assert errors[n]["mean"] < 3.5 / math.sqrt(ess), (n, errors[n])
        # A quantile judged by the grid's CDF there (the median of C_A lies in the valley
        # between the modes, where a Gaussian's standard error would not apply).
        axis = np.asarray(grid.axes[i])
        marginal = grid.mass.sum(axis=1 - i)
        step = axis[1] - axis[0]
        edges = np.exp(np.concatenate([[axis[0] - step / 2], axis + step / 2]))
        cdf = np.concatenate([[0.0], np.cumsum(marginal)]) / np.sum(marginal)
        for key, p in (("q05", 0.05), ("median", 0.5), ("q95", 0.95)):
            at = float(np.interp(result.summary[n][key], edges, cdf))
            assert abs(at - p) < 3.5 * math.sqrt(p * (1 - p) / ess), (n, key, at)
        assert errors[n]["sd_ratio"] == pytest.approx(1.0, abs=0.1), (n, errors[n])
    # an importance sample of the covering reference: no tempering from the prior
    assert result.evaluations <= 4 * 1000 * 2 + 2


def test_a_minimum_without_posterior_mass_leaves_the_reference_as_it_was():
    """A far worse minimum (cost 200 above the best) gets no share: the reference is the fit's
    t alone, and the reason says why the other minimum was left out."""
    centre = np.array([C, U1])
    cov = np.diag([0.1, 0.2]) ** 2

    def residuals(u):
        return jnp.stack([(u[0] - C) / 0.1, (u[1] - U1) / 0.2])

    far = np.array([C + 2.0, U1])  # 20 sd away: log density -200 there
    result = _posterior._sample(
        residuals, NAMES, centre, cov, priors_for(NAMES, None), np.full(2, -1), (), [],
        likelihood="gaussian", nu=4.0, chains=4, draws=500, warmup=1, seed=0, jitter=0.5,
        target_accept=0.9, progress=False, minima=[far],
    )  # fmt: skip
    assert "the fit's 1 other minima: posterior shares below" in result.reason
    assert result.converged, result.message
