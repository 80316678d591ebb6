"""The posterior's likelihood, and the noise factors of observables without sigmas.

Residuals ``r`` are the fit's weighted residuals, ``(model - observed) / scale``. An
observation whose data give a sigma has ``scale = sigma`` and ``r ~ N(0, 1)`` (or ``t(nu)``).
An observable without sigmas gets one noise factor ``s_k`` (its sigma in units of the
observable's default scale), log-uniform on :data:`NOISE_FACTOR_RANGE` ``= [a, b]``, with
``r / s_k ~ N(0, 1)`` (or ``t(nu)``).

**The Gaussian likelihood integrates each factor out in closed form.** With ``n`` (weighted)
observations of group ``k`` and their residual sum of squares ``S = sum r^2``,

    int_a^b s^-n exp(-S / (2 s^2)) ds / (s ln(b/a))
        = Gamma(n/2) (2/S)^(n/2) [P(n/2, S/(2a^2)) - P(n/2, S/(2b^2))] / (2 ln(b/a))

(substitute ``t = S / (2 s^2)``; ``P`` is the regularized lower incomplete gamma function).
The sampler then runs on the physical parameters alone, and each factor is drawn afterwards
from its exact conditional given the residuals of each draw: ``t = S / (2 s^2)`` follows a
Gamma(n/2) distribution truncated to ``[S/(2b^2), S/(2a^2)]``. The joint draws ``(theta, s)``
are then exact draws of the same posterior that sampling ``s`` gives, with one dimension per
observable less to explore. The Student-t likelihood has no such closed form: its factors are
sampled (``noise="sampled"`` forces that for the Gaussian too).

Constants common to both forms are dropped alike (the ``2 pi`` of the Gaussian), so that a
log evidence is the same in either form.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.special import gammainc, gammaincc, gammaln
from scipy import special

__all__ = [
    "LIKELIHOODS",
    "NOISE_FACTOR_RANGE",
    "NOISE_TREATMENTS",
    "draw_noise_factors",
    "group_sums",
    "log_likelihood_function",
    "log_marginal_gaussian",
    "noise_factors",
    "noise_groups",
]

LIKELIHOODS = ("gaussian", "student-t")
#: Range of the noise factors (log-uniform prior).
NOISE_FACTOR_RANGE = (1e-3, 1e3)
#: How noise factors enter the posterior: ``integrated`` (closed form, Gaussian only),
#: ``sampled`` (a coordinate of the sampler each), ``auto`` (integrated where possible).
NOISE_TREATMENTS = ("auto", "integrated", "sampled")


def noise_groups(observable, sigma) -> tuple[np.ndarray, tuple[str, ...]]:
    """Noise factor of each observation (an index; -1 where the data give a sigma) and the
    factors' names ``sigma_factor[OBSERVABLE]``, in the order the observables first appear."""
    observable = np.asarray(observable)
    no_sigma = ~np.isfinite(np.asarray(sigma, float))
    kinds = list(dict.fromkeys(observable[no_sigma]))
    groups = np.full(len(observable), -1)
    for j, kind in enumerate(kinds):
        groups[no_sigma & (observable == kind)] = j
    return groups, tuple(f"sigma_factor[{k}]" for k in kinds)


def log_marginal_gaussian(S, n):
    """``ln`` of the Gaussian likelihood of ``n`` residuals with sum of squares ``S``,
    integrated over their noise factor's log-uniform prior on :data:`NOISE_FACTOR_RANGE`
    (module docstring; JAX, differentiable in ``S``). ``n = 0``: 0 (the prior's mass)."""
    lo, hi = NOISE_FACTOR_RANGE
    n = jnp.asarray(n, dtype=jnp.result_type(float))
    empty = n <= 0
    a = jnp.where(empty, 1.0, 0.5 * n)
    S = jnp.where(empty, 1.0, S) + 1e-200  # a perfect fit (S = 0) has a finite limit
    t_lo, t_hi = S / (2 * lo**2), S / (2 * hi**2)  # t at s = a (large) and s = b (small)
    # The mass of Gamma(a) on [t_hi, t_lo] times (2/S)^a, from whichever tail keeps its
    # digits; each branch's input masked, so that no NaN reaches a derivative through the
    # branch not taken.
    upper = t_hi > a
    q = jax.lax.stop_gradient(gammaincc(a, t_hi) - gammaincc(a, t_lo))
    far = upper & ~(q > 0)  # Q underflows: residuals far above the largest factor
    t_u = jnp.where(upper & ~far, t_hi, 2.0 * a)
    t_f = jnp.where(far, t_hi, 2.0 * a)
    log_upper = jnp.where(
        far,
        (a - 1.0) * jnp.log(t_f) - t_f - gammaln(a),  # Q(a, t) ~ t^(a-1) e^-t / Gamma(a)
        jnp.log(gammaincc(a, t_u) - gammaincc(a, jnp.where(upper & ~far, t_lo, 4.0 * a))),
    ) + a * (math.log(2.0) - jnp.log(S))
    # Lower tail: P(a, t_lo) - P(a, t_hi) = P(a, t_lo) (1 - ratio). Where P(a, t_lo)
    # underflows (residuals far below the smallest factor), its series' leading term
    # t^a e^-t / Gamma(a + 1) / (1 - t / (a + 1)), with (2/S)^a t_lo^a = a^-2a in closed form.
    tiny = ~upper & ~(jax.lax.stop_gradient(gammainc(a, t_lo)) > 1e-280)
    t_ok = jnp.where(tiny | upper, a, t_lo)
    t_s = jnp.where(tiny, t_lo, 0.5 * a)
    p_ok = gammainc(a, t_ok)
    ratio = jnp.where(
        tiny, (lo / hi) ** (2 * a), gammainc(a, jnp.where(tiny | upper, 0.5 * a, t_hi)) / p_ok
    )
    log_lower = jnp.where(
        tiny,
        -2 * a * math.log(lo) - t_s - gammaln(a + 1.0) - jnp.log1p(-t_s / (a + 1.0)),
        jnp.log(p_ok) + a * (math.log(2.0) - jnp.log(S)),
    ) + jnp.log1p(-jnp.minimum(ratio, 1.0 - 1e-16))
    value = gammaln(a) + jnp.where(upper, log_upper, log_lower) - math.log(2 * math.log(hi / lo))
    return jnp.where(empty, 0.0, value)


def group_sums(r, groups, n_groups: int, weight=None):
    """``(S (k,), n (k,))``: each noise group's weighted residual sum of squares and weighted
    count (JAX; rows with a sigma, group -1, count in none)."""
    w = jnp.ones_like(r) if weight is None else jnp.asarray(weight, r.dtype)
    onehot = jnp.asarray(np.arange(n_groups)[:, None] == np.asarray(groups)[None, :], r.dtype)
    r2 = jnp.where(w == 0, 0.0, r * r)  # a left-out row's residual may be inf
    return onehot @ (w * r2), onehot @ w


def log_likelihood_function(groups, n_noise: int, likelihood: str, nu: float, integrated=False):
    """``(r, log noise factors[, weight]) -> log likelihood`` (JAX, up to the constants both
    forms drop). ``weight`` (one per observation, default 1): 0 leaves an observation out.
    ``integrated``: the Gaussian with every noise factor integrated out (the log factors
    passed are then ignored: pass an empty array)."""
    groups = np.asarray(groups)
    if integrated and likelihood != "gaussian":
        raise ValueError("only the Gaussian likelihood integrates its noise factors")
    # Rows with a sigma use factor 1 (index n_noise, a fixed 0 appended to the log factors).
    index = jnp.asarray(np.where(groups >= 0, groups, n_noise))
    has_sigma = jnp.asarray(groups < 0)

    def with_sigmas(r, weight):
        ll = -0.5 * r**2
        if weight is not None:
            ll = jnp.where(weight == 0, 0.0, weight * ll)
        return jnp.sum(jnp.where(has_sigma, ll, 0.0))

    def log_likelihood(r, log_s, weight=None):
        if integrated:
            S, n = group_sums(r, groups, n_noise, weight)
            return with_sigmas(r, weight) + jnp.sum(log_marginal_gaussian(S, n))
        log_scale = jnp.concatenate([log_s, jnp.zeros(1, r.dtype)])[index]
        x = r * jnp.exp(-log_scale)
        if likelihood == "gaussian":
            ll = -0.5 * x**2 - log_scale
        else:
            ll = -0.5 * (nu + 1) * jnp.log1p(x**2 / nu) - log_scale
        if weight is not None:  # where, not a product: a left-out term may be inf
            ll = jnp.where(weight == 0, 0.0, weight * ll)
        return jnp.sum(ll)

    return log_likelihood


def draw_noise_factors(S, n, rng: np.random.Generator) -> np.ndarray:
    """One draw of a noise factor from its exact conditional posterior for each residual sum
    of squares in ``S`` (numpy, any shape) of ``n`` (weighted) observations: ``t = S /
    (2 s^2)`` is Gamma(n/2) truncated to ``[S/(2b^2), S/(2a^2)]`` (by its inverse CDF);
    ``n = 0``: the log-uniform prior."""
    lo, hi = NOISE_FACTOR_RANGE
    S = np.asarray(S, float)
    u = rng.uniform(size=S.shape)
    if not n > 0:
        return np.exp(math.log(lo) + u * math.log(hi / lo))
    a = 0.5 * float(n)
    S = np.maximum(S, 1e-300)
    t_lo, t_hi = S / (2 * lo**2), S / (2 * hi**2)
    with np.errstate(all="ignore"):
        upper = t_hi > a
        q_hi, q_lo = special.gammaincc(a, t_hi), special.gammaincc(a, t_lo)
        p_hi, p_lo = special.gammainc(a, t_hi), special.gammainc(a, t_lo)
        t = np.where(
            upper,
            special.gammainccinv(a, q_lo + u * (q_hi - q_lo)),
            special.gammaincinv(a, p_hi + u * (p_lo - p_hi)),
        )
        s = np.sqrt(S / (2.0 * t))
        # Where P(a, t_lo) underflows the residuals are far below the smallest factor: the
        # conditional is then s^-(n+1) on [a, b] (exp(-S / 2s^2) = 1 there).
        tiny = ~upper & ~(p_lo > 1e-290)
        power = lo * (1.0 - u * (1.0 - (lo / hi) ** n)) ** (-1.0 / n)
        # Where Q(a, t_hi) underflows they are far above the largest: s = b.
        s = np.where(upper & ~(q_hi > 0), hi, s)
    return np.clip(np.where(tiny | ~np.isfinite(s), power, s), lo, hi)


def noise_factors(noise: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """``(draws, observations)`` sigma factor of each observation at each draw: its group's
    factor (``noise``: ``(draws, groups)``), 1 for rows with a sigma (group -1)."""
    groups = np.asarray(groups)
    if not noise.size:
        return np.ones((noise.shape[0], groups.size))
    return np.where(groups >= 0, noise[:, np.maximum(groups, 0)], 1.0)
