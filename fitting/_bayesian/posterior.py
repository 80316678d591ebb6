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
import time
from collections.abc import Mapping, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from jaximpact._engine.devices import engine_jit

from .._least_squares.fit import SAME_VALUES, FitResult, fit
from .._least_squares.objective import FitError, Objective, check_names
from .._least_squares.transforms import dphys_du, to_unbounded
from .hmc import WARMUP, _run_hmc, _starts_and_metric
from .independence import _run_independence
from .likelihood import (
    LIKELIHOODS,
    NOISE_TREATMENTS,
    group_sums,
    noise_factors,
)
from .priors import priors_for
from .programs import (
    BLOCK,
    SAMPLING_RTOL,
    _at_tolerance,
    _batch_log_density,
    _integrates,
    _log_density,
    _model_residuals,
    _model_values,
    _noise_groups,
    _weights,
    _x_batch_log_density,
)
from .result import MAX_RHAT, PosteriorResult, _judged_quantities, _posterior_result
from .smc_posterior import _attach_noise, _describe_noise, _sample_smc
from .space import SamplingSpace

__all__ = [
    "LIKELIHOODS",
    "MAX_RHAT",
    "NOISE_TREATMENTS",
    "PosteriorResult",
    "prepare_posterior",
    "sample_posterior",
]


#: Samplers: ``auto`` (= ``smc``, or ``hmc`` when the chains' starts are given), ``smc``,
#: ``independence`` (values only: every proposal of every chain evaluated in a few large
#: batches; right only where its t proposal covers the posterior) and ``hmc`` (gradients).
SAMPLERS = ("auto", "independence", "hmc", "smc")


#: SMC's local moves: a random walk on values, or MALA on the log density's gradient.
MOVES = ("values", "mala")


def _sample(
    residuals, names, u_center, cov_u, priors, groups, noise, log_noise_center, *, likelihood,
    nu, chains, draws, warmup, seed, jitter, target_accept, progress, z0=None, sampler="auto",
    batch_log_density=None, smc_batch=None, weight=None, noise_treatment="auto", minima=(),
    moves="values",
) -> PosteriorResult:  # fmt: skip
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
    return _sample_chains(
        residuals, names, u_center, cov_u, priors, groups, noise, log_noise_center,
        likelihood=likelihood, nu=nu, chains=chains, draws=draws, warmup=warmup, seed=seed,
        jitter=jitter, target_accept=target_accept, progress=progress, z0=z0, sampler=sampler,
        batch_log_density=batch_log_density, weight=weight, integrated=integrated,
    )  # fmt: skip


def _sample_chains(
    residuals, names, u_center, cov_u, priors, groups, noise, log_noise_center, *, likelihood,
    nu, chains, draws, warmup, seed, jitter, target_accept, progress, z0, sampler,
    batch_log_density, weight, integrated,
) -> PosteriorResult:  # fmt: skip
    """Markov chains: the independence sampler (``sampler="independence"``, unless the
    chains' starts ``z0`` are given) or HMC, from the least-squares shape."""
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
            batch_log_density, center, metric, chains=chains, warmup=warmup, draws=draws,
            seed=seed, progress=progress, judged=lambda z: _judged_quantities(names, z),
        )  # fmt: skip
        divergent, step_size, used = np.zeros(lp.shape, bool), math.nan, "independence"
    if used == "hmc":
        z, lp, divergent, accept, step_size, evaluations, t_warm, t_draw = _run_hmc(
            log_density, z0, metric, warmup=warmup, draws=draws, seed=seed,
            target_accept=target_accept, progress=progress,
        )  # fmt: skip
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


def sample_posterior(
    scene, observations, params: Sequence[str], *, priors: Mapping[str, object] | None = None,
    likelihood: str = "gaussian", nu: float = 4.0, chains: int = 4, draws: int = 1000,
    warmup: int = WARMUP, seed: int = 0, fit_result: FitResult | None = None,
    initial: Mapping[str, float] | None = None, starts: int = 3, jitter: float = 0.5,
    target_accept: float = 0.9, progress: bool = True, method: str | None = None,
    rtol: float | None = SAMPLING_RTOL, sampler: str = "auto", leave_out: Sequence[int] = (),
    noise: str = "auto", moves: str = "values",
) -> PosteriorResult:  # fmt: skip
    """Sample the posterior of ``params`` given the observations.

    **Arguments:**
    - `scene`, `observations`, `params`, `initial`, `starts`, `method`: as for `fit`, which
      runs first (unless `fit_result` is given) to place the sampler.
    - `priors`: ``{name: Prior or "loguniform:LO:HI" or "normal:MU:SD"}``; where not given,
      the scene's ``[priors]`` table, else log-uniform over
      :data:`fitting._priors.PRIOR_RANGES`.
    - `likelihood`: ``"gaussian"`` or ``"student-t"`` (with `nu` degrees of freedom).
    - `sampler`: ``"auto"`` (default) or ``"smc"``: tempered sequential Monte Carlo, from a t
      on the fit where its importance weights show that it covers the posterior, else from
      the prior (`chains` independent populations of `draws` particles); ``"independence"``
      (right only where the posterior is nearly Gaussian) or ``"hmc"`` (module docstring).
    - `chains` (4 or more for a trustworthy R-hat), `draws`, `warmup` (per chain); `seed`;
      `jitter` (chains start this many standard errors from the optimum) and
      `target_accept` (the step size's target acceptance): independence and HMC.
    - `progress`: progress bars on stderr.
    - `rtol`: solver tolerance of the sampler's evaluations (float64; atol ``rtol / 100``),
      where the scene leaves its own unset; None: the scene's (the fit's) tolerance.
    - `noise` (:data:`NOISE_TREATMENTS`): ``"auto"`` integrates the noise factors of
      observables without sigmas out in closed form with the Gaussian likelihood (each factor
      then drawn from its exact conditional) and samples them with the Student-t;
      ``"integrated"`` or ``"sampled"`` forces one (``result.noise_treatment`` says which).
    - `moves` (SMC): ``"values"`` (an independence proposal alternating with a random walk)
      or ``"mala"`` (MALA steps on the log density's forward-mode gradient instead of the
      random walk: a second compiled program, several values' cost per evaluation).
    - `leave_out`: indices (in the fit's order) of observations whose likelihood terms are
      left out, for exact leave-one-out (``fitting.loo``): the same compiled program (the
      rows are simulated with weight 0); a group's only observation left out: its noise
      factor follows the prior.

    **Returns:** a `PosteriorResult`; check ``converged`` (R-hat, divergences).

    **Raises:** `FitError` for bad options, names or priors (and what `fit` raises).
    """
    names = _checked(params, sampler, likelihood, nu, chains, draws, warmup, moves, noise)
    prior_map = priors_for(names, priors, scene.priors, scene.model.damping)
    fit_result, t_fit = _fit_first(
        scene, observations, names, fit_result, initial, starts, progress, method, dict(
            priors=priors, likelihood=likelihood, nu=nu, draws=draws, method=method, rtol=rtol,
            noise=noise, moves=moves,
        ) if sampler in ("smc", "auto") and not leave_out else None,
    )  # fmt: skip
    t_start = time.perf_counter() - t_fit  # a fit made before this call counts in the total
    objective, theta = fit_result.objective, fit_result.theta
    if sampler in ("independence", "hmc"):  # SMC needs no start inside the prior
        _check_inside_priors(names, theta, prior_map)
    sampled = _at_tolerance(objective, rtol)
    cov_u = _u_covariance(names, fit_result)
    groups, noise_names = _noise_groups(objective)
    integrated = _integrates(noise, likelihood, noise_names)
    log_noise = _initial_log_noise(fit_result, groups, noise_names)
    left_out = _check_leave_out(leave_out, len(objective.observations))
    weight = _weights(len(objective.observations), left_out) if left_out else None
    result = _sample(
        _model_residuals(sampled, names), names, to_unbounded(names, theta), cov_u, prior_map,
        groups, noise_names, log_noise, likelihood=likelihood, nu=nu, chains=chains,
        draws=draws, warmup=warmup, seed=seed, jitter=jitter, target_accept=target_accept,
        progress=progress, sampler=sampler, weight=weight, noise_treatment=noise,
        minima=_other_minima(fit_result), moves=moves,
        **_programs(sampler, sampled, names, prior_map, likelihood, nu, weight, integrated, moves),
    )  # fmt: skip
    result.fit, result.left_out, result.noise_groups = fit_result, left_out, groups
    result.options = dict(
        likelihood=likelihood, nu=nu, chains=chains, draws=draws, warmup=warmup, seed=seed,
        jitter=jitter, target_accept=target_accept, rtol=rtol, sampler=sampler, noise=noise,
        moves=moves,
    )  # fmt: skip
    result.program, result.objective = _model_values(sampled, names), sampled
    result.timings = {"fit": t_fit, **result.timings, "total": time.perf_counter() - t_start}
    return result


def _checked(params, sampler, likelihood, nu, chains, draws, warmup, moves, noise):
    """The parameter names, after every option is checked (before the fit runs)."""
    names = check_names(params)
    _check_options(sampler, likelihood, nu, chains, draws, warmup)
    if moves not in MOVES:
        raise FitError(f"moves must be one of {', '.join(MOVES)}, got {moves!r}")
    _integrates(noise, likelihood, ("any factor",))
    return names


def _u_covariance(names, fit_result) -> np.ndarray:
    """The fit's covariance carried into the solver variables ``u``."""
    dpdu = dphys_du(names, fit_result.theta)
    return np.asarray(fit_result.covariance) / np.outer(dpdu, dpdu)


def _fit_first(scene, observations, names, fit_result, initial, starts, progress, method, prepare):
    """The least-squares fit that places the sampler (``fit_result`` where given, checked) and
    its seconds. ``prepare``: :func:`prepare_posterior`'s options, to compile the sampler's
    program while the fit runs (None: not)."""
    if fit_result is not None:
        if tuple(fit_result.params) != names:
            raise FitError(f"fit_result fits {fit_result.params}, not {names}")
        return fit_result, float(fit_result.timings.get("total", 0.0))
    t_start = time.perf_counter()
    if prepare is not None:
        prepare_posterior(scene, observations, names, **prepare)
    fit_result = fit(
        scene, observations, names, initial=initial, starts=starts, progress=progress,
        method=method,
    )  # fmt: skip
    return fit_result, time.perf_counter() - t_start


def _programs(sampler, sampled, names, prior_map, likelihood, nu, weight, integrated, moves):
    """The batch programs that ``sampler`` evaluates, as :func:`_sample`'s keywords."""
    groups, noise_names = _noise_groups(sampled)
    batch = smc = None
    if sampler == "independence":
        batch = _batch_log_density(
            sampled, names, prior_map, groups, len(noise_names), likelihood, nu, weight,
            integrated,
        )  # fmt: skip
    if sampler in ("smc", "auto"):
        smc = _smc_program(sampled, names, prior_map, likelihood, nu, weight, integrated, moves)[0]
    return {"batch_log_density": batch, "smc_batch": smc}


def _smc_program(sampled, names, prior_map, likelihood, nu, weight, integrated, moves):
    """The SMC sampler's batch program (:func:`_x_batch_log_density`) for the objective
    ``sampled`` (the fit's at the sampler's tolerance)."""
    groups, noise_names = _noise_groups(sampled)
    space = SamplingSpace(names, () if integrated else noise_names, prior_map)
    k_int = len(noise_names) if integrated else 0
    return _x_batch_log_density(
        sampled, space, groups, likelihood, nu, weight, k_int, moves == "mala"
    ), space


def prepare_posterior(
    scene, observations, params: Sequence[str], *, priors=None, likelihood: str = "gaussian",
    nu: float = 4.0, draws: int = 1000, method: str | None = None,
    rtol: float | None = SAMPLING_RTOL, noise: str = "auto", moves: str = "values",
) -> bool:  # fmt: skip
    """Start compiling the SMC sampler's program for these data in a background thread, so
    that the least-squares fit that comes first (its own trace, compile and solve) runs
    meanwhile: a cold ``fit --posterior`` pays for the longer of the two compiles, not their
    sum. :func:`sample_posterior` does this itself when it runs the fit; call it before
    :func:`fitting.fit` when you pass that fit's result as ``fit_result``. The arguments are
    :func:`sample_posterior`'s (``method`` the fit's). The program is only used where it is the
    one the sampler needs (a fit whose ``"auto"`` method resolves otherwise at its other
    starts makes another).

    **Returns:** whether a compile was started (False for options or data that
    :func:`sample_posterior` will refuse, with its message, when called)."""
    try:
        names = check_names(params, scene)
        prior_map = priors_for(names, priors, scene.priors, scene.model.damping)
        _check_options("smc", likelihood, nu, 1, draws, WARMUP)
        _integrates(noise, likelihood, ("any factor",))
        if moves not in MOVES:
            return False
        objective = Objective(scene, observations, names, method=method)
        sampled = _at_tolerance(objective, rtol)
        integrated = _integrates(noise, likelihood, _noise_groups(sampled)[1])
    except (ValueError, OSError):  # FitError, DataError: the sampler's call says it
        return False
    program, space = _smc_program(
        sampled, names, prior_map, likelihood, nu, None, integrated, moves
    )
    program.prepare(min(BLOCK, int(draws)), space.dim)
    return True


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
