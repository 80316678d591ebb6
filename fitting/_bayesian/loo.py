"""Which model do the data support: leave-one-out cross-validation of posteriors (PSIS-LOO,
Vehtari, Gelman & Gabry 2017, "Practical Bayesian model evaluation using leave-one-out
cross-validation and WAIC", Statistics and Computing 27, through ArviZ).

Each observation's log likelihood is evaluated at (up to ``max_draws``) posterior draws, with
exactly the likelihood the sampler used: the same residuals (the capture hinge included), noise
factors and Gaussian or Student-t density, with the normalizing terms kept (``-log sigma -
log sqrt(2 pi)`` for the Gaussian), so that models fitted to the same data compare on one
scale. ``elpd_loo`` is the expected log predictive density of a new observation; its standard
error comes from the spread over observations, and each observation's Pareto k says whether
its leave-one-out estimate can be trusted (k > 0.7: not; the observation is too influential
for importance sampling, and the comparison should not rest on it).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import jax
import numpy as np
from scipy.special import gammaln

from jaximpact._engine.devices import engine_jit

from .._least_squares.fit import FitError
from .._least_squares.transforms import to_unbounded
from .posterior import PosteriorResult, _model_residuals, noise_factors
from .report import import_arviz

__all__ = ["LOO", "compare_models", "loo", "pointwise_log_likelihood"]

#: An observation with a larger Pareto k has an unreliable leave-one-out estimate.
MAX_KHAT = 0.7


def pointwise_log_likelihood(result: PosteriorResult, max_draws: int = 1000) -> np.ndarray:
    """``(chains, draws, observations)`` log likelihood of each observation at up to
    ``max_draws`` draws (evenly spaced within each chain), with the sampler's likelihood."""
    objective = result.objective
    if objective is None:
        raise FitError("the log likelihood needs a result of sample_posterior")
    if not (isinstance(max_draws, int) and max_draws >= result.chains):
        raise FitError(f"max_draws must be an integer >= {result.chains} (the chains)")
    names, p = result.params, len(result.params)
    chains, draws = result.draws.shape[:2]
    keep = np.unique(np.linspace(0, draws - 1, max(1, max_draws // chains)).astype(int))
    theta = result.draws[:, keep].reshape(-1, p)
    U = np.stack([to_unbounded(names, t) for t in theta])
    residuals = np.asarray(engine_jit(jax.vmap(_model_residuals(objective, names)))(U))
    noise = result.noise_draws[:, keep].reshape(len(theta), -1)
    factor = noise_factors(noise, result.noise_groups)
    scale = np.asarray(objective.scale, float) * factor  # in the observations' units
    x = residuals / factor
    if result.likelihood == "gaussian":
        ll = -0.5 * x * x - np.log(scale) - 0.5 * math.log(2 * math.pi)
    else:
        nu = float(result.nu)
        const = float(gammaln((nu + 1) / 2) - gammaln(nu / 2)) - 0.5 * math.log(nu * math.pi)
        ll = const - 0.5 * (nu + 1) * np.log1p(x * x / nu) - np.log(scale)
    return ll.reshape(chains, keep.size, -1)


@dataclass
class LOO:
    """PSIS-LOO of one posterior: ``elpd`` (expected log predictive density of a new
    observation, summed over observations), its standard error ``se``, ``p_loo`` (effective
    number of parameters), per observation ``pointwise`` elpd and ``khat`` (Pareto k), and
    ``problems`` (observations whose k is above MAX_KHAT)."""

    elpd: float
    se: float
    p_loo: float
    pointwise: np.ndarray
    khat: np.ndarray
    draws: int
    problems: list[str]


def _inference_data(az, result: PosteriorResult, max_draws: int):
    ll = pointwise_log_likelihood(result, max_draws)
    posterior = {"_index": np.zeros(ll.shape[:2])}  # ArviZ wants a posterior group
    return az.from_dict(posterior=posterior, log_likelihood={"obs": ll}), ll


def loo(result: PosteriorResult, max_draws: int = 1000) -> LOO:
    """PSIS-LOO of ``result`` (a `PosteriorResult` of :func:`sample_posterior`); needs
    ArviZ (``pip install "jaximpact[posterior]"``)."""
    az = import_arviz("PSIS-LOO")
    data, ll = _inference_data(az, result, max_draws)
    with warnings.catch_warnings():  # its Pareto k warning: said in ``problems`` instead
        warnings.simplefilter("ignore", UserWarning)
        out = az.loo(data, pointwise=True)
    khat = np.asarray(out.pareto_k, float)
    bad = np.flatnonzero(khat > MAX_KHAT)
    problems = (
        [
            f"{bad.size} observation(s) with Pareto k above {MAX_KHAT} (rows "
            + ", ".join(str(int(i) + 1) for i in bad[:10])
            + "): their leave-one-out estimates are unreliable"
        ]
        if bad.size
        else []
    )
    return LOO(
        elpd=float(out.elpd_loo), se=float(out.se), p_loo=float(out.p_loo),
        pointwise=np.asarray(out.loo_i, float), khat=khat, draws=int(ll.shape[0] * ll.shape[1]),
        problems=problems,
    )  # fmt: skip


def compare_models(results: Mapping[str, PosteriorResult], max_draws: int = 1000) -> list[dict]:
    """Models fitted to the same observations, best first: ``name``, ``elpd``, ``se``,
    ``elpd_diff`` (to the best) and its standard error ``se_diff`` (from the pointwise
    differences, Vehtari et al. 2017), ``p_loo``, ``max_khat``, ``problems``."""
    if len(results) < 2:
        raise FitError("compare_models needs at least two posteriors")
    each = {name: loo(r, max_draws) for name, r in results.items()}
    sizes = {name: v.pointwise.size for name, v in each.items()}
    if len(set(sizes.values())) != 1:
        raise FitError(f"the posteriors were fitted to different observations: {sizes}")
    order = sorted(each, key=lambda n: -each[n].elpd)
    best = each[order[0]]
    rows = []
    for name in order:
        v = each[name]
        diff = v.pointwise - best.pointwise
        rows.append(
            dict(
                name=name,
                elpd=v.elpd,
                se=v.se,
                elpd_diff=float(np.sum(diff)),
                se_diff=float(math.sqrt(diff.size * np.var(diff))),
                p_loo=v.p_loo,
                max_khat=float(np.max(v.khat)),
                problems=v.problems,
            )  # fmt: skip
        )
    return rows
