"""HMC (``sampler="hmc"``): blackjax's HMC, chains in step (one batch per gradient
evaluation), in the fit's solver variables ``u``, its metric from the least-squares shape.
"""

from __future__ import annotations

import math
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaximpact._engine.devices import engine_jit

from .programs import _progress_bar

#: Default warm-up steps per chain (see `_run_hmc`: it starts from the least-squares shape).
WARMUP = 300


#: HMC trajectory length in units of the metric: a quarter period of a Gaussian posterior
#: whose covariance the metric matches, where successive draws are independent.
TRAJECTORY = math.pi / 2


#: Most leapfrog steps of one transition (a step size collapsed by a bad region stops here).
MAX_LEAPFROG = 64


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

    chains = z0.shape[0]
    kernel = blackjax.hmc.build_kernel()

    def one(key, state, step_size, inverse_mass_matrix, n_leapfrog):
        return kernel(key, state, log_density, step_size, inverse_mass_matrix, n_leapfrog)

    # One compiled program for every step of warm-up and sampling (the step size, metric and
    # leapfrog count are inputs).
    step = engine_jit(jax.vmap(one, in_axes=(0, 0, None, None, None)))
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
    with bar(warmup, "warm-up") as progress_bar:
        states, step_size, imm = _warm_up(
            transition, states, metric, warmup, dual_averaging_adaptation(target_accept),
            progress_bar, evaluations,
        )  # fmt: skip
    t_warm = time.perf_counter() - t0
    t0 = time.perf_counter()
    with bar(draws, "draws") as progress_bar:
        out = _draws(transition, states, step_size, imm, draws, progress_bar, evaluations)
    return (*out, step_size, evaluations[0], t_warm, time.perf_counter() - t0)


def _warm_up(transition, states, metric, warmup, adaptation, progress_bar, evaluations):
    """:func:`_run_hmc`'s warm-up (its steps 1-3): ``(states, step size, metric)``."""
    da_init, da_update, _ = adaptation
    da_update = jax.jit(da_update)
    chains, dim = np.shape(states.position)
    imm = np.asarray(metric, dtype=float)
    step_size = 0.5  # in units of the metric's standard deviations
    first = warmup // 2
    pooled = []
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
    return states, step_size, imm


def _draws(transition, states, step_size, imm, draws, progress_bar, evaluations):
    """``draws`` transitions of every chain: positions, log densities, divergent and
    acceptance, each ``(chains, draws, ...)``."""
    positions, lps, divergent, accept = [], [], [], []
    for _ in range(draws):
        states, info = transition(states, step_size, imm)
        positions.append(np.asarray(states.position))
        lps.append(np.asarray(states.logdensity))
        divergent.append(np.asarray(info.is_divergent))
        accept.append(np.asarray(info.acceptance_rate))
        progress_bar.update()
        progress_bar.set_postfix(evaluations=evaluations[0], refresh=False)
    return tuple(np.swapaxes(np.stack(xs), 0, 1) for xs in (positions, lps, divergent, accept))


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
