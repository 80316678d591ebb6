"""MCMC convergence diagnostics for one scalar quantity drawn by several chains.

Every function takes ``x``, an array of shape ``(chains, draws)`` (a 1-D array is one chain),
and returns a float:

- ``split_rhat``: classic split R-hat of the raw values (between- vs within-chain variance,
  each chain cut into two halves).
- ``rank_rhat``: the improved R-hat, the larger of the split R-hat of the rank-normalized draws
  (bulk) and of the rank-normalized folded draws ``|x - median|`` (tails).  Use it to decide
  convergence: values above 1.01 mean the chains have not mixed.
- ``ess``: effective sample size of the raw values (multi-chain autocorrelation estimate).
- ``ess_bulk``: ESS of the rank-normalized split chains; reliability of means and medians.
- ``ess_tail``: the smaller ESS of the indicators ``x <= q05`` and ``x <= q95``; reliability
  of the 5 % and 95 % quantiles.
- ``mcse_quantile``: Monte Carlo standard error of a quantile of ``x``.

And for importance weights (a 1-D array): ``pareto_khat``, the shape of a generalized Pareto
distribution fitted to their upper tail (Zhang & Stephens 2009, with the weak prior toward
0.5 of Vehtari et al. 2024; above 0.7 the weights' mean is unreliable).

Reference: A. Vehtari, A. Gelman, D. Simpson, B. Carpenter, P.-C. Bürkner (2021),
"Rank-normalization, folding, and localization: An improved R-hat for assessing convergence of
MCMC", Bayesian Analysis 16(2), 667-718.  The autocorrelation sum is truncated with Geyer's
initial monotone sequence as in Stan.

The results agree with ArviZ (``az.rhat``, ``az.ess``, ``az.mcse``): draws containing NaN, or
fewer than 4 draws per chain, give NaN; a constant array gives NaN for R-hat and the total number
of draws for ESS.  Unlike ArviZ, R-hat is also computed for a single chain (from its two halves).
"""

import numpy as np
from scipy.special import betaincinv, ndtri
from scipy.stats import rankdata

__all__ = [
    "ess", "ess_bulk", "ess_tail", "mcse_quantile", "pareto_khat", "rank_rhat", "split_rhat",
]  # fmt: skip

_MIN_DRAWS = 4
# Spread below which a set of draws counts as constant (the threshold ArviZ uses).
_CONSTANT = np.finfo(float).resolution


def _as_draws(x) -> np.ndarray | None:
    """``x`` as a float (chains, draws) array, or None when no diagnostic can be computed."""
    x = np.asarray(x, dtype=float)
    if x.ndim == 1:
        x = x[None, :]
    if x.ndim != 2:
        raise ValueError(f"expected draws of shape (chains, draws), got shape {x.shape}")
    if x.shape[0] < 1 or x.shape[1] < _MIN_DRAWS or np.isnan(x).any():
        return None
    return x


def _split(x: np.ndarray) -> np.ndarray:
    """Each chain cut into its first and second half (the middle draw dropped if odd)."""
    half = x.shape[1] // 2
    return np.concatenate([x[:, :half], x[:, x.shape[1] - half :]], axis=0)


def _rank_normalize(x: np.ndarray) -> np.ndarray:
    """Normal scores of the ranks of all draws pooled (ties get their average rank)."""
    ranks = rankdata(x, method="average", axis=None).reshape(x.shape)
    return ndtri((ranks - 0.375) / (x.size + 0.25))


def _rhat(x: np.ndarray) -> float:
    """R-hat of chains taken as they are: sqrt(var_plus / W)."""
    if np.ptp(x) < _CONSTANT:
        return np.nan
    n = x.shape[1]
    within = np.mean(np.var(x, axis=1, ddof=1))
    between_over_n = np.var(np.mean(x, axis=1), ddof=1) if x.shape[0] > 1 else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.sqrt(((n - 1) / n * within + between_over_n) / within))


def _autocov(x: np.ndarray) -> np.ndarray:
    """Autocovariance of each chain at lags 0..draws-1 (normalized by draws), via the FFT."""
    n = x.shape[1]
    centred = x - np.mean(x, axis=1, keepdims=True)
    nfft = 1 << (2 * n - 1).bit_length()  # zero padding >= 2n - 1: no circular wrap-around
    spectrum = np.fft.rfft(centred, n=nfft, axis=1)
    power = spectrum.real**2 + spectrum.imag**2
    return np.fft.irfft(power, n=nfft, axis=1)[:, :n] / n


def _ess(x: np.ndarray) -> float:
    """ESS of chains taken as they are (no splitting, no shape checks)."""
    m, n = x.shape
    if np.ptp(x) < _CONSTANT:
        return float(x.size)
    acov = _autocov(x)
    if not np.isfinite(acov).all():
        return np.nan
    within = np.mean(acov[:, 0]) * n / (n - 1)
    var_plus = (n - 1) / n * within
    if m > 1:
        var_plus += np.var(np.mean(x, axis=1), ddof=1)
    # Combined autocorrelation estimate rho_t = 1 - (W - mean over chains of acov_t) / var_plus,
    # rho_0 = 1 by definition (as in Stan; the formula would give (n - 1) / n W / var_plus).
    rho = 1.0 - (within - np.mean(acov, axis=0)) / var_plus
    rho[0] = 1.0

    # Geyer's initial positive sequence: keep the pairs (rho_{t+1}, rho_{t+2}), t = 1, 3, ...,
    # up to the first pair with a negative sum.
    kept = np.zeros(n)
    kept[:2] = rho[:2]
    even, odd = rho[0], rho[1]
    t = 1
    while t < n - 3 and even + odd > 0.0:
        even, odd = rho[t + 1], rho[t + 2]
        if even + odd >= 0.0:
            kept[t + 1], kept[t + 2] = even, odd
        t += 2
    last = t - 2  # the odd lag before the last pair examined
    if even > 0.0:  # that pair's even lag enters once, as in Stan (its odd lag does not)
        kept[last + 1] = even
    # Geyer's initial monotone sequence: pair sums may not increase.
    for t in range(1, last - 1, 2):
        if kept[t + 1] + kept[t + 2] > kept[t - 1] + kept[t]:
            kept[t + 1] = kept[t + 2] = (kept[t - 1] + kept[t]) / 2.0
    tau = -1.0 + 2.0 * np.sum(kept[: last + 1]) + kept[last + 1]
    # Stan's floor on tau, so that ESS is at most S log10(S) for antithetic chains.
    tau = max(tau, 1.0 / np.log10(x.size))
    return float(x.size / tau)


def _ess_quantile(x: np.ndarray, prob: float) -> float:
    """ESS of the indicator x <= (the prob quantile of all draws pooled), split chains."""
    q = np.quantile(x, prob)
    return _ess(_split(x <= q).astype(float))


def split_rhat(x) -> float:
    """Classic split R-hat of the raw values (Gelman et al., BDA3)."""
    x = _as_draws(x)
    return np.nan if x is None else _rhat(_split(x))


def rank_rhat(x) -> float:
    """Rank-normalized split R-hat: the larger of the bulk and the folded (tail) R-hat."""
    x = _as_draws(x)
    if x is None:
        return np.nan
    halves = _split(x)
    bulk = _rhat(_rank_normalize(halves))
    tail = _rhat(_rank_normalize(np.abs(halves - np.median(halves))))
    return float(max(bulk, tail))


def ess(x) -> float:
    """Effective sample size of the raw values, the chains taken whole (not split)."""
    x = _as_draws(x)
    return np.nan if x is None else _ess(x)


def ess_bulk(x) -> float:
    """Bulk ESS: ESS of the rank-normalized split chains."""
    x = _as_draws(x)
    return np.nan if x is None else _ess(_rank_normalize(_split(x)))


def ess_tail(x) -> float:
    """Tail ESS: the smaller ESS of the 5 % and 95 % quantile indicators."""
    x = _as_draws(x)
    if x is None:
        return np.nan
    return min(_ess_quantile(x, 0.05), _ess_quantile(x, 0.95))


def mcse_quantile(x, prob: float) -> float:
    """Monte Carlo standard error of the ``prob`` quantile of the draws.

    Half the distance between the order statistics at the 15.9 % and 84.1 % points of the
    posterior (Beta) of the probability mass below the estimated quantile, whose sample size is
    the ESS of the indicator.
    """
    x = _as_draws(x)
    if x is None:
        return np.nan
    n_eff = _ess_quantile(x, prob)
    lo, hi = betaincinv(n_eff * prob + 1, n_eff * (1 - prob) + 1, [0.1586553, 0.8413447])
    draws = np.sort(x, axis=None)
    size = draws.size
    # 1-based order statistics floor(lo S) and ceil(hi S), clipped to 1..S (the extremes if NaN).
    i = max(int(np.floor(lo * size)), 1) - 1 if np.isfinite(lo) else 0
    j = min(int(np.ceil(hi * size)), size) - 1 if np.isfinite(hi) else size - 1
    return float((draws[j] - draws[i]) / 2)


#: Share of the weights taken as the tail (at least 5 of them): blackjax's ``pareto_khat``
#: default, which the sampler's thresholds were validated with.
TAIL_SHARE = 0.10


def pareto_khat(weights) -> float:
    """Pareto shape k of the upper tail of ``weights`` (1-D, >= 0; e.g. importance ratios
    ``exp(log_w - max)``): the empirical-Bayes fit of Zhang & Stephens (2009) to the
    exceedances of the largest :data:`TAIL_SHARE` over the next value, shrunk toward 0.5 by a
    prior worth 10 exceedances. 0 where the tail is flat. numpy only: no compile per size."""
    x = np.sort(np.asarray(weights, float).ravel())
    n = x.size
    m = max(int(TAIL_SHARE * n), 5)
    if n <= m:
        return np.inf
    tail = x[n - m :] - x[n - m - 1]  # ascending, >= 0
    if not tail[-1] > np.finfo(float).tiny:
        return 0.0
    grid = 30 + int(m**0.5)
    # candidate b (the GPD's -k / sigma), spread by the tail's quartile and maximum
    b = 1.0 - np.sqrt(grid / (np.arange(1, grid + 1) - 0.5))
    quartile = tail[int(m / 4 + 0.5) - 1]
    if not quartile > 0:  # ties at the threshold: the smallest exceedance instead of 0
        quartile = tail[tail > 0][0]
    b = b / (3.0 * quartile) + 1.0 / tail[-1]
    k = np.mean(np.log1p(-b[:, None] * tail[None, :]), axis=1)
    profile = m * (np.log(-b / k) - k - 1.0)  # profile log likelihood of each b
    w = np.exp(profile - np.max(profile))
    b_mean = np.sum(b * w) / np.sum(w)
    k_fit = float(np.mean(np.log1p(-b_mean * tail)))
    return (m * k_fit + 10 * 0.5) / (m + 10)
