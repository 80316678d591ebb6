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

Exact refits (``refit=``; Vehtari et al. 2017, section 2.1): for such an observation ``i`` the
posterior is sampled again without it (:func:`refit_without`: ``sample_posterior``'s
``leave_out``, the same options and compiled program), and its pointwise elpd becomes ``log
mean_s p(y_i | theta_s)`` over those draws, with the same likelihood as above (its noise
factor at the refit's draws). ``elpd``, ``se``, ``p_loo`` and the comparison's differences
follow from the new pointwise values.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import jax
import numpy as np
from scipy.special import gammaln, logsumexp

from jaximpact._engine.devices import engine_jit

from .._least_squares.fit import FitError
from .._least_squares.transforms import to_unbounded
from .likelihood import noise_factors
from .posterior import sample_posterior
from .programs import _model_residuals
from .report import import_arviz
from .result import PosteriorResult

__all__ = [
    "LOO",
    "compare_models",
    "exact_loo_refits",
    "loo",
    "pointwise_log_likelihood",
    "refit_without",
]

#: An observation with a larger Pareto k has an unreliable leave-one-out estimate.
MAX_KHAT = 0.7
#: Default cap on the exact refits of one posterior (each costs a posterior's sampling).
MAX_REFITS = 10


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
    residuals = np.asarray(
        _residual_program(objective, names)(U, objective._value, objective._scale)
    )
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


#: Compiled residual programs, by the objective's fingerprint: a posterior's refits share
#: one (each refit's objective is a new object with the same fingerprint).
_PROGRAMS: dict = {}


def _residual_program(objective, names):
    """``(U (n, p), value, scale) -> residuals (n, observations)``, compiled once per design."""
    key = (objective.fingerprint(), tuple(names))
    if key not in _PROGRAMS:
        if len(_PROGRAMS) >= 4:
            _PROGRAMS.pop(next(iter(_PROGRAMS)))

        def residuals(u, value, scale):
            return _model_residuals(objective, names, value, scale)(u)

        _PROGRAMS[key] = engine_jit(jax.vmap(residuals, in_axes=(0, None, None)))
    return _PROGRAMS[key]


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
    #: Observations whose pointwise elpd is an exact refit's (``khat`` stays PSIS's), those
    #: among them whose refit did not converge, and PSIS's pointwise elpd before the refits.
    refitted: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    refits_not_converged: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    pointwise_psis: np.ndarray | None = None

    @property
    def unreliable(self) -> np.ndarray:
        """Observations whose estimate is not to be trusted: k above MAX_KHAT and not
        refitted, or refitted by a posterior that did not converge."""
        bad = np.setdiff1d(np.flatnonzero(self.khat > MAX_KHAT), self.refitted)
        return np.union1d(bad, self.refits_not_converged).astype(int)


def _inference_data(az, result: PosteriorResult, max_draws: int):
    ll = pointwise_log_likelihood(result, max_draws)
    posterior = {"_index": np.zeros(ll.shape[:2])}  # ArviZ wants a posterior group
    return az.from_dict(posterior=posterior, log_likelihood={"obs": ll}), ll


def loo(
    result: PosteriorResult,
    max_draws: int = 1000,
    *,
    refit: bool | Callable[[int], PosteriorResult] = False,
    rows: Sequence[int] | None = None,
    max_refits: int = MAX_REFITS,
    announce: Callable[[int, int, int], None] | None = None,
) -> LOO:
    """PSIS-LOO of ``result`` (a `PosteriorResult` of :func:`sample_posterior`); needs
    ArviZ (``pip install "jaximpact[posterior]"``).

    ``refit``: True (:func:`refit_without`) or ``i -> the posterior without observation i``:
    the observations ``rows`` (indices from 0; default those with Pareto k above
    :data:`MAX_KHAT`, highest first, at most ``max_refits``) get their exact leave-one-out
    elpd instead of PSIS's. ``announce(i, n, total)`` is called before the n-th of ``total``
    refits (progress)."""
    az = import_arviz("PSIS-LOO")
    data, ll = _inference_data(az, result, max_draws)
    with warnings.catch_warnings():  # its Pareto k warning: said in ``problems`` instead
        warnings.simplefilter("ignore", UserWarning)
        out = az.loo(data, pointwise=True)
    khat = np.asarray(out.pareto_k, float)
    psis = LOO(
        elpd=float(out.elpd_loo), se=float(out.se), p_loo=float(out.p_loo),
        pointwise=np.asarray(out.loo_i, float), khat=khat, draws=int(ll.shape[0] * ll.shape[1]),
        problems=[],
    )  # fmt: skip
    if refit is not False and refit is not None:
        if refit is True:
            refit = lambda i: refit_without(result, i)  # noqa: E731
        if rows is None:
            rows = _rows_to_refit(khat, max_refits)
        psis = exact_loo_refits(psis, rows, refit, max_draws, announce)
    psis.problems = _problems(psis)
    return psis


def _rows_to_refit(khat: np.ndarray, max_refits: int) -> list[int]:
    """Observations with k above MAX_KHAT, highest k first, at most ``max_refits``."""
    if not (isinstance(max_refits, int) and max_refits >= 0):
        raise FitError(f"max_refits must be an integer >= 0, got {max_refits!r}")
    bad = np.flatnonzero(khat > MAX_KHAT)
    return [int(i) for i in bad[np.argsort(-khat[bad], kind="stable")][:max_refits]]


def refit_without(result: PosteriorResult, i: int, *, progress: bool = False) -> PosteriorResult:
    """The posterior of ``result``'s model and data without observation ``i`` (from 0): the
    same fit (the sampler's start), priors, likelihood and options (seed included)."""
    if result.fit is None or not result.options:
        raise FitError("a refit needs a result of sample_posterior")
    fit = result.fit
    return sample_posterior(
        fit.objective.scene, fit.objective.observations, result.params, priors=result.priors,
        fit_result=fit, progress=progress, leave_out=(*result.left_out, i), **result.options,
    )  # fmt: skip


def exact_loo_refits(
    psis: LOO,
    rows: Sequence[int],
    sample_without: Callable[[int], PosteriorResult],
    max_draws: int = 1000,
    announce: Callable[[int, int, int], None] | None = None,
) -> LOO:
    """``psis`` with the pointwise elpd of each observation in ``rows`` replaced by its exact
    leave-one-out value: ``log mean_s p(y_i | theta_s)`` over (up to ``max_draws``) draws
    ``theta_s`` of ``sample_without(i)``, the posterior without observation ``i``; ``elpd``,
    ``se`` (``sqrt(n var(pointwise))``, as PSIS's) and ``p_loo`` recomputed."""
    n = psis.pointwise.size
    rows = [int(i) for i in dict.fromkeys(rows)]
    if any(not 0 <= i < n for i in rows):
        raise FitError(f"rows to refit must lie in [0, {n}), got {rows}")
    pointwise = psis.pointwise.copy()
    failed = []
    for k, i in enumerate(rows):
        if announce is not None:
            announce(i, k + 1, len(rows))
        without = sample_without(i)
        if i not in without.left_out:
            raise FitError(f"the refit without observation {i + 1} left out {without.left_out}")
        if not without.converged:
            failed.append(i)
        pointwise[i] = exact_elpd(pointwise_log_likelihood(without, max_draws)[..., i])
    # p_loo = lppd - elpd (ArviZ's): the refits move elpd, not lppd
    elpd = float(np.sum(pointwise))
    return LOO(
        elpd=elpd, se=float(math.sqrt(n * np.var(pointwise))),
        p_loo=psis.p_loo + psis.elpd - elpd, pointwise=pointwise, khat=psis.khat,
        draws=psis.draws, problems=list(psis.problems), refitted=np.array(sorted(rows), int),
        refits_not_converged=np.array(sorted(failed), int), pointwise_psis=psis.pointwise,
    )  # fmt: skip


def exact_elpd(ll: np.ndarray) -> float:
    """``log mean exp(ll)`` over all draws: an observation's leave-one-out predictive density
    from its log likelihood at draws of the posterior without it."""
    ll = np.asarray(ll, float).ravel()
    return float(logsumexp(ll) - math.log(ll.size))


def _rows(index) -> str:
    return ", ".join(str(int(i) + 1) for i in index[:10]) + (", ..." if len(index) > 10 else "")


def _problems(v: LOO) -> list[str]:
    """Which leave-one-out terms are unreliable, and which were refitted exactly."""
    problems = []
    exact = np.setdiff1d(v.refitted, v.refits_not_converged)
    if exact.size:
        problems.append(
            f"{exact.size} observation(s) refitted exactly (rows {_rows(exact)}; Pareto k up to "
            f"{np.max(v.khat[exact]):.2f}): their leave-one-out terms are exact, not PSIS's"
        )
    if v.refits_not_converged.size:
        problems.append(
            f"{v.refits_not_converged.size} exact refit(s) did not converge (rows "
            f"{_rows(v.refits_not_converged)}): their leave-one-out estimates are unreliable"
        )
    bad = np.setdiff1d(np.flatnonzero(v.khat > MAX_KHAT), v.refitted)
    if bad.size:
        problems.append(
            f"{bad.size} observation(s) with Pareto k above {MAX_KHAT} (rows {_rows(bad)}): "
            "their leave-one-out estimates are unreliable"
        )
    return problems


def compare_models(
    results: Mapping[str, PosteriorResult],
    max_draws: int = 1000,
    *,
    refit: bool | Callable[[str, int], PosteriorResult] = False,
    max_refits: int = MAX_REFITS,
    announce: Callable[[str, int, int, int], None] | None = None,
) -> list[dict]:
    """Models fitted to the same observations, best first: ``name``, ``elpd``, ``se``,
    ``elpd_diff`` (to the best) and its standard error ``se_diff`` (from the pointwise
    differences, Vehtari et al. 2017), ``p_loo``, ``max_khat``, ``problems``, ``refitted``
    (observations whose term is an exact refit's) and ``unreliable`` (those with Pareto k
    above 0.7 left to PSIS, or whose refit did not converge).

    ``refit``: True (:func:`refit_without`) or ``(name, i) -> the posterior of model name
    without observation i``: up to ``max_refits`` observations of each model with k above
    0.7 are refitted exactly (:func:`loo`); ``announce(name, i, n, total)`` before each."""
    if len(results) < 2:
        raise FitError("compare_models needs at least two posteriors")
    sizes = {name: len(r.noise_groups) for name, r in results.items() if r.noise_groups is not None}
    if len(set(sizes.values())) > 1:
        raise FitError(f"the posteriors were fitted to different observations: {sizes}")
    each = {}
    for name, r in results.items():
        if refit is True:
            own = lambda i, r=r: refit_without(r, i)  # noqa: E731
        elif refit:
            own = lambda i, name=name: refit(name, i)  # noqa: E731
        else:
            own = False
        said = None if announce is None else lambda i, n, t, name=name: announce(name, i, n, t)
        each[name] = loo(r, max_draws, refit=own, max_refits=max_refits, announce=said)
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
                refitted=int(v.refitted.size),
                unreliable=int(v.unreliable.size),
            )  # fmt: skip
        )
    return rows
