"""Bayesian posterior of the fitted parameters: sequential Monte Carlo (default), the
independence sampler or HMC.

The log density calls the simulator directly, so it (and, for HMC, its gradient: the
simulator's own derivatives, see ``jaximpact._engine.simulate``) is one compiled JAX program,
evaluated for many points at once. Samplers (``sampler=``, :data:`SAMPLERS`):

- ``smc`` (``auto``, the default): tempered SMC (``_smc``) in the coordinates of ``_space``
  (the logit of each log-uniform prior's range: no walls), in independent populations, from
  the fit's Student-t mixed with the prior where that covers the posterior (its importance
  weights say so), else from the prior. Values only; no Gaussian shape assumed: ridges, mass
  against a prior's end, weakly determined parameters, captured impacts.
- ``independence``: independence Metropolis on a t placed by the fit and a pilot (for
  nearly Gaussian posteriors; refused where its Pareto k exceeds 0.7).
- ``hmc``: blackjax's HMC, chains in step (one batch per gradient evaluation), in the
  fit's solver variables ``u`` of ``_transforms``.

Likelihood (``r``: the fit's weighted residuals, ``(model - observed) / scale``):

- ``gaussian``: ``r / s ~ N(0, 1)``; ``s = 1`` where the data give sigma, else a factor
  ``s_k`` per observable ``k`` (log-uniform on [1e-3, 1e3]) on the default scale, integrated
  out in closed form (``noise="auto"``: the sampler runs on the physical parameters only, and
  each factor is drawn afterwards from its exact conditional; ``_likelihood``), or sampled
  (``noise="sampled"``);
- ``student-t``: ``r / s ~ t(nu)`` (heavy tails: an outlier pulls less); its factors sampled.

A run is good only when every R-hat is at most :data:`MAX_RHAT` (SMC: rank-normalized, over
its independent populations, with bulk and tail ESS at least :data:`MIN_ESS`) and no
transition diverged; otherwise ``status`` is ``"not converged"`` and ``problems`` says why.
``reason`` says which sampler ran and why.
"""

from __future__ import annotations

import math
import operator
import sys
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaximpact._engine.devices import compiler_options, engine_jit, gathered
from jaximpact._io.cache import compiled_program, runtime_checks_as_nan

from .._least_squares.fit import SAME_VALUES, FitResult, fit
from .._least_squares.objective import FitError, Objective, check_names
from .._least_squares.transforms import dphys_du, to_physical, to_unbounded
from . import diagnostics
from .likelihood import (
    LIKELIHOODS,
    NOISE_FACTOR_RANGE,
    NOISE_TREATMENTS,
    draw_noise_factors,
    group_sums,
    log_likelihood_function,
    noise_factors,
    noise_groups,
)
from .priors import Prior, priors_for
from .smc import IMPORTANCE_KHAT, IMPORTANCE_MAX_WEIGHT, Reference, SMCRun, run_smc
from .space import SamplingSpace

__all__ = ["LIKELIHOODS", "MAX_RHAT", "NOISE_TREATMENTS", "PosteriorResult", "sample_posterior"]

#: A run with a larger split R-hat for any parameter is not called converged.
MAX_RHAT = 1.01
#: HMC trajectory length in units of the metric: a quarter period of a Gaussian posterior
#: whose covariance the metric matches, where successive draws are independent.
TRAJECTORY = math.pi / 2
#: Most leapfrog steps of one transition (a step size collapsed by a bad region stops here).
MAX_LEAPFROG = 64
#: Default solver rtol of the posterior's evaluations in float64 (scenes that set their own
#: rtol keep it). The sampler needs the log density to well under 0.1 and its gradient to a few
#: per cent; rtol 1e-8 gives both with a wide margin (measured in BENCHMARKS.md: "Posterior
#: and design") in about half the steps of the fit's default 1e-10; rtol 1e-7 (the default)
#: keeps cor_n of 200 x 25 Table 1 impacts within 1.0e-5 of rtol 1e-10 (rms 2.2e-6, 0.07 % of
#: a sigma of 0.003) in 90 steps against 127 at 1e-8 and 246 at 1e-10.
SAMPLING_RTOL = 1e-7
#: Step limit of the sampler's evaluations with an explicit solver (the scene's, if smaller).
#: 20,000 Table 1 impacts over C_A 1e-3..5, C_H 0.1..0.5, f0 50..1500 s/m, N/m, 0.05-8 m/s
#: take at most 189 steps at rtol 1e-7; the prior's stiff corners (C_H of tens of s/m) take
#: up to the default 4,096 and hold up the batch they are in (prior draws evaluate 2.1x faster
#: with 1,024). An impact past the limit fails: zero posterior density there.
SAMPLING_MAX_STEPS = 1024
#: The sampler's step loop: lanes refilled as impacts finish (``jaximpact._engine.simulate``,
#: ``default_loop``). Its points from the prior need very different step counts (6 Table 1
#: impacts x 500 prior draws: median 48, 90 % 116, at most the limit of 1,024), so that chunks
#: of 128 lanes ran 7.9x the steps their impacts needed; the pool evaluated 4,700 such points
#: per second against 1,250 (2 cores), for 3.7 s more compiling.
SAMPLING_LOOP = "pool"
#: Default warm-up steps per chain (see `_run_hmc`: it starts from the least-squares shape).
WARMUP = 300
#: Samplers: ``auto`` (= ``smc``, or ``hmc`` when the chains' starts are given), ``smc``,
#: ``independence`` (values only: every proposal of every chain evaluated in a few large
#: batches; right only where its t proposal covers the posterior) and ``hmc`` (gradients).
SAMPLERS = ("auto", "independence", "hmc", "smc")
#: SMC's local moves: a random walk on values, or MALA on the log density's gradient.
MOVES = ("values", "mala")
#: Largest Pareto shape of the importance weights at which the independence sampler's
#: proposal is trusted (Vehtari et al. 2024, "Pareto smoothed importance sampling").
MAX_KHAT = 0.7
#: Pilot draws that place the independence sampler's proposal.
PILOT = 1000
#: Proposal: Student-t with this many degrees of freedom, covariance inflated by this factor.
PROPOSAL_NU = 7.0
PROPOSAL_INFLATION = 1.15
#: Points evaluated per compiled call of the independence sampler (times the impacts: lanes).
BLOCK = 500
#: Times the independence sampler may re-place its proposal (on the importance-weighted
#: moments of its last batch, wider by REFINE_INFLATION) while the Pareto k is above MAX_KHAT,
#: before it gives up (``auto``: HMC, which takes minutes).
REFINEMENTS = 2
REFINE_INFLATION = 1.3
#: Times the independence sampler may extend its chains by ``draws`` more each while a split
#: R-hat is above MAX_RHAT (Pareto k fine: the proposal covers the posterior, and R-hat a
#: little above 1.01 is the sampling noise of short chains). In a 20-replication calibration
#: run, 3 runs were refused at R-hat 1.0105-1.0139 without it.
EXTENSIONS = 2
#: Only chains of at least this many draws that are just above the limit (R-hat up to this)
#: are extended: a larger R-hat means chains that do not mix, and short runs stay short.
MIN_DRAWS_TO_EXTEND = 100
MAX_RHAT_TO_EXTEND = 1.05


@dataclass
class PosteriorResult:
    """Result of :func:`sample_posterior`.

    Attributes:
        params: sampled parameter names.
        draws: ``(chains, draws, p)`` physical values.
        noise: names of the sampled noise factors (``sigma_factor[cor_n]``: sigma in units of
            the default scale of that observable), and ``noise_draws`` ``(chains, draws, k)``.
        summary: ``{name: {mean, median, sd, q05, q95, rhat, ess}}`` for params and noise.
        correlation: ``(p, p)`` correlation of the draws (physical values).
        divergences: divergent transitions after warm-up (all chains).
        status: ``"converged"`` or ``"not converged"``; ``converged``; ``problems``.
        priors: ``{name: Prior}``; likelihood, nu.
        sampler: ``"independence"`` or ``"hmc"``; khat: Pareto shape of the independence
            proposal's importance weights (NaN for HMC).
        step_size: HMC's per chain after adaptation (NaN for the independence sampler);
            acceptance: mean acceptance rate.
        evaluations: log-density evaluations (the independence sampler: points; HMC:
            gradient evaluations of all chains at once).
        timings: seconds: ``fit`` (a given ``fit_result``'s own time), ``compile``,
            ``warmup``, ``sampling``, ``total`` (the fit included).
        fit: the least-squares `FitResult` the chains started from (None for a toy oracle).
        log_density: ``(chains, draws)``.
    """

    params: tuple[str, ...]
    draws: np.ndarray
    noise: tuple[str, ...]
    noise_draws: np.ndarray
    summary: dict
    correlation: np.ndarray
    divergences: int
    status: str
    converged: bool
    problems: list[str]
    priors: dict[str, Prior]
    likelihood: str
    nu: float
    step_size: np.ndarray
    acceptance: float
    evaluations: int
    timings: dict[str, float]
    log_density: np.ndarray
    fit: FitResult | None = None
    program: Callable | None = field(default=None, repr=False)
    #: The objective the sampler evaluated (the fit's, at the sampling tolerance).
    objective: Objective | None = field(default=None, repr=False)
    noise_groups: np.ndarray | None = field(default=None, repr=False)
    sampler: str = "hmc"
    khat: float = math.nan
    #: SMC: tempering steps per population, and the mean over populations of the log
    #: marginal likelihood's estimate (up to the likelihood's constant terms).
    stages: np.ndarray | None = None
    log_evidence: float = math.nan
    #: Which sampler ran and why (printed and in the JSON).
    reason: str = ""
    #: Observations whose likelihood terms were left out (``sample_posterior``'s
    #: ``leave_out``), and the sampling options (so that a refit can repeat them).
    left_out: tuple[int, ...] = ()
    options: dict = field(default_factory=dict, repr=False)
    #: How the noise factors entered: ``"integrated"`` (closed form; each drawn afterwards
    #: from its exact conditional), ``"sampled"`` (coordinates of the sampler) or ``"none"``
    #: (every datum has a sigma).
    noise_treatment: str = "none"

    @property
    def chains(self) -> int:
        return self.draws.shape[0]

    @property
    def message(self) -> str:
        return self.status + ("" if not self.problems else ": " + "; ".join(self.problems))


# -- the log density ------------------------------------------------------------------------


def _model_residuals(objective: Objective, names, value=None, scale=None):
    """``u -> r``: the fit's weighted residuals as a JAX function (values and derivatives from
    the simulator's step loop; no host round trip); ``value``, ``scale``: observed values and
    scales in place of the objective's."""
    value = objective._value if value is None else value
    scale = objective._scale if scale is None else scale

    def residuals(u):
        theta = to_physical(names, u)
        result = objective._simulate_impl(theta)
        return objective.residuals_from_result(result, objective.hertz_time(theta), value, scale)

    return residuals


def _log_density(
    residuals, names, priors, groups, n_noise, likelihood, nu, weight=None, integrated=False
):
    """``z = (u, log noise factors) -> log posterior`` (up to a constant); ``integrated``: the
    ``n_noise`` factors integrated out (``z = u``)."""
    p = len(names)
    terms = _posterior_terms(names, priors, groups, n_noise, likelihood, nu, integrated)
    weight = None if weight is None else jnp.asarray(weight)
    return lambda z: terms(z, residuals(z[:p]), weight)


def _posterior_terms(names, priors, groups, n_noise, likelihood, nu, integrated=False):
    """``(z, r) -> log posterior`` given the residuals ``r`` at ``z``'s parameters (``z``: the
    fit's ``u`` and the log noise factors, none where ``integrated``)."""
    p = len(names)
    lo, hi = (math.log(v) for v in NOISE_FACTOR_RANGE)
    log_likelihood = log_likelihood_function(groups, n_noise, likelihood, nu, integrated)

    def log_density(z, r, weight=None):
        u, log_s = z[:p], z[p:]
        lp = sum(priors[n].log_density_u(n, u[i]) for i, n in enumerate(names))
        if n_noise and not integrated:
            inside = jnp.all((log_s >= lo) & (log_s <= hi))
            lp = lp + jnp.where(inside, 0.0, -jnp.inf)
        return lp + log_likelihood(r, log_s, weight)

    return log_density


def _noise_groups(objective: Objective) -> tuple[np.ndarray, tuple[str, ...]]:
    """Noise factor of each observation (index, -1 where the data give sigma) and the names."""
    return noise_groups(objective.observations.observable, objective.observations.sigma)


# -- the sampler ----------------------------------------------------------------------------


def _run_hmc(log_density, z0, metric, *, warmup, draws, seed, target_accept, progress):
    """Warm-up then draws of every chain (rows of ``z0``), all chains one batch.

    Returns draws ``(C, D, d)``, log densities ``(C, D)``, divergent ``(C, D)``, acceptance
    ``(C, D)``, the step size, the log-density evaluations (of the whole batch) and the
    seconds of warm-up and sampling.

    Each step is one HMC transition of every chain with the same number of leapfrog steps
    (blackjax's HMC kernel, ``vmap``-ed): a trajectory of :data:`TRAJECTORY` (in units of the
    metric, jittered by a factor drawn from [0.5, 1.5] per step) divided by the step size. The
    chains thus stay in step, each evaluation of the log density fills the batch with all
    chains, and no chain waits for a deeper tree (NUTS's cost under ``vmap``). The warm-up
    starts from the least-squares covariance ``metric`` (the posterior's own shape, the C_A-f0
    ridge included):

    1. first half: dual averaging of one step size shared by all chains, with ``metric``;
    2. the metric re-estimated from the second quarter's draws of all chains pooled, shrunk
       slightly towards ``metric``;
    3. second half: dual averaging again with that metric.
    """
    import blackjax
    from blackjax.adaptation.step_size import dual_averaging_adaptation

    chains, dim = z0.shape
    kernel = blackjax.hmc.build_kernel()

    def one(key, state, step_size, inverse_mass_matrix, n_leapfrog):
        return kernel(key, state, log_density, step_size, inverse_mass_matrix, n_leapfrog)

    # One compiled program for every step of warm-up and sampling (the step size, metric and
    # leapfrog count are inputs).
    step = engine_jit(jax.vmap(one, in_axes=(0, 0, None, None, None)))
    da_init, da_update, _ = dual_averaging_adaptation(target_accept)
    da_update = jax.jit(da_update)
    rng = np.random.default_rng(seed)
    keys = iter(jax.random.split(jax.random.PRNGKey(seed), warmup + draws))
    evaluations = [1]

    def transition(states, step_size, imm):
        n = int(np.clip(np.ceil(rng.uniform(0.5, 1.5) * TRAJECTORY / step_size), 1, MAX_LEAPFROG))
        evaluations[0] += n
        key = jax.random.split(next(keys), chains)
        return step(key, states, jnp.asarray(step_size), jnp.asarray(imm), jnp.asarray(n))

    def bar(total, what):
        return _progress_bar(total, f"posterior {what} ({chains} chains)", "step", progress)

    t0 = time.perf_counter()
    states = engine_jit(jax.vmap(lambda z: blackjax.hmc.init(z, log_density)))(jnp.asarray(z0))
    imm = np.asarray(metric, dtype=float)
    step_size = 0.5  # in units of the metric's standard deviations
    first = warmup // 2
    pooled = []
    with bar(warmup, "warm-up") as progress_bar:
        for phase, (begin, stop) in enumerate(((0, first), (first, warmup))):
            da = da_init(step_size)
            for i in range(begin, stop):
                states, info = transition(states, float(np.exp(da.log_step_size)), imm)
                accept = np.nan_to_num(np.asarray(info.acceptance_rate), nan=0.0)
                da = da_update(da, float(np.mean(accept)))
                if phase == 0 and i >= first // 2:
                    pooled.append(np.asarray(states.position))
                progress_bar.update()
                progress_bar.set_postfix(evaluations=evaluations[0], refresh=False)
            if stop > begin:
                step_size = float(np.exp(da.log_step_size_avg))
            if phase == 0 and len(pooled) * chains > 2 * dim:
                imm = _pooled_metric(np.concatenate(pooled), imm)
    t_warm = time.perf_counter() - t0

    positions, lps, divergent, accept = [], [], [], []
    t0 = time.perf_counter()
    with bar(draws, "draws") as progress_bar:
        for _ in range(draws):
            states, info = transition(states, step_size, imm)
            positions.append(np.asarray(states.position))
            lps.append(np.asarray(states.logdensity))
            divergent.append(np.asarray(info.is_divergent))
            accept.append(np.asarray(info.acceptance_rate))
            progress_bar.update()
            progress_bar.set_postfix(evaluations=evaluations[0], refresh=False)
    t_draw = time.perf_counter() - t0
    stack = lambda xs: np.swapaxes(np.stack(xs), 0, 1)  # noqa: E731
    return (
        stack(positions),
        stack(lps),
        stack(divergent),
        stack(accept),
        step_size,
        evaluations[0],
        t_warm,
        t_draw,
    )


def _pooled_metric(samples: np.ndarray, prior_metric: np.ndarray, weight: float = 5.0):
    """Covariance of the pooled warm-up ``samples`` ``(n, d)``, shrunk towards
    ``prior_metric`` as if it were ``weight`` more samples (Stan shrinks towards a small
    identity the same way); ``prior_metric`` again if the estimate is not positive definite."""
    n = len(samples)
    estimate = (n * np.atleast_2d(np.cov(samples, rowvar=False)) + weight * prior_metric) / (
        n + weight
    )
    try:
        np.linalg.cholesky(estimate)
    except np.linalg.LinAlgError:
        return prior_metric
    return estimate if np.all(np.isfinite(estimate)) else prior_metric


def judge(summary: Mapping[str, dict], divergences: int) -> list[str]:
    """Why a run cannot be called good (empty if it can): a split R-hat above
    :data:`MAX_RHAT` (or undefined), or any divergent transition after warm-up."""
    problems = []
    worst = max(
        summary,
        key=lambda n: (
            -math.inf
            if summary[n]["rhat"] <= MAX_RHAT
            else math.inf
            if not math.isfinite(summary[n]["rhat"])
            else summary[n]["rhat"]
        ),
    )
    if not summary[worst]["rhat"] <= MAX_RHAT:
        problems.append(
            f"split R-hat of {worst} is {summary[worst]['rhat']:.4f} > {MAX_RHAT} (the chains "
            "disagree: run longer or check for several modes)"
        )
    if divergences:
        problems.append(
            f"{divergences} divergent transition(s) after warm-up (the sampler could not "
            "follow the posterior's curvature there; the draws may be biased)"
        )
    return problems


def _summarize(x: np.ndarray, rank: bool = False) -> dict:
    """Summary of one quantity's draws ``x (chains, draws)``; ``rank``: the rank-normalized
    R-hat and bulk ESS (Vehtari et al. 2021; SMC) instead of the classic split R-hat and ESS."""
    flat = x.reshape(-1)
    q05, median, q95 = np.quantile(flat, [0.05, 0.5, 0.95])
    return {
        "mean": float(np.mean(flat)),
        "median": float(median),
        "sd": float(np.std(flat, ddof=1)),
        "q05": float(q05),
        "q95": float(q95),
        "rhat": diagnostics.rank_rhat(x) if rank else diagnostics.split_rhat(x),
        "ess": diagnostics.ess_bulk(x) if rank else diagnostics.ess(x),
        "ess_tail": diagnostics.ess_tail(x),
    }


def _sample(
    residuals,
    names,
    u_center,
    cov_u,
    priors,
    groups,
    noise,
    log_noise_center,
    *,
    likelihood,
    nu,
    chains,
    draws,
    warmup,
    seed,
    jitter,
    target_accept,
    progress,
    z0=None,
    sampler="auto",
    batch_log_density=None,
    smc_batch=None,
    weight=None,
    noise_treatment="auto",
    minima=(),
    moves="values",
) -> PosteriorResult:
    """The sampler on any residual function ``u -> r`` (JAX, differentiable): the path of
    :func:`sample_posterior`, open to a toy problem with a known posterior.
    ``batch_log_density``: ``Z (n, d) -> (n,)``, the independence sampler's (default: the
    log density ``vmap``-ed). ``weight``: each observation's likelihood weight (default 1).
    ``noise_treatment``: :data:`NOISE_TREATMENTS` (``smc_batch``, where given, must match).
    ``minima``: the fit's other distinct minima in ``u`` (SMC's reference covers them)."""
    integrated = _integrates(noise_treatment, likelihood, noise)
    if sampler == "smc" or (sampler == "auto" and z0 is None):
        return _sample_smc(
            residuals, names, u_center, cov_u, priors, groups, noise, log_noise_center,
            likelihood=likelihood, nu=nu, chains=chains, draws=draws, seed=seed,
            progress=progress, batch=smc_batch, sampler=sampler, weight=weight,
            integrated=integrated, minima=minima, moves=moves,
        )  # fmt: skip
    all_noise = noise
    if integrated:  # the sampler sees the physical parameters only
        noise, log_noise_center = (), []
    p, k = len(names), len(noise)
    starts_given = z0 is not None  # chains placed by hand: HMC from there
    log_density = _log_density(
        residuals, names, priors, np.asarray(groups), len(all_noise), likelihood, nu, weight,
        integrated,
    )  # fmt: skip
    if batch_log_density is None:
        batch_log_density = engine_jit(jax.vmap(log_density))
    z0, metric, center = _starts_and_metric(
        u_center, cov_u, groups, log_noise_center, p, k, chains, jitter, seed, z0
    )
    khat, used = math.nan, "hmc"
    if sampler == "independence" and not starts_given:
        z, lp, accept, khat, evaluations, t_warm, t_draw = _run_independence(
            batch_log_density,
            center,
            metric,
            chains=chains,
            warmup=warmup,
            draws=draws,
            seed=seed,
            progress=progress,
            judged=lambda z: _judged_quantities(names, z),
        )
        divergent, step_size, used = np.zeros(lp.shape, bool), math.nan, "independence"
    if used == "hmc":
        z, lp, divergent, accept, step_size, evaluations, t_warm, t_draw = _run_hmc(
            log_density,
            z0,
            metric,
            warmup=warmup,
            draws=draws,
            seed=seed,
            target_accept=target_accept,
            progress=progress,
        )
    result = _posterior_result(
        names, noise, priors, likelihood, nu, chains, z, lp, divergent, accept, step_size,
        evaluations, t_warm, t_draw, used, khat,
    )  # fmt: skip
    result.reason = (
        "HMC: the chains' starts were given"
        if starts_given
        else f"{'HMC' if used == 'hmc' else 'independence Metropolis'}: as asked "
        f"(sampler={sampler!r})"
    )
    if integrated:
        w = None if weight is None else jnp.asarray(weight)
        sums = engine_jit(
            jax.vmap(lambda zz: group_sums(residuals(zz[:p]), groups, len(all_noise), w)[0])
        )
        S = np.asarray(sums(jnp.asarray(z.reshape(-1, z.shape[-1])))).reshape(*z.shape[:2], -1)
        _attach_noise(result, all_noise, groups, S, weight, seed, rank=False)
    _describe_noise(result, integrated, all_noise)
    return result


def _starts_and_metric(u_center, cov_u, groups, log_noise_center, p, k, chains, jitter, seed, z0):
    """The chains' starts (the least-squares optimum plus a jitter of ``jitter`` standard
    errors, unless ``z0`` is given), the sampler's metric and the center of the proposal."""
    rng = np.random.default_rng(seed)
    cov_u = np.asarray(cov_u, dtype=float)
    if not np.all(np.isfinite(cov_u)):
        cov_u = np.eye(p) * 1e-4
    chol = np.linalg.cholesky(cov_u + 1e-12 * np.eye(p))
    u0 = np.asarray(u_center) + jitter * rng.standard_normal((chains, p)) @ chol.T
    s0 = np.asarray(log_noise_center) + 0.1 * jitter * rng.standard_normal((chains, k))
    if z0 is None:
        z0 = np.concatenate([u0, s0], axis=1)
    metric = np.zeros((p + k, p + k))
    metric[:p, :p] = cov_u + 1e-12 * np.eye(p)
    # log of a fitted noise factor: variance about 1 / (2 n_k) for n_k observations
    for j in range(k):
        metric[p + j, p + j] = 0.5 / max(int(np.sum(np.asarray(groups) == j)), 1)
    center = np.concatenate([np.asarray(u_center, float), np.asarray(log_noise_center, float)])
    return z0, metric, center


def _judged_quantities(names, z):
    """The physical parameters and noise factors of draws ``z`` ``(..., d)`` (in ``u`` and log
    noise): what the summary and the convergence rules are about."""
    p = len(names)
    theta = np.asarray(jax.vmap(jax.vmap(lambda u: to_physical(names, u)))(jnp.asarray(z[..., :p])))
    return np.concatenate([theta, np.exp(z[..., p:])], axis=-1)


def _posterior_result(
    names, noise, priors, likelihood, nu, chains, z, lp, divergent, accept, step_size,
    evaluations, t_warm, t_draw, used, khat,
) -> PosteriorResult:  # fmt: skip
    """The ``PosteriorResult`` of the chains' draws ``z`` (in ``u`` and log noise)."""
    p = len(names)
    judged = _judged_quantities(names, z)
    theta, noise_draws = judged[..., :p], judged[..., p:]
    summary = {n: _summarize(theta[..., i]) for i, n in enumerate(names)}
    summary.update({n: _summarize(noise_draws[..., j]) for j, n in enumerate(noise)})
    flat = theta.reshape(-1, p)
    correlation = np.corrcoef(flat, rowvar=False) if p > 1 else np.ones((1, 1))
    n_div = int(np.sum(divergent))
    problems = judge(summary, n_div)
    if used == "independence" and not khat <= MAX_KHAT:
        problems.append(
            f"the independence proposal misses part of the posterior (Pareto k {khat:.2f} > "
            f"{MAX_KHAT}); use sampler='hmc'"
        )
    status = "not converged" if problems else "converged"
    return PosteriorResult(
        params=tuple(names),
        draws=theta,
        noise=tuple(noise),
        noise_draws=noise_draws,
        summary=summary,
        correlation=correlation,
        divergences=n_div,
        status=status,
        converged=not problems,
        problems=problems,
        priors=dict(priors),
        likelihood=likelihood,
        nu=float(nu),
        step_size=np.full(chains, step_size),
        sampler=used,
        khat=khat,
        acceptance=float(np.mean(accept)),
        evaluations=evaluations,
        timings={"warmup": t_warm, "sampling": t_draw},
        log_density=lp,
    )


# -- the independence sampler ------------------------------------------------------------


def _batch_log_density(
    objective: Objective, names, priors, groups, n_noise, likelihood, nu, weight=None,
    integrated=False,
):  # fmt: skip
    """``Z (n, d) -> log posterior (n,)``: every row's impacts in one simulation (a flat
    batch of ``n x impacts`` lanes; the simulator under ``vmap`` costs 2-3x that)."""
    p = len(names)
    terms = _posterior_terms(names, priors, groups, n_noise, likelihood, nu, integrated)

    def log_density(Z, value, scale, weight):
        theta = jax.vmap(lambda u: to_physical(names, u))(Z[:, :p])
        result = objective._simulate_impl(tuple(theta[:, i : i + 1] for i in range(p)))

        def one(result, th, z):
            r = objective.residuals_from_result(result, objective.hertz_time(th), value, scale)
            return terms(z, r, weight)

        return jax.vmap(one)(result, theta, Z)

    key = "|".join(
        [
            objective.fingerprint(),
            "u",
            repr(names),
            repr(dict(priors)),
            repr(np.asarray(groups).tolist()),
        ]
        + [str(n_noise), likelihood, repr(float(nu)), f"integrated={integrated}"]
    )
    weight = _weights(len(objective.observations)) if weight is None else weight
    return over_devices(log_density, key, objective._value, objective._scale, weight)


class _StudentT:
    """Multivariate Student-t proposal: ``mean + L x / sqrt(g / nu)`` (``x ~ N(0, I)``,
    ``g ~ chi2(nu)``); heavier tails than the posterior keep the importance weights bounded."""

    def __init__(self, mean, cov, nu=PROPOSAL_NU):
        self.mean, self.nu = np.asarray(mean, float), float(nu)
        self.cov = np.asarray(cov, float)
        self.chol = np.linalg.cholesky(self.cov)

    def sample(self, rng, n):
        x = rng.standard_normal((n, len(self.mean)))
        g = rng.chisquare(self.nu, (n, 1))
        return self.mean + (x @ self.chol.T) / np.sqrt(g / self.nu)

    def log_density(self, Z):
        d = len(self.mean)
        y = np.linalg.solve(self.chol, (np.asarray(Z) - self.mean).T).T
        return -0.5 * (self.nu + d) * np.log1p(np.sum(y * y, axis=1) / self.nu)


def _weighted_t(points, log_w, fallback_cov, inflation):
    """A t proposal on the importance-weighted mean and covariance of ``points`` (``fallback_cov``
    where the weighted covariance is not positive definite), covariance inflated by
    ``inflation**2``."""
    w = _normalized(log_w)
    mean = w @ points
    dev = points - mean
    moments = (w[:, None] * dev).T @ dev
    if not np.all(np.isfinite(moments)) or np.any(np.linalg.eigvalsh(moments) <= 0):
        moments = np.asarray(fallback_cov)
    return _StudentT(mean, inflation**2 * (moments + 1e-12 * np.eye(len(mean))))


def _evaluate(log_density, Z, block, progress_bar):
    """Log densities of the rows of ``Z`` in blocks of ``block`` rows (:func:`_blocks`), NaN
    as ``-inf``, counted on ``progress_bar``."""
    out = _blocks(log_density, block)(Z)
    progress_bar.update(len(Z))
    return np.nan_to_num(out, nan=-np.inf)


def _run_independence(
    log_density, center, cov, *, chains, warmup, draws, seed, progress, judged=None
):
    """Independence Metropolis-Hastings with a Student-t proposal fitted to the posterior.

    1. Pilot: :data:`PILOT` draws from a t proposal on the least-squares optimum and
       covariance (inflated by :data:`PROPOSAL_INFLATION`); their importance weights give the
       posterior's mean and covariance, and the main proposal is the t on those.
    2. Every chain proposes ``warmup + draws`` independent points from the main proposal: all
       chains' proposals are evaluated as a few large batches (the lanes full). If their
       importance weights' Pareto k is above :data:`MAX_KHAT` (a posterior further from
       Gaussian than the pilot could see), the proposal is re-placed on those weights, wider,
       and the batch drawn again, up to :data:`REFINEMENTS` times.
    3. Each chain accepts or rejects in turn (``min(1, w' / w)``, ``w = p / q``). A chain
       starts at a pilot point drawn by its importance weight; its first ``warmup`` steps are
       dropped.
    4. While a split R-hat is just above :data:`MAX_RHAT` (up to :data:`MAX_RHAT_TO_EXTEND`,
       with the Pareto k fine and at least :data:`MIN_DRAWS_TO_EXTEND` draws per chain), every
       chain is extended by ``draws`` more steps on new proposals, up to :data:`EXTENSIONS`
       times: the result then holds more than ``draws`` draws per chain. ``judged``: draws
       ``(C, D, d)`` -> the quantities whose R-hat is judged ``(C, D, q)`` (default: the draws).

    Returns draws ``(C, D, d)``, log densities ``(C, D)``, acceptance ``(C, D)``, the Pareto
    shape ``k`` of the main proposal's importance weights (above 0.7 the proposal misses
    part of the posterior), the evaluations and the seconds of the pilot and the chains.
    """
    rng = np.random.default_rng(seed)
    block = max(1, min(BLOCK, chains * (warmup + draws)))
    total = PILOT + chains * (warmup + draws)
    desc = f"posterior ({chains} chains, independence sampler)"
    with _progress_bar(total, desc, "point", progress) as bar:
        t0 = time.perf_counter()
        pilot = _StudentT(center, PROPOSAL_INFLATION**2 * np.asarray(cov))
        Z0 = pilot.sample(rng, PILOT)
        lp0 = _evaluate(log_density, Z0, block, bar)
        log_w0 = lp0 - pilot.log_density(Z0)
        proposal = _weighted_t(Z0, log_w0, np.asarray(cov), PROPOSAL_INFLATION)
        picked = rng.choice(PILOT, size=chains, p=_normalized(log_w0))
        starts, start_lp = Z0[picked], lp0[picked]
        t_pilot = time.perf_counter() - t0

        t0 = time.perf_counter()
        n = chains * (warmup + draws)
        for attempt in range(REFINEMENTS + 1):
            Z = proposal.sample(rng, n)
            lp = _evaluate(log_density, Z, block, bar)
            log_w = lp - proposal.log_density(Z)
            khat = diagnostics.pareto_khat(np.exp(log_w - np.max(log_w)))
            if khat <= MAX_KHAT or attempt == REFINEMENTS:
                break
            inflation = PROPOSAL_INFLATION * REFINE_INFLATION ** (attempt + 1)
            proposal = _weighted_t(Z, log_w, proposal.cov, inflation)
            total += n
            bar.total = total
            bar.refresh()
    Z, lp, log_w = (a.reshape(chains, warmup + draws, *a.shape[1:]) for a in (Z, lp, log_w))
    state = (starts, start_lp, start_lp - proposal.log_density(starts))
    state, positions, lps, accept = _advance_chains(state, Z, lp, log_w, rng)
    positions, lps, accept = (a[:, warmup:] for a in (positions, lps, accept))
    # Longer chains while R-hat is just above the limit (each extension: `draws` more per chain
    # from the same proposal, continuing each chain where it stopped).
    for _ in range(EXTENSIONS if khat <= MAX_KHAT and draws >= MIN_DRAWS_TO_EXTEND else 0):
        values = positions if judged is None else judged(positions)
        rhat = max(diagnostics.split_rhat(values[:, :, j]) for j in range(values.shape[-1]))
        if not MAX_RHAT < rhat <= MAX_RHAT_TO_EXTEND:
            break
        n = chains * draws
        with _progress_bar(n, desc + ", extended", "point", progress) as bar:
            Z = proposal.sample(rng, n)
            lp = _evaluate(log_density, Z, block, bar)
        log_w = lp - proposal.log_density(Z)
        Z, lp, log_w = (a.reshape(chains, draws, *a.shape[1:]) for a in (Z, lp, log_w))
        state, more, more_lp, more_accept = _advance_chains(state, Z, lp, log_w, rng)
        positions = np.concatenate([positions, more], axis=1)
        lps = np.concatenate([lps, more_lp], axis=1)
        accept = np.concatenate([accept, more_accept], axis=1)
        total += n
    t_chains = time.perf_counter() - t0
    return positions, lps, accept, khat, total, t_pilot, t_chains


def _advance_chains(state, Z, lp, log_w, rng):
    """Each chain accepts or rejects the proposals ``Z (chains, steps, d)`` in turn
    (``min(1, w' / w)``) from ``state = (z, log density, log weight)``; returns the new state
    and the chains' positions, log densities and acceptance probabilities ``(chains, steps)``."""
    chains, steps, dim = Z.shape
    positions = np.empty((chains, steps, dim))
    lps = np.empty((chains, steps))
    accept = np.empty((chains, steps))
    z, l_cur, w_cur = (np.array(a) for a in state)
    for i in range(steps):
        ratio = np.exp(np.minimum(log_w[:, i] - w_cur, 0.0))
        take = rng.uniform(size=chains) < ratio
        z = np.where(take[:, None], Z[:, i], z)
        l_cur = np.where(take, lp[:, i], l_cur)
        w_cur = np.where(take, log_w[:, i], w_cur)
        positions[:, i], lps[:, i], accept[:, i] = z, l_cur, ratio
    return (z, l_cur, w_cur), positions, lps, accept


def _progress_bar(total, desc, unit, progress):
    """A progress bar on stderr (none unless ``progress``)."""
    return tqdm(
        total=total, desc=desc, unit=unit, disable=not progress, file=sys.stderr, leave=False
    )


def _normalized(log_w):
    w = np.exp(log_w - np.max(log_w))
    return w / np.sum(w)


def _at_tolerance(objective: Objective, rtol: float | None, loop: str | None = None) -> Objective:
    """The objective that the sampler evaluates: the fit's, with the step loop ``loop``
    (default the simulator's) and, in float64, solver tolerance ``rtol`` (atol ``rtol / 100``)
    and, for an explicit solver, at most :data:`SAMPLING_MAX_STEPS` steps per impact, unless
    ``rtol`` is None or the scene sets its own (float32's default is looser)."""
    scene = objective.scene
    solver = scene.solver
    if rtol is not None and solver.rtol is None and jnp.result_type(float) == jnp.float64:
        if not 0 < rtol < 1:
            raise FitError(f"rtol must be in (0, 1), got {rtol!r}")
        settings = {"rtol": rtol, "atol": solver.atol or rtol / 100}
        if not objective.method.startswith("kvaerno"):
            settings["max_steps"] = min(solver.max_steps, SAMPLING_MAX_STEPS)
        scene = scene.replace(solver=settings)
    return Objective(
        scene,
        objective.observations,
        objective.params,
        failure_residual=objective.failure_residual,
        method=objective.method,
        loop=loop,
    )


def sample_posterior(
    scene,
    observations,
    params: Sequence[str],
    *,
    priors: Mapping[str, object] | None = None,
    likelihood: str = "gaussian",
    nu: float = 4.0,
    chains: int = 4,
    draws: int = 1000,
    warmup: int = WARMUP,
    seed: int = 0,
    fit_result: FitResult | None = None,
    initial: Mapping[str, float] | None = None,
    starts: int = 3,
    jitter: float = 0.5,
    target_accept: float = 0.9,
    progress: bool = True,
    method: str | None = None,
    rtol: float | None = SAMPLING_RTOL,
    sampler: str = "auto",
    leave_out: Sequence[int] = (),
    noise: str = "auto",
    moves: str = "values",
) -> PosteriorResult:
    """Sample the posterior of ``params`` given the observations.

    **Arguments:**
    - `scene`, `observations`, `params`, `initial`, `starts`, `method`: as for `fit`, which
      runs first (unless `fit_result` is given) to place the chains.
    - `priors`: ``{name: Prior or "loguniform:LO:HI" or "normal:MU:SD"}``; where not given,
      the scene's ``[priors]`` table, else log-uniform over
      :data:`fitting._priors.PRIOR_RANGES`.
    - `likelihood`: ``"gaussian"`` or ``"student-t"`` (with `nu` degrees of freedom).
    - `chains` (>= 1; 4 or more for a trustworthy R-hat), `draws`, `warmup` (per chain).
    - `seed`: jitter of the starts and the sampler's random stream.
    - `jitter`: the chains start this many standard errors (least squares) from the optimum.
    - `target_accept`: the step-size adaptation's target acceptance rate.
    - `progress`: progress bars on stderr.
    - `sampler`: ``"auto"`` (default) or ``"smc"``: tempered sequential Monte Carlo
      (``fitting._bayesian.smc``), from a t on the fit where its importance weights show
      that it covers the posterior, else from the prior; ``"independence"`` (an independence
      Metropolis sampler with a t proposal on the fit, right only where the posterior is
      nearly Gaussian); ``"hmc"`` (see :data:`SAMPLERS` and the module docstring). With
      SMC, `chains` is the number of independent populations and `draws` their particles.
    - `rtol`: solver tolerance of the sampler's evaluations (float64; atol ``rtol / 100``),
      where the scene leaves its own unset; None: the scene's (the fit's) tolerance.
    - `noise`: how the noise factors of observables without sigmas enter (one of
      :data:`NOISE_TREATMENTS`): ``"auto"`` (default) integrates them out in closed form
      with the Gaussian likelihood (the sampler runs on `params` alone; each factor is then
      drawn from its exact conditional at each draw) and samples them with the Student-t;
      ``"integrated"`` or ``"sampled"`` forces one. ``result.noise_treatment`` says which ran.
    - `moves` (SMC): ``"values"`` (default: an independence proposal alternating with a
      random walk) or ``"mala"`` (the random walk replaced by MALA steps along the log
      density's gradient, the simulator's forward-mode derivatives: a second compiled
      program, each evaluation several times a value's cost; for curved posteriors).
    - `leave_out`: indices (from 0, in the order of the fit's observations) of observations
      whose likelihood terms are left out: the posterior without them, for exact
      leave-one-out (``fitting.loo``). The rest is unchanged: the same compiled program (the
      left-out rows are still simulated, with likelihood weight 0), and each noise factor is
      still sampled (a group's only observation left out: its factor follows the prior).

    **Returns:** a `PosteriorResult`; check ``converged`` (R-hat, divergences).

    **Raises:** `FitError` for bad options, names or priors (and what `fit` raises).
    """
    t_start = time.perf_counter()
    names = check_names(params)
    _check_options(sampler, likelihood, nu, chains, draws, warmup)
    if moves not in MOVES:
        raise FitError(f"moves must be one of {', '.join(MOVES)}, got {moves!r}")
    _integrates(noise, likelihood, ("any factor",))  # options checked before the fit
    prior_map = priors_for(names, priors, scene.priors)
    if fit_result is None:
        fit_result = fit(
            scene, observations, names, initial=initial, starts=starts, progress=progress,
            method=method,
        )  # fmt: skip
        t_fit = time.perf_counter() - t_start
    elif tuple(fit_result.params) != names:
        raise FitError(f"fit_result fits {fit_result.params}, not {names}")
    else:  # fitted before this call: its own time, counted in the total too
        t_fit = float(fit_result.timings.get("total", 0.0))
        t_start -= t_fit
    objective = fit_result.objective
    theta = fit_result.theta
    if sampler in ("independence", "hmc"):  # SMC needs no start inside the prior
        _check_inside_priors(names, theta, prior_map)
    sampled = _at_tolerance(objective, rtol)
    dpdu = dphys_du(names, theta)
    cov_u = np.asarray(fit_result.covariance) / np.outer(dpdu, dpdu)
    groups, noise_names = _noise_groups(objective)
    integrated = _integrates(noise, likelihood, noise_names)
    k_int = len(noise_names) if integrated else 0
    log_noise = _initial_log_noise(fit_result, groups, noise_names)
    left_out = _check_leave_out(leave_out, len(objective.observations))
    weight = _weights(len(objective.observations), left_out) if left_out else None
    result = _sample(
        _model_residuals(sampled, names),
        names,
        to_unbounded(names, theta),
        cov_u,
        prior_map,
        groups,
        noise_names,
        log_noise,
        likelihood=likelihood,
        nu=nu,
        chains=chains,
        draws=draws,
        warmup=warmup,
        seed=seed,
        jitter=jitter,
        target_accept=target_accept,
        progress=progress,
        sampler=sampler,
        batch_log_density=_batch_log_density(
            sampled,
            names,
            prior_map,
            groups,
            len(noise_names),
            likelihood,
            nu,
            weight,
            integrated,
        )  # fmt: skip
        if sampler == "independence"
        else None,
        smc_batch=_x_batch_log_density(
            sampled,
            SamplingSpace(names, () if integrated else noise_names, prior_map),
            groups,
            likelihood,
            nu,
            weight,
            k_int,
            moves == "mala",
        )  # fmt: skip
        if sampler in ("smc", "auto")
        else None,
        weight=weight,
        noise_treatment=noise,
        minima=_other_minima(fit_result),
        moves=moves,
    )
    result.fit = fit_result
    result.left_out = left_out
    result.options = dict(
        likelihood=likelihood, nu=nu, chains=chains, draws=draws, warmup=warmup, seed=seed,
        jitter=jitter, target_accept=target_accept, rtol=rtol, sampler=sampler, noise=noise,
        moves=moves,
    )  # fmt: skip
    result.program = _model_values(sampled, names)
    result.objective = sampled
    result.noise_groups = groups
    result.timings = {
        "fit": t_fit,
        **result.timings,
        "total": time.perf_counter() - t_start,
    }
    return result


def _other_minima(fit_result: FitResult) -> list[np.ndarray]:
    """The fit's distinct minima other than its answer, in the solver's variables ``u``."""
    names = list(fit_result.params)
    centre = np.asarray(to_unbounded(names, fit_result.theta), float)
    others = []
    for m in fit_result.minima:
        u = np.asarray(to_unbounded(names, [m.values[n] for n in names]), float)
        if np.max(np.abs(u - centre)) > SAME_VALUES:
            others.append(u)
    return others


def _check_options(sampler, likelihood, nu, chains, draws, warmup) -> None:
    """``sample_posterior``'s options checked (``FitError`` naming the bad one)."""
    if sampler not in SAMPLERS:
        raise FitError(f"sampler must be one of {', '.join(SAMPLERS)}, got {sampler!r}")
    if likelihood not in LIKELIHOODS:
        raise FitError(f"likelihood must be one of {', '.join(LIKELIHOODS)}, got {likelihood!r}")
    if not nu > 0:
        raise FitError(f"nu must be > 0, got {nu!r}")
    for label, value, least in (("chains", chains, 1), ("draws", draws, 4), ("warmup", warmup, 1)):
        if not (isinstance(value, int) and value >= least):
            raise FitError(f"{label} must be an integer >= {least}, got {value!r}")


def _check_leave_out(leave_out, n: int) -> tuple[int, ...]:
    """``leave_out`` as sorted distinct row indices, each in ``[0, n)``; not all of them."""
    try:
        rows = tuple(sorted({operator.index(i) for i in leave_out}))
    except TypeError:
        raise FitError(f"leave_out must be row indices (integers), got {leave_out!r}") from None
    if rows and not (0 <= rows[0] and rows[-1] < n):
        raise FitError(f"leave_out: rows must lie in [0, {n}), got {list(rows)}")
    if len(rows) >= n:
        raise FitError("leave_out would leave no observation")
    return rows


def _check_inside_priors(names, theta, prior_map) -> None:
    """The least-squares values must lie where the priors have mass."""
    for n, v in zip(names, theta, strict=True):
        if not math.isfinite(float(prior_map[n].log_density_u(n, to_unbounded([n], [v])[0]))):
            raise FitError(
                f"the least-squares {n} = {v:.4g} lies outside its prior {prior_map[n].describe()}"
            )


def _initial_log_noise(fit_result, groups, noise) -> list[float]:
    """The log noise factor of each group without sigmas at the least-squares optimum (its
    rms residual in default scales, at least 0.01)."""
    r_fit = np.asarray(fit_result.residuals)
    return [
        math.log(max(float(np.sqrt(np.mean(r_fit[groups == j] ** 2))), 1e-2))
        for j in range(len(noise))
    ]


def _model_values(objective: Objective, names):
    """``U (n, p) -> model values (n, n_data)``: cor_n continued below zero where captured,
    as the residuals see it (one compiled program, draws as a batch)."""
    zero, one = jnp.zeros_like(objective._value), jnp.ones_like(objective._scale)
    return engine_jit(jax.vmap(_model_residuals(objective, names, zero, one)))


def posterior_predictive(result: PosteriorResult, n: int = 100, seed: int = 0):
    """Model values at the observations for ``n`` draws spread over the chains, and the same
    with the likelihood's noise added: ``(model (n, n_data), predicted (n, n_data))``."""
    if result.program is None or result.fit is None:
        raise FitError("posterior_predictive needs a result of sample_posterior")
    names, p = result.params, len(result.params)
    flat = result.draws.reshape(-1, p)
    noise = result.noise_draws.reshape(flat.shape[0], -1)
    pick = np.linspace(0, len(flat) - 1, min(n, len(flat))).astype(int)
    U = np.stack([to_unbounded(names, flat[i]) for i in pick])
    model = np.asarray(result.program(jnp.asarray(U)))
    objective = result.fit.objective
    groups = result.noise_groups
    factor = noise_factors(noise[pick], groups)
    rng = np.random.default_rng(seed)
    if result.likelihood == "gaussian":
        e = rng.standard_normal(model.shape)
    else:
        e = rng.standard_t(result.nu, model.shape)
    return model, model + e * factor * objective.scale


# -- sequential Monte Carlo (sampler="smc") -------------------------------------------------

#: SMC's reference: a Student-t with REFERENCE_NU degrees of freedom on the fit, its standard
#: deviations REFERENCE_WIDTH times the fit's (at most the prior's), mixed with the prior
#: (share PRIOR_SHARE).
REFERENCE_NU = 4.0
REFERENCE_WIDTH = 1.3
PRIOR_SHARE = 0.05
#: SMC: a run is called converged only with every bulk and tail ESS at least MIN_ESS and every
#: rank-normalized R-hat (over the independent populations) at most MAX_RHAT; while either
#: fails, ``chains`` more populations are run, up to SMC_EXTENSIONS times.
MIN_ESS = 400
SMC_EXTENSIONS = 2


def _likelihood_of(space: SamplingSpace, groups, likelihood, nu, integrated: int):
    """The log likelihood ``(r, log s, weight) -> ...`` of a posterior in ``space`` whose
    noise factors are its coordinates, or (``integrated``: their number) integrated out."""
    n_noise = integrated or len(space.noise)
    return log_likelihood_function(np.asarray(groups), n_noise, likelihood, nu, integrated > 0)


def _x_log_density(
    residuals, space: SamplingSpace, groups, likelihood, nu, weight=None, integrated: int = 0,
    gradient: bool = False,
):  # fmt: skip
    """``x -> (log posterior, S_1 .. S_k[, its gradient in x])`` (up to a constant) from
    ``residuals: u -> r`` (JAX); ``S_j``: the residual sum of squares of each of the
    ``integrated`` noise groups (what their factors' conditional draws need; none where the
    factors are sampled); ``gradient``: the log posterior's gradient appended (MALA moves)."""
    log_likelihood = _likelihood_of(space, groups, likelihood, nu, integrated)
    weight = None if weight is None else jnp.asarray(weight)

    def log_density(x):
        u, log_s = space.to_u(x)
        r = residuals(u)
        lp = space.log_prior(x) + log_likelihood(r, log_s, weight)
        return jnp.concatenate([lp[None], group_sums(r, groups, integrated, weight)[0]])

    if not gradient:
        return log_density

    def with_gradient(x):  # one evaluation for the value, the sums and the gradient
        def value(y):
            out = log_density(y)
            return out[0], out

        grad, out = jax.grad(value, has_aux=True)(x)
        return jnp.concatenate([out, grad])

    return with_gradient


def _x_batch_log_density(
    objective: Objective,
    space: SamplingSpace,
    groups,
    likelihood,
    nu,
    weight=None,
    integrated: int = 0,
    gradient: bool = False,
):
    """``X (n, d) -> (n, 1 + integrated [+ d])``: the log posterior of each row and its integrated
    noise groups' residual sums of squares (:func:`_x_log_density`), every row's impacts in
    one simulation (a flat batch of ``n x impacts`` lanes; the simulator under ``vmap`` costs
    2-3x that), compiled by :func:`over_devices` with the observed values, scales and
    likelihood weights (``weight``, default 1: one program for a posterior and its
    leave-one-out refits) as inputs. (The simulator called on its own, outside this program,
    runs about 1.7x faster but compiles in 35 s instead of 9 s on 2 cores: the wrong trade
    here.) ``gradient``: each row's gradient of its log posterior in ``x`` appended (forward
    mode through the simulator: one tangent per coordinate, rows independent)."""
    names, p = space.names, len(space.names)
    log_likelihood = _likelihood_of(space, groups, likelihood, nu, integrated)
    objective = _at_tolerance(objective, None, SAMPLING_LOOP)

    def log_density(X, value, scale, weight):
        def prepare(x):
            u, log_s = space.to_u(x)
            return to_physical(names, u), log_s, space.log_prior(x)

        theta, log_s, log_prior = jax.vmap(prepare)(X)
        result = objective._simulate_impl(tuple(theta[:, i : i + 1] for i in range(p)))

        def one(result, th, ls, lp):
            r = objective.residuals_from_result(result, objective.hertz_time(th), value, scale)
            lp = lp + log_likelihood(r, ls, weight)
            return jnp.concatenate([lp[None], group_sums(r, groups, integrated, weight)[0]])

        return jax.vmap(one)(result, theta, log_s, log_prior)

    def log_density_and_gradient(X, value, scale, weight):
        def values(Y):
            return log_density(Y, value, scale, weight)

        # One simulation: the primal is not batched over the tangents (one per coordinate).
        basis = jnp.broadcast_to(jnp.eye(X.shape[1])[:, None, :], (X.shape[1], *X.shape))
        out, tangents = jax.vmap(lambda t: jax.jvp(values, (X,), (t,)))(basis)
        return jnp.concatenate([out[0], tangents[:, :, 0].T], axis=1)

    key = "|".join(
        [objective.fingerprint(), "x", repr(space), repr(np.asarray(groups).tolist())]
        + [likelihood, repr(float(nu)), f"integrated={integrated}", f"gradient={gradient}"]
    )
    program = log_density_and_gradient if gradient else log_density
    weight = _weights(len(objective.observations)) if weight is None else weight
    return over_devices(program, key, objective._value, objective._scale, weight)


def _weights(n: int, leave_out: Sequence[int] = ()) -> np.ndarray:
    """Likelihood weight of each of ``n`` observations: 0 for those left out, else 1."""
    weight = np.ones(n)
    weight[list(leave_out)] = 0.0
    return weight


#: Compiled log-density programs of this process: key -> compiled (the last few).
_PROGRAMS: OrderedDict = OrderedDict()
_PROGRAMS_KEPT = 4


def over_devices(log_density, key: str, *data):
    """``X -> log_density(X, *data)`` (rows independent) compiled once per row count, with
    the data as the program's inputs: kept in this process (:data:`_PROGRAMS`) and, with the
    compilation cache on, on disk (``jaximpact._io.cache.compiled_program``), so a second data
    set of the same design (a calibration's replications, a user's next sample) neither traces
    nor compiles again. ``key``: a digest of everything ``log_density`` closes over.

    The rows are split over the local devices (``shard_map``; ``data`` replicated): on a CPU
    with one device per core (``jaximpact.use_all_cpu_cores``, as the CLI does) every core
    runs its share of the step loop. 500 rows of 25 impacts: 0.38 s on 2 cores against 0.82 s
    on one, the same values, the same compile time. Rows are padded (copies of the first) to a
    multiple of the device count."""
    devices = jax.local_devices()
    mesh = jax.sharding.Mesh(np.array(devices), ("rows",))
    rows = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("rows"))
    whole = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    fn = log_density
    if len(devices) > 1:
        # (check_vma=False: the solver's loops start from constants that JAX's type check
        # would want cast to per-device values; nothing crosses devices.)
        fn = jax.shard_map(
            log_density, mesh=mesh, in_specs=(rows.spec,) + (whole.spec,) * len(data),
            out_specs=rows.spec, check_vma=False,
        )  # fmt: skip
    data = tuple(jax.device_put(jnp.asarray(a), whole) for a in data)

    def compiled(shape, dtype):
        program_key = f"{key}|{shape}|{dtype}|{len(devices)}"
        if program_key in _PROGRAMS:
            _PROGRAMS.move_to_end(program_key)
            return _PROGRAMS[program_key]
        example = (jax.ShapeDtypeStruct(shape, dtype, sharding=rows),) + tuple(
            jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=whole) for a in data
        )
        # Equinox's run-time checks as NaN (a rejected point): a raising check is a host
        # callback, which would keep the program out of the caches.
        with runtime_checks_as_nan():
            program, _ = compiled_program(
                "posterior", fn, example, program_key, compiler_options() or None
            )
        _PROGRAMS[program_key] = program
        while len(_PROGRAMS) > _PROGRAMS_KEPT:
            _PROGRAMS.popitem(last=False)
        return program

    def call(X):
        X = jnp.asarray(X)
        n, pad = X.shape[0], -X.shape[0] % len(devices)
        if pad:
            X = jnp.concatenate([X, jnp.repeat(X[:1], pad, axis=0)])
        program = compiled(tuple(X.shape), X.dtype)
        out = program(jax.device_put(X, rows), *data)
        return (gathered(out) if len(devices) > 1 else out)[:n]

    return call


def _blocks(log_density, block):
    """``X (n, d) -> (n,)`` numpy, ``block`` rows per call of ``log_density`` (one compiled
    shape: the last block is padded with copies of its first row)."""

    def evaluate(X):
        X = np.asarray(X, float)
        out = []
        for i in range(0, len(X), block):
            part = X[i : i + block]
            pad = block - len(part)
            if pad:
                part = np.concatenate([part, np.repeat(part[:1], pad, axis=0)])
            out.append(np.asarray(log_density(jnp.asarray(part)))[: block - pad])
        return np.concatenate(out) if out else np.zeros(0)

    return evaluate


def _smc_problems(summary: Mapping[str, dict], divergences: int = 0) -> list[str]:
    """Why a run cannot be called good (empty if it can): a rank-normalized R-hat above
    :data:`MAX_RHAT` (or undefined), a bulk or tail ESS below :data:`MIN_ESS`, or a divergent
    HMC transition."""
    problems = []
    rhat = {n: s["rhat"] for n, s in summary.items()}
    bad = [n for n, r in rhat.items() if not r <= MAX_RHAT]
    if bad:
        worst = max(bad, key=lambda n: math.inf if not math.isfinite(rhat[n]) else rhat[n])
        problems.append(
            f"R-hat of {worst} is {rhat[worst]:.4f} > {MAX_RHAT} (rank-normalized, bulk and "
            "tails: the chains or populations disagree; a part of the posterior may be missed)"
        )
    ess = {n: min(s["ess"], s.get("ess_tail", s["ess"])) for n, s in summary.items()}
    low = [n for n, e in ess.items() if not e >= MIN_ESS]
    if low:
        worst = min(low, key=lambda n: ess[n] if math.isfinite(ess[n]) else -math.inf)
        problems.append(
            f"effective sample size of {worst} is {ess[worst]:.0f} < {MIN_ESS} (bulk or "
            "tails): too few independent draws for its quantiles"
        )
    if divergences:
        problems.append(
            f"{divergences} divergent transition(s) after warm-up (the sampler could not "
            "follow the posterior's curvature there; the draws may be biased)"
        )
    return problems


def _x_judged(space: SamplingSpace, z):
    """The physical parameters and noise factors of draws ``z`` ``(..., d)`` in ``x``: what
    the summary and the convergence rules are about."""
    flat = jnp.asarray(np.asarray(z).reshape(-1, space.dim))
    p = len(space.names)

    def one(x):
        u, log_s = space.to_u(x)
        return jnp.concatenate([to_physical(space.names, u) if p else u, jnp.exp(log_s)])

    out = np.asarray(jax.jit(jax.vmap(one))(flat))
    return out.reshape(*np.shape(z)[:-1], space.dim)


def _reference(space: SamplingSpace, theta, cov_u, log_noise, groups) -> Reference:
    """The defensive reference in ``x``: a t on the least-squares optimum, its covariance
    carried from ``u`` into ``x`` and widened by :data:`REFERENCE_WIDTH` (a coordinate whose
    fitted variance is not finite, or wider than its prior, gets the prior's and no
    correlation), mixed with the prior."""
    p, d = len(space.names), space.dim
    center = space.from_physical(theta, log_noise)
    dpdu = dphys_du(space.names, theta) if p else np.zeros(0)
    dlog_du = np.concatenate([dpdu / np.asarray(theta, float), np.ones(d - p)])
    scale = np.array(
        [
            space.dx_dlog(center)[i] * dlog_du[i] if space._box(i) is not None else 1.0
            for i in range(d)
        ]
    )
    cov = np.zeros((d, d))
    cov[:p, :p] = np.asarray(cov_u, float)
    for j in range(d - p):  # log of a fitted noise factor: variance about 1 / (2 n_k)
        cov[p + j, p + j] = 0.5 / max(int(np.sum(np.asarray(groups) == j)), 1)
    cov = cov * np.outer(scale, scale)
    limit = space.prior_sd() ** 2
    var = np.diag(cov).copy()
    for i in range(d):
        if not (np.isfinite(var[i]) and 0 < var[i] <= limit[i]) or not np.all(np.isfinite(cov[i])):
            cov[i, :] = cov[:, i] = 0.0
            cov[i, i] = limit[i]
    cov = REFERENCE_WIDTH**2 * cov + 1e-10 * np.eye(d)
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        cov = np.diag(np.diag(cov))
    return Reference(
        center, cov, REFERENCE_NU, space.sample_prior, space.log_prior_normalized, PRIOR_SHARE
    )


def _smc_summaries(space: SamplingSpace, run: SMCRun) -> dict:
    """``{coordinate index: summary}`` of an SMC run's draws (physical values). The rank ESS
    counts the particles as if independent; the last tempering step's weights bound what its
    resampled copies are worth (the moves after it make them independent only as far as they
    mix): the ESS reported is the smaller of the two."""
    judged = _x_judged(space, run.draws)
    floor = float(np.sum(run.final_ess))
    out = {}
    for i in range(space.dim):
        s = _summarize(judged[..., i], rank=True)
        s["ess"], s["ess_tail"] = min(s["ess"], floor), min(s["ess_tail"], floor)
        out[i] = s
    return out


def _run_smc_extended(evaluate, reference, space, *, chains, draws, rng, progress, gradient=False):
    """SMC with ``chains`` populations of ``draws`` particles, extended by ``chains`` more
    populations (up to :data:`EXTENSIONS` times) while an R-hat or ESS fails (``gradient``:
    MALA moves, ``run_smc``)."""
    desc = f"posterior (SMC, {chains} populations x {draws})"
    prior = Reference(
        np.zeros(space.dim), np.eye(space.dim), REFERENCE_NU, space.sample_prior,
        space.log_prior_normalized, 1.0,
    )  # fmt: skip
    runs = [run_smc(evaluate, reference, populations=chains, particles=draws, rng=rng,
                    progress=progress, description=desc, fallback=prior,
                    gradient=gradient)]  # fmt: skip
    for _ in range(SMC_EXTENSIONS):
        if not _smc_problems(_smc_summaries(space, _merge_runs(runs))):
            break
        runs.append(
            run_smc(evaluate, prior if runs[0].from_fallback else reference,
                    populations=chains, particles=draws, rng=rng, progress=progress,
                    description=desc + ", extended", gradient=gradient)
        )  # fmt: skip
    return _merge_runs(runs)


def _merge_runs(runs: list[SMCRun]) -> SMCRun:
    if len(runs) == 1:
        return runs[0]
    cat = lambda name: np.concatenate([getattr(r, name) for r in runs])  # noqa: E731
    total = sum(r.moves.sum() for r in runs)
    return SMCRun(
        draws=cat("draws"),
        log_density=cat("log_density"),
        stages=cat("stages"),
        moves=cat("moves"),
        acceptance=float(
            sum(np.nan_to_num(r.acceptance) * r.moves.sum() for r in runs) / total
            if total
            else math.nan
        ),
        correlation=cat("correlation"),
        khat=max(r.khat for r in runs),
        log_evidence=cat("log_evidence"),
        evaluations=sum(r.evaluations for r in runs),
        seconds=sum(r.seconds for r in runs),
        problems=[p for r in runs for p in r.problems],
        from_fallback=runs[0].from_fallback,
        final_ess=cat("final_ess"),
        importance_only=cat("importance_only"),
        aux=cat("aux"),
    )


def posterior_setup(
    fit_result: FitResult,
    priors: Mapping[str, object] | None = None,
    likelihood: str = "gaussian",
    nu: float = 4.0,
    rtol: float | None = SAMPLING_RTOL,
    noise: str = "auto",
):
    """The posterior that :func:`sample_posterior` samples, for a fit's data and parameters:
    ``(space, batch log density X (n, d) -> (n,) in the sampler's coordinates, the objective
    at the sampling tolerance, noise groups)``. The grid reference of the benchmarks and tests
    evaluates exactly this density (with noise factors integrated out, the marginal posterior
    of the physical parameters)."""
    objective = fit_result.objective
    names = tuple(fit_result.params)
    prior_map = priors_for(names, priors, objective.scene.priors)
    groups, noise_names = _noise_groups(objective)
    integrated = _integrates(noise, likelihood, noise_names)
    space = SamplingSpace(names, () if integrated else noise_names, prior_map)
    sampled = _at_tolerance(objective, rtol)
    full = _x_batch_log_density(
        sampled, space, groups, likelihood, nu, integrated=len(noise_names) if integrated else 0
    )
    return space, lambda X: full(X)[:, 0], sampled, groups


def _integrates(noise: str, likelihood: str, noise_names) -> bool:
    """Whether the noise factors ``noise_names`` are integrated out (``noise``: one of
    :data:`NOISE_TREATMENTS`; a bad combination is a ``FitError``)."""
    if noise not in NOISE_TREATMENTS:
        raise FitError(f"noise must be one of {', '.join(NOISE_TREATMENTS)}, got {noise!r}")
    if noise == "integrated" and likelihood != "gaussian":
        raise FitError(
            "noise='integrated' needs likelihood='gaussian' (the Student-t likelihood has no "
            "closed-form integral over its noise factors: use noise='sampled' or 'auto')"
        )
    return bool(noise_names) and likelihood == "gaussian" and noise != "sampled"


def grid_reference(
    fit_result: FitResult,
    priors: Mapping[str, object] | None = None,
    *,
    likelihood: str = "gaussian",
    nu: float = 4.0,
    points: int = 40,
    half_width: float = 8.0,
    axes: str = "whitened",
    rtol: float | None = SAMPLING_RTOL,
    progress: bool = False,
) -> dict:
    """The exact posterior of :func:`sample_posterior` on a grid, as a yardstick for samplers
    (1-3 parameters; observables without sigmas: their noise factors integrated out, the
    Gaussian likelihood's marginal posterior).

    ``axes="whitened"``: the grid lies in the fit's whitened coordinates ``g`` (``x = centre +
    L g``, ``L`` the Cholesky factor of the fit's covariance carried into the sampler's
    coordinates ``x``, a parameter the data leave open at its prior's width), over ``|g| <=
    half_width``, refined once to where the mass is (``_grid``). A grid along the parameters'
    own axes cannot resolve a ridge thinner than its cells (a C_A-f0 ridge 70x thinner than
    long is common); along the ridge's axes it can. Where more than 1e-6 of the mass lies on
    the box's faces the box is doubled (up to twice). It cannot follow a ridge that curves away
    from the fit's axes: check its face mass and compare two resolutions.
    ``axes="parameters"``: the grid lies in ``ln p`` over each log-uniform prior's whole
    range (nothing is outside it), refined once: robust where the posterior is wide or curved,
    fine enough for 2 parameters (``points`` of 100-200).
    The physical values' mean, sd and 5/50/95 % quantiles come from the cells as weighted
    points.

    Returns ``{name: {mean, sd, q05, median, q95}}`` plus ``"_grid"`` (the `GridPosterior`
    in ``g``) and ``"_face_mass"`` (the mass on the box's faces).
    """
    from .grid import grid_posterior

    space, batch, _, groups = posterior_setup(fit_result, priors, likelihood, nu, rtol)
    if space.noise:
        raise FitError(
            "grid_reference needs the noise factors integrated out (the Gaussian likelihood) "
            "or sigmas for every datum"
        )
    names = space.names
    theta = np.asarray(fit_result.theta, float)
    dpdu = dphys_du(names, theta)
    cov_u = np.asarray(fit_result.covariance) / np.outer(dpdu, dpdu)
    reference = _reference(space, theta, cov_u, [], groups)
    centre, chol = reference.mean, np.linalg.cholesky(reference.cov / REFERENCE_WIDTH**2)
    evaluate = _blocks(batch, BLOCK)
    d = space.dim
    if axes == "parameters":
        ends = [space._box(i) for i in range(d)]
        if any(e is None for e in ends):
            raise FitError("axes='parameters' needs log-uniform priors")
        start = np.array([a for a, _ in ends])
        width = np.array([b - a for a, b in ends])

        def log_density(L):  # ln p -> x, with the Jacobian |dx / d ln p|
            q = np.clip((L - start) / width, 1e-300, 1 - 1e-16)
            return evaluate(np.log(q) - np.log1p(-q)) - np.sum(np.log(width * q * (1 - q)), 1)

        grid = grid_posterior(
            log_density, start, start + width, names=names, points=points, block=BLOCK,
            to_physical=lambda i, u: np.exp(u), progress=progress,
        )  # fmt: skip
        return {**grid.summary, "_grid": grid, "_face_mass": 0.0}
    for _ in range(3):
        grid = grid_posterior(
            lambda G: evaluate(centre + G @ chol.T), [-half_width] * d, [half_width] * d,
            names=names, points=points, block=BLOCK, progress=progress,
        )  # fmt: skip
        face = _face_mass(grid, half_width)
        if face <= 1e-6:
            break
        half_width *= 2
    mesh = np.stack(np.meshgrid(*grid.axes, indexing="ij"), axis=-1).reshape(-1, d)
    # Each cell's mass spread over SUB^d points inside it (its density is the centre's: the
    # midpoint rule), so that the cells, projected on a parameter's axis, give a smooth CDF.
    h = np.array([a[1] - a[0] for a in grid.axes])
    offsets = (np.arange(SUB) + 0.5) / SUB - 0.5
    sub = np.stack(np.meshgrid(*[offsets * hi for hi in h], indexing="ij"), -1).reshape(-1, d)
    points = (mesh[:, None, :] + sub[None]).reshape(-1, d)
    weight = np.repeat(grid.mass.reshape(-1), len(sub)) / len(sub)
    keep = weight > 1e-14 * weight.max()
    values = _x_judged(space, centre + points[keep] @ chol.T)
    return _weighted_summary(names, values, weight[keep] / weight[keep].sum(), grid, face)


#: Points per cell and dimension that carry a whitened grid cell's mass into the summary.
SUB = 4


def _weighted_summary(names, values, weight, grid, face) -> dict:
    """Mean, sd and 5/50/95 % quantiles of each column of ``values`` weighted by ``weight``."""
    out = {"_grid": grid, "_face_mass": face}
    for i, name in enumerate(names):
        v = values[:, i]
        mean = float(weight @ v)
        order = np.argsort(v)
        cdf = np.cumsum(weight[order]) - 0.5 * weight[order]
        q05, median, q95 = np.interp([0.05, 0.5, 0.95], cdf, v[order])
        out[name] = {
            "mean": mean,
            "sd": float(np.sqrt(weight @ (v - mean) ** 2)),
            "q05": float(q05),
            "median": float(median),
            "q95": float(q95),
        }
    return out


def _face_mass(grid, half_width) -> float:
    """Mass of the cells on the faces of the box ``|g| <= half_width`` (after refinement, only
    faces that are still at the box's edge count)."""
    mass = grid.mass
    total = 0.0
    for i, axis in enumerate(grid.axes):
        h = axis[1] - axis[0]
        for end, index in ((-half_width, 0), (half_width, -1)):
            if abs(axis[index] - end) < h:
                total += float(np.take(mass, index, axis=i).sum())
    return total


def _sample_smc(
    residuals, names, u_center, cov_u, priors, groups, noise, log_noise_center, *, likelihood,
    nu, chains, draws, seed, progress, batch=None, sampler="smc", weight=None, integrated=False,
    minima=(), moves="values",
) -> PosteriorResult:  # fmt: skip
    """``sampler="smc"``: tempered SMC in the coordinates of ``_space``, judged by the
    rank-normalized R-hat over its independent populations, bulk and tail ESS and the
    particles' decorrelation (``batch``: ``X (n, d) -> (n, 1 + k)``, the log density and,
    where ``integrated``, the ``k`` noise groups' residual sums of squares; default the log
    density ``vmap``-ed). ``minima``: the fit's other distinct minima (in ``u``), which the
    reference covers too (:func:`_cover_minima`). ``moves="mala"``: the local moves are MALA
    steps (``batch`` then appends each row's gradient in ``x``)."""
    gradient = moves == "mala"
    all_noise = tuple(noise)
    k_int = len(all_noise) if integrated else 0
    if integrated:  # the particles carry the physical parameters only
        noise, log_noise_center = (), []
    space = SamplingSpace(tuple(names), tuple(noise), dict(priors))
    if batch is None:
        batch = engine_jit(
            jax.vmap(
                _x_log_density(residuals, space, groups, likelihood, nu, weight, k_int, gradient)
            )
        )
    theta = np.asarray(to_physical(names, jnp.asarray(u_center)), float)
    reference = _reference(space, theta, cov_u, log_noise_center, groups)
    rng = np.random.default_rng(seed)
    # Every call evaluates whole populations (those still moving): blocks of at most one
    # population leave no padding. Blocks of BLOCK rows padded a population of 6 particles
    # 83-fold (0.17 s per move for 60 impacts).
    evaluate = _blocks(batch, min(BLOCK, draws))
    reference, minima_note, extra = _cover_minima(
        reference, space, names, minima, log_noise_center, evaluate
    )
    run = _run_smc_extended(
        evaluate, reference, space, chains=chains, draws=draws, rng=rng, progress=progress,
        gradient=gradient,
    )  # fmt: skip
    run.evaluations += extra
    to_z = jax.jit(jax.vmap(lambda x: jnp.concatenate(space.to_u(x))))
    z = np.asarray(to_z(jnp.asarray(run.draws.reshape(-1, space.dim)))).reshape(run.draws.shape)
    shape = run.log_density.shape
    result = _posterior_result(
        names, noise, priors, likelihood, nu, shape[0], z, run.log_density, np.zeros(shape, bool),
        np.full(shape, run.acceptance), math.nan, run.evaluations, 0.0, run.seconds, "smc",
        run.khat,
    )  # fmt: skip
    names_all = result.params + result.noise
    summary = {names_all[i]: s for i, s in _smc_summaries(space, run).items()}
    for n, stats in summary.items():
        result.summary[n].update(rhat=stats["rhat"], ess=stats["ess"], ess_tail=stats["ess_tail"])
    if integrated:
        floor = float(np.sum(run.final_ess))
        S = run.aux[..., :k_int]
        _attach_noise(result, all_noise, groups, S, weight, seed, rank=True, floor=floor)
        summary.update({n: result.summary[n] for n in all_noise})
    result.problems = _smc_problems(summary) + run.problems
    result.converged = not result.problems
    result.status = "converged" if result.converged else "not converged"
    result.stages = run.stages
    result.log_evidence = float(np.mean(run.log_evidence))
    start = (
        "from the prior: a t on the least-squares fit did not cover the posterior (its "
        "importance weights' ESS or Pareto k failed)"
        if run.from_fallback
        else "from a t on the least-squares fit mixed with the prior (its importance weights "
        "showed that it covers the posterior)"
    )
    importance = int(np.sum(run.importance_only))
    steps = f"{int(np.max(run.stages))} tempering step(s), {int(np.median(run.moves))} moves per "
    steps += "population (median)"
    if importance:
        steps += (
            "; "
            + (
                "every population"
                if importance == run.importance_only.size
                else f"{importance} of {run.importance_only.size} populations"
            )
            + f" ended as an importance sample at b = 1 (weights with Pareto k <= "
            f"{IMPORTANCE_KHAT}, an ESS of at least half its particles and no draw worth more "
            f"than {IMPORTANCE_MAX_WEIGHT:g}; resampled: the ESS reported is the weights')"
        )
    result.reason = (
        f"SMC ({'the default' if sampler == 'auto' else 'as asked'}; values only, no Gaussian "
        f"shape assumed): {run.draws.shape[0]} independent populations of "
        f"{run.draws.shape[1]} particles, {start}{minima_note}; {steps}"
        + ("; local moves: MALA (the log density's gradient)" if gradient else "")
    )
    _describe_noise(result, integrated, all_noise)
    return result


#: A fit's other minimum joins the reference where its posterior density is at least this
#: fraction of the mixture's weight (its share: its density at the minimum over the sum).
MIN_MINIMUM_SHARE = 1e-3


def _cover_minima(reference, space, names, minima, log_noise, evaluate):
    """The reference widened to the fit's other distinct ``minima`` (``u`` of each): a t of the
    same shape on each, weighted by the posterior density at its centre (a Laplace estimate
    of its mass, with the best minimum's shape); those with a share below
    :data:`MIN_MINIMUM_SHARE` left out. Returns the reference, a note for ``reason`` and the
    evaluations spent."""
    if not len(minima):
        return reference, "", 0
    centres = [reference.mean] + [
        space.from_physical(np.asarray(to_physical(names, jnp.asarray(u)), float), log_noise)
        for u in minima
    ]
    out = np.atleast_2d(evaluate(np.stack(centres)))
    lp = np.nan_to_num(out[:, 0] if out.shape[0] == len(centres) else out[0], nan=-np.inf)
    share = np.exp(lp - np.max(lp))
    share = share / np.sum(share)
    keep = share >= MIN_MINIMUM_SHARE
    keep[int(np.argmax(share))] = True
    n = len(centres)
    if keep.sum() == 1 and keep[0]:
        note = f" (the fit's {n - 1} other minima: posterior shares below {MIN_MINIMUM_SHARE:g})"
        return reference, note, n
    covered = Reference(
        reference.mean, reference.cov, reference.nu, reference.prior_sample,
        reference.prior_log_density, reference.prior_share, np.stack(centres)[keep], share[keep],
    )  # fmt: skip
    shares = ", ".join(f"{s:.3g}" for s in share[keep])
    note = (
        f", on {int(keep.sum())} of the fit's {n} distinct minima (shares {shares}, by the "
        "posterior density at each)"
    )
    return covered, note, n


def _attach_noise(result, noise, groups, S, weight, seed, *, rank, floor=None) -> None:
    """Each draw's noise factors drawn from their exact conditional given its residual sums
    of squares ``S`` ``(chains, draws, k)`` (``_likelihood``), put into ``result`` with their
    summaries (``rank``: SMC's rank-normalized R-hat and ESS, the ESS at most ``floor``)."""
    groups = np.asarray(groups)
    w = np.ones(groups.size) if weight is None else np.asarray(weight, float)
    counts = [float(np.sum(w[groups == j])) for j in range(len(noise))]
    rng = np.random.default_rng([seed, 52])
    draws = np.stack(
        [draw_noise_factors(S[..., j], counts[j], rng) for j in range(len(noise))], axis=-1
    )
    result.noise, result.noise_draws = tuple(noise), draws
    for j, name in enumerate(noise):
        stats = _summarize(draws[..., j], rank=rank)
        if floor is not None:
            stats["ess"] = min(stats["ess"], floor)
            stats["ess_tail"] = min(stats["ess_tail"], floor)
        result.summary[name] = stats


def _describe_noise(result, integrated: bool, noise) -> None:
    """``result.noise_treatment`` and the sentence on it in ``result.reason``."""
    if not noise:
        result.noise_treatment = "none"
        return
    result.noise_treatment = "integrated" if integrated else "sampled"
    result.reason += (
        "; noise factors integrated out in closed form (Gaussian likelihood), each drawn "
        "afterwards from its exact conditional"
        if integrated
        else "; noise factors sampled as coordinates"
    )
