"""Bayesian posterior of the fitted parameters by NUTS (blackjax), on jaximpact's derivatives.

The log density is written in the solver variables ``u`` of ``_transforms`` (with the Jacobian
term of each prior, ``_priors``), plus one log noise factor per observable that has no sigma
column. Its gradient uses the fit's own compiled residual-and-Jacobian program (forward mode,
``_program``): blackjax calls a ``custom_jvp`` residual function whose value and Jacobian come
from that program through ``jax.pure_callback``, so the sampler never traces the simulator
(no second compilation; the fit's cache serves it) and never runs reverse mode through
diffrax. The chains are a ``vmap``, so each call evaluates all chains as one batch.

Likelihood (``r``: the fit's weighted residuals, ``(model - observed) / scale``):

- ``gaussian``: ``r / s ~ N(0, 1)``; ``s = 1`` where the data give sigma, else a factor
  ``s_k`` per observable ``k`` (sampled, log-uniform on [1e-3, 1e3]) on the default scale;
- ``student-t``: ``r / s ~ t(nu)`` (heavy tails: an outlier pulls less).

A run is good only when every split R-hat is at most :data:`MAX_RHAT` and no transition
diverged; otherwise ``status`` is ``"not converged"`` and ``problems`` says why.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from ._fit import FitResult, fit
from ._objective import FitError, Objective, check_names
from ._priors import Prior, priors_for
from ._program import ResidualProgram
from ._transforms import dphys_du, to_physical, to_unbounded

__all__ = ["LIKELIHOODS", "MAX_RHAT", "PosteriorResult", "sample_posterior"]

LIKELIHOODS = ("gaussian", "student-t")
#: A run with a larger split R-hat for any parameter is not called converged.
MAX_RHAT = 1.01
#: NUTS tree depth limit (at most 2^MAX_DOUBLINGS - 1 log-density evaluations per draw).
MAX_DOUBLINGS = 8
#: Default solver rtol of the posterior's evaluations in float64 (scenes that set their own
#: rtol keep it). The sampler needs the log density to well under 0.1 and its gradient to a few
#: per cent; rtol 1e-8 gives both with a wide margin (measured in BENCHMARKS.md: "Posterior
#: and design") in about half the steps of the fit's default 1e-10.
SAMPLING_RTOL = 1e-8
#: Default warm-up steps per chain (see `_run_nuts`: it starts from the least-squares shape).
WARMUP = 300
#: Range of the sampled noise factors (log-uniform prior).
NOISE_FACTOR_RANGE = (1e-3, 1e3)


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
        step_size: per chain after adaptation; acceptance: mean acceptance rate.
        evaluations: log-density evaluations (each for all chains at once).
        timings: seconds: ``fit``, ``compile``, ``warmup``, ``sampling``, ``total``.
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
    program: ResidualProgram | None = field(default=None, repr=False)
    noise_groups: np.ndarray | None = field(default=None, repr=False)

    @property
    def chains(self) -> int:
        return self.draws.shape[0]

    @property
    def message(self) -> str:
        return self.status + ("" if not self.problems else ": " + "; ".join(self.problems))


# -- the log density ------------------------------------------------------------------------


def _residual_function(oracle: Callable, n: int, p: int, counter: list):
    """``u -> r`` for JAX, computed on the host by ``oracle(U) -> (r, J)`` (``U``: ``(..., p)``),
    with the Jacobian ``J`` as its derivative (``custom_jvp``)."""
    dtype = jnp.result_type(float)

    def host(u):
        counter[0] += 1
        r, jac = oracle(np.asarray(u, dtype=float))
        return np.asarray(r, dtype), np.asarray(jac, dtype)

    def call(u):
        shapes = (
            jax.ShapeDtypeStruct((n,), dtype),
            jax.ShapeDtypeStruct((n, p), dtype),
        )
        return jax.pure_callback(host, shapes, u, vmap_method="broadcast_all")

    @jax.custom_jvp
    def residuals(u):
        return call(u)[0]

    @residuals.defjvp
    def _jvp(primals, tangents):
        (u,), (du,) = primals, tangents
        r, jac = call(u)
        return r, jac @ du

    return residuals


def _log_density(residuals, names, priors, groups, n_noise, likelihood, nu):
    """``z = (u, log noise factors) -> log posterior`` (up to a constant)."""
    p = len(names)
    # Rows with a sigma use factor 1 (index n_noise, a fixed 0 appended to the log factors).
    index = jnp.asarray(np.where(groups >= 0, groups, n_noise))
    lo, hi = (math.log(v) for v in NOISE_FACTOR_RANGE)

    def log_density(z):
        u, log_s = z[:p], z[p:]
        lp = sum(priors[n].log_density_u(n, u[i]) for i, n in enumerate(names))
        if n_noise:
            inside = jnp.all((log_s >= lo) & (log_s <= hi))
            lp = lp + jnp.where(inside, 0.0, -jnp.inf)
        log_scale = jnp.concatenate([log_s, jnp.zeros(1, z.dtype)])[index]
        x = residuals(u) * jnp.exp(-log_scale)
        if likelihood == "gaussian":
            ll = -0.5 * x**2 - log_scale
        else:
            ll = -0.5 * (nu + 1) * jnp.log1p(x**2 / nu) - log_scale
        return lp + jnp.sum(ll)

    return log_density


def _noise_groups(objective: Objective) -> tuple[np.ndarray, tuple[str, ...]]:
    """Noise factor of each observation (index, -1 where the data give sigma) and the names."""
    obs = objective.observations
    no_sigma = ~np.isfinite(obs.sigma)
    kinds = [k for k in dict.fromkeys(obs.observable[no_sigma])]
    groups = np.full(len(obs), -1)
    for j, k in enumerate(kinds):
        groups[no_sigma & (obs.observable == k)] = j
    return groups, tuple(f"sigma_factor[{k}]" for k in kinds)


# -- the sampler ----------------------------------------------------------------------------


def _run_nuts(log_density, z0, metric, *, warmup, draws, seed, target_accept, progress, counter):
    """Warm-up then NUTS draws for every chain (rows of ``z0``). Returns draws ``(C, D, d)``,
    log densities ``(C, D)``, divergent ``(C, D)``, acceptance ``(C, D)``, step sizes ``(C,)``
    and the seconds of warm-up and sampling.

    The warm-up is shorter and shallower than Stan's windowed scheme because it starts from
    the least-squares covariance ``metric`` (the posterior's own shape, the C_A-f0 ridge
    included) instead of learning the metric from scratch:

    1. first half: dual averaging of one step size shared by all chains, with ``metric``;
    2. the metric re-estimated from the second quarter's draws of all chains pooled (4 chains
       x W/4 draws; Stan's windows use one chain's few dozen), shrunk slightly towards
       ``metric``;
    3. second half: dual averaging again with that metric.

    One shared step size and metric keep the chains' trees of similar depth, which matters
    because the chains are one batch: every log-density call evaluates all of them, so a
    step costs as many calls as its deepest chain needs (measured in BENCHMARKS.md)."""
    import blackjax
    from blackjax.adaptation.step_size import dual_averaging_adaptation

    key = jax.random.PRNGKey(seed)
    k_warm, k_draw = jax.random.split(key)
    chains, dim = z0.shape
    kernel = blackjax.nuts.build_kernel()

    def one(k, state, step_size, inverse_mass_matrix):
        return kernel(k, state, log_density, step_size, inverse_mass_matrix, MAX_DOUBLINGS)

    step = jax.jit(jax.vmap(one, in_axes=(0, 0, None, None)))
    da_init, da_update, _ = dual_averaging_adaptation(target_accept)
    da_update = jax.jit(da_update)

    def bar(total, what):
        return tqdm(
            total=total,
            desc=f"posterior {what} ({chains} chains)",
            unit="step",
            disable=not progress,
            file=sys.stderr,
            leave=False,
        )

    t0 = time.perf_counter()
    states = jax.jit(jax.vmap(lambda z: blackjax.nuts.init(z, log_density)))(jnp.asarray(z0))
    imm = np.asarray(metric, dtype=float)
    step_size = 0.5  # in units of the metric's standard deviations
    first = warmup // 2
    pooled = []
    keys = jax.random.split(k_warm, max(warmup, 1))
    with bar(warmup, "warm-up") as progress_bar:
        for phase, (begin, stop) in enumerate(((0, first), (first, warmup))):
            da = da_init(step_size)
            for i in range(begin, stop):
                states, info = step(
                    jax.random.split(keys[i], chains), states, jnp.exp(da.log_step_size), imm
                )
                accept = np.nan_to_num(np.asarray(info.acceptance_rate), nan=0.0)
                da = da_update(da, float(np.mean(accept)))
                if phase == 0 and i >= first // 2:
                    pooled.append(np.asarray(states.position))
                progress_bar.update()
                progress_bar.set_postfix(evaluations=counter[0], refresh=False)
            if stop > begin:
                step_size = float(np.exp(da.log_step_size_avg))
            if phase == 0 and len(pooled) * chains > 2 * dim:
                imm = _pooled_metric(np.concatenate(pooled), imm)
    t_warm = time.perf_counter() - t0

    positions, lps, divergent, accept = [], [], [], []
    t0 = time.perf_counter()
    keys = jax.random.split(k_draw, draws)
    with bar(draws, "draws") as progress_bar:
        for i in range(draws):
            states, info = step(jax.random.split(keys[i], chains), states, step_size, imm)
            positions.append(np.asarray(states.position))
            lps.append(np.asarray(states.logdensity))
            divergent.append(np.asarray(info.is_divergent))
            accept.append(np.asarray(info.acceptance_rate))
            progress_bar.update()
            progress_bar.set_postfix(evaluations=counter[0], refresh=False)
    t_draw = time.perf_counter() - t0
    stack = lambda xs: np.swapaxes(np.stack(xs), 0, 1)  # noqa: E731
    return (
        stack(positions),
        stack(lps),
        stack(divergent),
        stack(accept),
        np.full(chains, step_size),
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


def split_rhat(x: np.ndarray) -> float:
    """Split R-hat (Gelman et al. 2013) of draws ``x`` ``(chains, draws)``: each chain cut in
    two halves, then the potential scale reduction of the halves."""
    from blackjax.diagnostics import potential_scale_reduction

    half = x.shape[1] // 2
    halves = np.concatenate([x[:, :half], x[:, half : 2 * half]], axis=0)
    return float(potential_scale_reduction(jnp.asarray(halves)))


def effective_sample_size(x: np.ndarray) -> float:
    """Effective sample size of draws ``x`` ``(chains, draws)`` (all chains together)."""
    from blackjax.diagnostics import effective_sample_size as ess

    return float(ess(jnp.asarray(x)))


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


def _summarize(x: np.ndarray) -> dict:
    flat = x.reshape(-1)
    q05, median, q95 = np.quantile(flat, [0.05, 0.5, 0.95])
    return {
        "mean": float(np.mean(flat)),
        "median": float(median),
        "sd": float(np.std(flat, ddof=1)),
        "q05": float(q05),
        "q95": float(q95),
        "rhat": split_rhat(x),
        "ess": effective_sample_size(x),
    }


def _sample(
    oracle,
    names,
    n_data,
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
) -> PosteriorResult:
    """The sampler on any residual oracle ``U (..., p) -> (r, J)``: the path of
    :func:`sample_posterior`, open to a toy problem with a known posterior."""
    p, k = len(names), len(noise)
    counter = [0]
    residuals = _residual_function(oracle, n_data, p, counter)
    log_density = _log_density(residuals, names, priors, np.asarray(groups), k, likelihood, nu)
    # Starts: the least-squares optimum plus a jitter of `jitter` standard errors.
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
    z, lp, divergent, accept, step_size, t_warm, t_draw = _run_nuts(
        log_density,
        z0,
        metric,
        warmup=warmup,
        draws=draws,
        seed=seed,
        target_accept=target_accept,
        progress=progress,
        counter=counter,
    )
    theta = np.asarray(jax.vmap(jax.vmap(lambda u: to_physical(names, u)))(jnp.asarray(z[..., :p])))
    noise_draws = np.exp(z[..., p:])
    summary = {n: _summarize(theta[..., i]) for i, n in enumerate(names)}
    summary.update({n: _summarize(noise_draws[..., j]) for j, n in enumerate(noise)})
    flat = theta.reshape(-1, p)
    correlation = np.corrcoef(flat, rowvar=False) if p > 1 else np.ones((1, 1))
    n_div = int(np.sum(divergent))
    problems = judge(summary, n_div)
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
        step_size=step_size,
        acceptance=float(np.mean(accept)),
        evaluations=counter[0],
        timings={"warmup": t_warm, "sampling": t_draw},
        log_density=lp,
    )


def _at_tolerance(objective: Objective, rtol: float | None) -> Objective:
    """The objective with solver tolerance ``rtol`` (atol ``rtol / 100``) unless ``rtol`` is
    None, the scene sets its own, or the precision is not float64 (its default is looser)."""
    solver = objective.scene.solver
    if rtol is None or solver.rtol is not None or jnp.result_type(float) != jnp.float64:
        return objective
    if not 0 < rtol < 1:
        raise FitError(f"rtol must be in (0, 1), got {rtol!r}")
    scene = objective.scene.replace(solver={"rtol": rtol, "atol": solver.atol or rtol / 100})
    return Objective(
        scene,
        objective.observations,
        objective.params,
        failure_residual=objective.failure_residual,
        method=objective.method,
    )


def _program_oracle(program: ResidualProgram, p: int):
    """``U (..., p) -> (r, J)`` by the compiled program, in batches of its size."""

    def oracle(U):
        U = np.asarray(U, dtype=float)
        lead = U.shape[:-1]
        flat = U.reshape(-1, p)
        size = program.starts
        pad = (-len(flat)) % size
        padded = np.concatenate([flat, np.repeat(flat[:1], pad, axis=0)]) if pad else flat
        rs, js = [], []
        for i in range(0, len(padded), size):
            r, jac, _ = program(padded[i : i + size])
            rs.append(r)
            js.append(jac)
        r = np.concatenate(rs)[: len(flat)]
        jac = np.concatenate(js)[: len(flat)]
        return r.reshape(*lead, r.shape[-1]), jac.reshape(*lead, *jac.shape[-2:])

    return oracle


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
) -> PosteriorResult:
    """Sample the posterior of ``params`` given the observations, by NUTS.

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
    - `rtol`: solver tolerance of the sampler's evaluations (float64; atol ``rtol / 100``),
      where the scene leaves its own unset; None: the scene's (the fit's) tolerance.

    **Returns:** a `PosteriorResult`; check ``converged`` (R-hat, divergences).

    **Raises:** `FitError` for bad options, names or priors (and what `fit` raises).
    """
    t_start = time.perf_counter()
    names = check_names(params)
    if likelihood not in LIKELIHOODS:
        raise FitError(f"likelihood must be one of {', '.join(LIKELIHOODS)}, got {likelihood!r}")
    if not nu > 0:
        raise FitError(f"nu must be > 0, got {nu!r}")
    for label, value, least in (("chains", chains, 1), ("draws", draws, 4), ("warmup", warmup, 1)):
        if not (isinstance(value, int) and value >= least):
            raise FitError(f"{label} must be an integer >= {least}, got {value!r}")
    prior_map = priors_for(names, priors, scene.priors)
    if fit_result is None:
        fit_result = fit(
            scene,
            observations,
            names,
            initial=initial,
            starts=starts,
            progress=progress,
            method=method,
        )
    elif tuple(fit_result.params) != names:
        raise FitError(f"fit_result fits {fit_result.params}, not {names}")
    t_fit = time.perf_counter() - t_start
    objective = fit_result.objective
    theta = fit_result.theta
    for n, v in zip(names, theta, strict=True):
        if not math.isfinite(float(prior_map[n].log_density_u(n, to_unbounded([n], [v])[0]))):
            raise FitError(
                f"the least-squares {n} = {v:.4g} lies outside its prior {prior_map[n].describe()}"
            )
    # Thousands of calls: the program that runs fastest, not the one that compiles fastest.
    program = ResidualProgram(_at_tolerance(objective, rtol), chains, program="throughput")
    t_compile = program.compile(status=progress)
    dpdu = dphys_du(names, theta)
    cov_u = np.asarray(fit_result.covariance) / np.outer(dpdu, dpdu)
    groups, noise = _noise_groups(objective)
    r_fit = np.asarray(fit_result.residuals)
    log_noise = [
        math.log(max(float(np.sqrt(np.mean(r_fit[groups == j] ** 2))), 1e-2))
        for j in range(len(noise))
    ]
    result = _sample(
        _program_oracle(program, len(names)),
        names,
        objective.n_data,
        to_unbounded(names, theta),
        cov_u,
        prior_map,
        groups,
        noise,
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
    )
    result.fit = fit_result
    result.program = program
    result.noise_groups = groups
    result.timings = {
        "fit": t_fit,
        "compile": t_compile,
        **result.timings,
        "total": time.perf_counter() - t_start,
    }
    return result


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
    oracle = _program_oracle(_ValueProgram(result.program), p)
    model, _ = oracle(U)
    objective = result.fit.objective
    groups = result.noise_groups
    factor = np.where(
        groups >= 0, noise[pick][:, np.maximum(groups, 0)] if noise.size else 1.0, 1.0
    )
    rng = np.random.default_rng(seed)
    if result.likelihood == "gaussian":
        e = rng.standard_normal(model.shape)
    else:
        e = rng.standard_t(result.nu, model.shape)
    return model, model + e * factor * objective.scale


class _ValueProgram:
    """The residual program asked for model values (observed 0, scale 1)."""

    def __init__(self, program):
        self.program, self.starts = program, program.starts

    def __call__(self, U):
        return self.program(U, value=0.0, scale=1.0)
