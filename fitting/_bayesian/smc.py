"""Sequential Monte Carlo: tempering from an overdispersed reference to the posterior.

Every population of particles starts as independent draws of a reference ``q0`` that covers
the posterior by construction: a mixture of a heavy-tailed Student-t placed by the
least-squares fit and the prior itself (a "defensive" mixture: the importance weight
``posterior / q0`` is bounded wherever the prior has mass, so no region of the prior is out of
reach). The particles then follow the geometric path ``pi_b ~ q0^(1-b) posterior^b`` from
``b = 0`` to 1 (Del Moral, Doucet & Jasra 2006, "Sequential Monte Carlo samplers"):

1. **reweight**: the next ``b`` is the largest that keeps the effective sample size of the
   incremental weights ``(posterior / q0)^(db)`` at :data:`TARGET_ESS` of the particles
   (found by bisection), so that no step loses the particles of a region at once; where the
   reference already covers the posterior, ``b`` goes to 1 in one step (plain importance
   sampling);
2. **resample** (systematic);
3. **move**: Metropolis-Hastings steps that leave ``pi_b`` invariant, alternately an
   independence proposal from a Gaussian mixture fitted to the population (global moves:
   its components follow a curved ridge) and a random walk with the population's covariance
   (local moves, step scaled toward 30 % acceptance), until each coordinate's correlation
   between the particles' positions now and at the resampling is below :data:`DECORRELATION` (at
   ``b = 1``; :data:`STAGE_DECORRELATION` on the way), so that the copies that resampling
   made of one particle have moved apart (the rule of PyMC's SMC). A population still
   above it after :data:`MAX_MOVES` moves at ``b = 1`` is reported only where the
   correlation of the positions' ranks is above it too, and above the noise of a correlation
   at this many particles (:data:`STUCK_SE`; a heavy tail keeps Pearson's high).

At ``b = 1`` a population stops as soon as it holds an importance sample of the posterior
whose weights certify it (ESS at least :data:`IMPORTANCE_ESS` of the particles, Pareto k at
most :data:`IMPORTANCE_KHAT`: below 0.5 the importance estimates have a finite variance,
Vehtari et al. 2024; no draw worth more than :data:`IMPORTANCE_MAX_WEIGHT` particles):
either the reference's own draws, where the first step reaches ``b = 1`` so, or the first
independence move's proposals (fresh draws of the mixture fitted to the particles, evaluated
for that move anyway), weighted by posterior over proposal. The population is then those
draws resampled, worth the Kish ESS of their weights, which is what the run reports as its
effective sample size; the moves would only turn the resampled copies into independent
draws, at 4-6 more evaluations per particle.

Only values of the log density are needed, never gradients, and every move of every particle
of every population is one batch of evaluations (the simulator's lanes full). The populations
are independent runs: their disagreement (R-hat over populations) is evidence that a run
missed part of the posterior, which chains that share one proposal cannot give.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.special import logsumexp
from scipy.stats import rankdata
from tqdm.auto import tqdm

from .diagnostics import pareto_khat

__all__ = ["Reference", "SMCRun", "run_smc"]

#: Each tempering step keeps this fraction of the particles as effective sample size; the
#: step to b = 1 may keep FINAL_ESS where its weights' Pareto k is at most FINAL_KHAT (the
#: importance weights are then reliable: Vehtari et al. 2024), which saves a stage's moves
#: where the reference already covers the posterior.
TARGET_ESS = 0.5
FINAL_ESS = 0.25
FINAL_KHAT = 0.7
#: Moves at b = 1 continue until every coordinate's correlation with the positions at the
#: last resampling is below this; on the way to b = 1, below STAGE_DECORRELATION.
DECORRELATION = 0.1
STAGE_DECORRELATION = 0.5
#: Most moves per stage (a kernel that cannot decorrelate the particles stops here and says so).
MAX_MOVES = 30
#: A population still above DECORRELATION after MAX_MOVES is reported where its rank
#: correlation is above DECORRELATION too, and above this many standard errors of the
#: correlation of independent positions (1 / sqrt(particles)): at 500 particles the largest of
#: three independent coordinates' |r| exceeds 0.1 in 7 % of populations by chance alone.
STUCK_SE = 4.0
#: ... and on the way to b = 1 at most this many (the next reweighting needs particles spread,
#: not independent; the last stage's moves make them independent).
MAX_STAGE_MOVES = 3
#: An importance sample at b = 1 with at least IMPORTANCE_ESS of the particles as ESS and a
#: Pareto k of at most IMPORTANCE_KHAT ends a population (module docstring).
IMPORTANCE_ESS = 0.5
IMPORTANCE_KHAT = 0.5
#: ... and no draw carrying more than this many particles' worth of weight. A proposal that
#: covers the posterior with room bounds the weights: for a Gaussian posterior and the
#: move's mixture fitted to it, p / q is at most 1.2^d / 0.75 times its mean (2.3 for d = 3).
#: One heavy draw signals a proposal tail lighter than the posterior's, which a Pareto k
#: estimated from 1,000 draws can miss: on a curved ridge (tests/test_posterior.py) one draw
#: carried 9.5 particles at k = 0.31 and put the sd of f0 72 % off; on the benchmark's
#: well-covered cases the heaviest draw carried 1.7-3.7.
IMPORTANCE_MAX_WEIGHT = 4.0
#: Random-walk steps are scaled toward this acceptance rate.
RW_ACCEPT = 0.3
#: MALA steps (``gradient=True``) toward this one (Roberts & Rosenthal 1998: 0.574 is optimal
#: for a Gaussian target in high dimension), from a step of MALA_STEP / d^(1/6) in units of
#: the population's covariance.
MALA_ACCEPT = 0.574
MALA_STEP = 1.2


class Reference:
    """The defensive mixture ``q0 = (1 - prior_share) t(mean, cov, nu) + prior_share prior``
    in the sampler's coordinates (``prior_sample(rng, n)``, ``prior_log_density(X)``: the
    prior's draws and normalized log density there). ``centres`` ``(m, d)`` and ``weights``:
    the t part as a mixture of ``m`` t's of the same shape at those centres (a fit with
    several distinct minima; default one, at ``mean``)."""

    def __init__(
        self, mean, cov, nu, prior_sample, prior_log_density, prior_share, centres=None,
        weights=None,
    ):  # fmt: skip
        self.mean = np.asarray(mean, float)
        self.cov = np.asarray(cov, float)
        self.nu = float(nu)
        self.chol = np.linalg.cholesky(self.cov)
        self.prior_sample = prior_sample
        self.prior_log_density = prior_log_density
        self.prior_share = float(prior_share)
        self.centres = self.mean[None] if centres is None else np.atleast_2d(centres)
        w = np.ones(len(self.centres)) if weights is None else np.asarray(weights, float)
        self.weights = w / np.sum(w)

    def sample(self, rng, n) -> tuple[np.ndarray, np.ndarray]:
        """``n`` draws and whether each came from the prior component."""
        from_prior = rng.uniform(size=n) < self.prior_share
        X = np.empty((n, len(self.mean)))
        m = int(from_prior.sum())
        x = rng.standard_normal((n - m, len(self.mean)))
        g = rng.chisquare(self.nu, (n - m, 1))
        centre = self.mean  # one t: no draw of a component (the random stream as before)
        if len(self.centres) > 1:
            centre = self.centres[rng.choice(len(self.centres), size=n - m, p=self.weights)]
        X[~from_prior] = centre + (x @ self.chol.T) / np.sqrt(g / self.nu)
        if m:
            X[from_prior] = self.prior_sample(rng, m)
        return X, from_prior

    def log_density(self, X) -> np.ndarray:
        X = np.asarray(X, float)
        d = len(self.mean)
        y2 = np.stack(
            [np.sum(np.linalg.solve(self.chol, (X - c).T).T ** 2, axis=1) for c in self.centres]
        )
        log_t = (
            math.lgamma((self.nu + d) / 2)
            - math.lgamma(self.nu / 2)
            - 0.5 * d * math.log(self.nu * math.pi)
            - np.sum(np.log(np.diag(self.chol)))
            + logsumexp(
                np.log(self.weights)[:, None] - 0.5 * (self.nu + d) * np.log1p(y2 / self.nu),
                axis=0,
            )
        )
        if self.prior_share <= 0:
            return log_t
        log_prior = self.prior_log_density(X)
        if self.prior_share >= 1:
            return log_prior
        return np.logaddexp(
            math.log1p(-self.prior_share) + log_t, math.log(self.prior_share) + log_prior
        )


@dataclass
class SMCRun:
    """What :func:`run_smc` returns.

    Attributes:
        draws: ``(populations, particles, d)`` equally weighted draws of the posterior.
        log_density: ``(populations, particles)`` their log posterior densities.
        stages: tempering steps of each population (``b`` reaches 1 after that many).
        moves: Metropolis-Hastings moves of each population (all stages).
        acceptance: mean acceptance rate of the moves (all populations).
        correlation: each population's largest correlation with its positions at the last
            resampling, at the end (below DECORRELATION when the moves mixed).
        khat: Pareto shape of the last tempering step's weights (Vehtari et al. 2024), the
            largest over populations: at most FINAL_KHAT where the reference covered the
            posterior well enough to step to b = 1 with FINAL_ESS.
        log_evidence: each population's estimate of the log marginal likelihood (up to the
            likelihood's constant terms).
        evaluations: log-density evaluations; seconds: wall time.
        from_fallback: whether the particles started from the fallback (the prior) because
            the reference did not cover the posterior.
        final_ess: each population's Kish effective sample size of its last step's weights
            (the resampling makes copies; the moves after it make them independent only as
            far as they mix, so this is a floor on what the population is worth).
        problems: what went wrong (a stage that could not decorrelate the particles).
        importance_only: which populations ended as an importance sample (module
            docstring); their draws hold resampled copies.
        aux: what the evaluations returned beside the log densities, for each draw.
    """

    draws: np.ndarray
    log_density: np.ndarray
    stages: np.ndarray
    moves: np.ndarray
    acceptance: float
    correlation: np.ndarray
    khat: float
    log_evidence: np.ndarray
    evaluations: int
    seconds: float
    problems: list[str] = field(default_factory=list)
    from_fallback: bool = False
    final_ess: np.ndarray | None = None
    importance_only: np.ndarray | None = None
    #: ``(populations, particles, m)``: what ``evaluate`` returned beside each particle's log
    #: density (its columns after the first), carried with the particle.
    aux: np.ndarray | None = None


def _ess(log_w: np.ndarray) -> float:
    """Kish effective sample size of log weights."""
    if not np.any(np.isfinite(log_w)):
        return 0.0
    w = np.exp(log_w - np.max(log_w))
    return float(np.sum(w) ** 2 / np.sum(w * w))


def _next_beta(beta: float, delta: np.ndarray, n: int) -> float:
    """The largest ``b' <= 1`` whose incremental weights ``exp((b' - b) delta)`` keep an ESS
    of at least ``TARGET_ESS n`` (bisection; ``delta = log posterior - log q0``), or 1 where
    the last step's weights keep FINAL_ESS with a Pareto k of at most FINAL_KHAT."""
    target = TARGET_ESS * n
    last = np.where(np.isfinite(delta), (1.0 - beta) * delta, -np.inf)
    ess = _ess(last)
    if ess >= target or (ess >= FINAL_ESS * n and _khat(last) <= FINAL_KHAT):
        return 1.0
    lo, hi = 0.0, 1.0 - beta
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _ess(mid * delta) >= target else (lo, mid)
    return beta + max(lo, 1e-12)


def _systematic(rng, log_w: np.ndarray, n: int) -> np.ndarray:
    w = np.exp(log_w - np.max(log_w))
    cdf = np.cumsum(w / np.sum(w))
    cdf[-1] = 1.0
    return np.searchsorted(cdf, (rng.uniform() + np.arange(n)) / n)


def _certified(log_w: np.ndarray, n: int) -> bool:
    """Whether weights ``log_w`` make their draws an importance sample of the posterior
    (module docstring)."""
    ess = _ess(log_w)
    if ess < IMPORTANCE_ESS * n:
        return False
    w = np.exp(log_w - np.max(log_w))
    heaviest = float(np.max(w) / np.mean(w))
    return heaviest <= IMPORTANCE_MAX_WEIGHT and _khat(log_w) <= IMPORTANCE_KHAT


def _importance_resample(rng, log_w: np.ndarray, n: int) -> np.ndarray:
    """Systematic resampling in random order: no copies side by side (the rank diagnostics
    read each population as a chain)."""
    return rng.permutation(_systematic(rng, log_w, n))


def _khat(log_w: np.ndarray) -> float:
    finite = log_w[np.isfinite(log_w)]
    if finite.size < 20:
        return math.inf
    return pareto_khat(np.exp(finite - np.max(finite)))


def _covariance(X: np.ndarray) -> np.ndarray:
    """The population's covariance, made positive definite (its diagonal, else identity)."""
    d = X.shape[1]
    cov = np.atleast_2d(np.cov(X, rowvar=False)) + 1e-12 * np.eye(d)
    for candidate in (cov, np.diag(np.diag(cov)) + 1e-12 * np.eye(d), np.eye(d) * 1e-4):
        try:
            return np.linalg.cholesky(candidate)
        except np.linalg.LinAlgError:
            continue
    return np.eye(d) * 1e-2


#: The independence proposal: a Gaussian mixture fitted to the population by EM (at most
#: COMPONENTS components, each with its own covariance, so that a curved ridge is covered by
#: straight pieces that follow it), its covariances widened by MIXTURE_WIDTH^2, mixed with a
#: Student-t (WIDE_NU degrees of freedom) on the population's mean and twice its standard
#: deviations (share WIDE). The wide part gives the proposal heavier tails than the target,
#: without which an independence sampler cannot grow a population that is too narrow.
COMPONENTS = 8
MIXTURE_WIDTH = 1.2
EM_ITERATIONS = 40
WIDE = 0.25
WIDE_NU = 3.0


def _gaussian_log_densities(Y, means, chols):
    """``(n, m)`` log densities of the rows of ``Y`` under each Gaussian component."""
    n, d = Y.shape
    out = np.empty((n, len(means)))
    for j, (mean, chol) in enumerate(zip(means, chols, strict=True)):
        z = np.linalg.solve(chol, (Y - mean).T)
        out[:, j] = (
            -0.5 * np.sum(z * z, axis=0)
            - np.sum(np.log(np.diag(chol)))
            - 0.5 * d * math.log(2 * math.pi)
        )
    return out


def _fit_mixture(rng, X: np.ndarray, chol: np.ndarray):
    """A Gaussian mixture fitted to ``X`` by EM (k-means++ starts in the population's
    whitened coordinates, covariances regularized by 1e-4 of the population's): ``(log
    weights, means, Cholesky factors)``."""
    n, d = X.shape
    m = max(1, min(COMPONENTS, n // (10 * (d + 1))))
    W = np.linalg.solve(chol, X.T).T
    centres = [W[rng.integers(n)]]
    for _ in range(1, m):  # k-means++: each new centre far from the others
        d2 = np.min(((W[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
        centres.append(W[rng.choice(n, p=d2 / d2.sum()) if d2.sum() > 0 else rng.integers(n)])
    labels = np.argmin(((W[:, None, :] - np.array(centres)[None]) ** 2).sum(-1), axis=1)
    resp = np.eye(m)[labels]
    floor = 1e-4 * (chol @ chol.T) + 1e-12 * np.eye(d)
    for it in range(EM_ITERATIONS + 1):
        weight = resp.sum(axis=0) + 1e-12
        means = (resp.T @ X) / weight[:, None]
        chols = []
        for j in range(m):
            dev = X - means[j]
            cov = (resp[:, j, None] * dev).T @ dev / weight[j] + floor
            chols.append(np.linalg.cholesky(cov))
        log_w = np.log(weight / n)
        if it == EM_ITERATIONS:
            break
        log_p = _gaussian_log_densities(X, means, chols) + log_w
        resp = np.exp(log_p - logsumexp(log_p, axis=1, keepdims=True))
    return log_w, means, chols


def _independence_proposal(rng, X: np.ndarray, chol: np.ndarray, n: int):
    """``n`` draws of the independence proposal fitted to the particles ``X`` (``chol``: the
    Cholesky factor of the population's covariance), and its log density ``Y -> (n,)``."""
    d = X.shape[1]
    log_w, means, chols = _fit_mixture(rng, X, chol)
    chols = [MIXTURE_WIDTH * c for c in chols]
    mean = X.mean(axis=0)
    component = rng.choice(len(means), size=n, p=np.exp(log_w) / np.exp(log_w).sum())
    Z = rng.standard_normal((n, d))
    Xp = np.empty((n, d))
    for j in range(len(means)):
        pick = component == j
        Xp[pick] = means[j] + Z[pick] @ chols[j].T
    wide = rng.uniform(size=n) < WIDE
    g = rng.chisquare(WIDE_NU, (n, 1))
    Xp[wide] = (mean + 2.0 * (Z @ chol.T) / np.sqrt(g / WIDE_NU))[wide]
    log_det = float(np.sum(np.log(np.diag(chol))))

    def log_q(Y):
        mixture = logsumexp(_gaussian_log_densities(Y, means, chols) + log_w, axis=1)
        y = np.linalg.solve(chol, (Y - mean).T).T / 2.0
        t = (
            math.lgamma((WIDE_NU + d) / 2)
            - math.lgamma(WIDE_NU / 2)
            - 0.5 * d * math.log(WIDE_NU * math.pi)
            - d * math.log(2.0)
            - log_det
            - 0.5 * (WIDE_NU + d) * np.log1p(np.sum(y * y, axis=1) / WIDE_NU)
        )
        return np.logaddexp(math.log1p(-WIDE) + mixture, math.log(WIDE) + t)

    return Xp, log_q


#: A MALA step's drift is at most this many proposal standard deviations long (in the
#: population's whitened coordinates): where the gradient is steep (a particle far out in a
#: thin ridge's tail) the full drift throws every proposal away and the particle never moves
#: (seen: a curved ridge's sd 30 % wide); truncated, the step is a random walk there
#: (Roberts & Tweedie 1996, MALTA). The drift is a fixed function of the position: the
#: Metropolis-Hastings ratio stays exact.
MALA_MAX_DRIFT = 2.0


def _langevin_drift(gradient, chol, h) -> np.ndarray:
    """``h^2 / 2 Sigma grad`` (``Sigma = chol chol^T``), each row's length in whitened
    coordinates capped at :data:`MALA_MAX_DRIFT` ``h``."""
    whitened = 0.5 * h * h * (np.asarray(gradient) @ chol)
    length = np.linalg.norm(whitened, axis=1, keepdims=True)
    cap = MALA_MAX_DRIFT * h
    whitened = whitened * np.minimum(1.0, cap / np.maximum(length, 1e-300))
    return whitened @ chol.T


def _tempered_gradient(beta: float, grad_posterior, reference: Reference, X) -> np.ndarray:
    """Gradient of ``ln pi_b = (1 - b) ln q0 + b ln posterior`` at ``X`` (the reference's by
    central differences; a non-finite entry as 0: that particle's step is a random walk)."""
    g = beta * np.asarray(grad_posterior, float)
    if beta < 1.0:
        g = g + (1.0 - beta) * _numerical_gradient(reference.log_density, X)
    return np.where(np.isfinite(g), g, 0.0)


def _numerical_gradient(f, X) -> np.ndarray:
    """Central differences of ``f: (n, d) -> (n,)`` at the rows of ``X``."""
    X = np.asarray(X, float)
    out = np.empty_like(X)
    for j in range(X.shape[1]):
        h = 1e-5 * (1.0 + np.abs(X[:, j]))
        up, down = X.copy(), X.copy()
        up[:, j] += h
        down[:, j] -= h
        out[:, j] = (np.asarray(f(up)) - np.asarray(f(down))) / (2 * h)
    return out


def _correlation(anchor: np.ndarray, X: np.ndarray) -> float:
    """Largest correlation over coordinates between positions ``anchor`` and ``X`` (1 where a
    coordinate does not vary: nothing moved)."""
    worst = 0.0
    for j in range(X.shape[1]):
        a, b = anchor[:, j], X[:, j]
        sa, sb = np.std(a), np.std(b)
        if sa == 0 or sb == 0:
            return 1.0
        worst = max(worst, abs(float(np.mean((a - a.mean()) * (b - b.mean())) / (sa * sb))))
    return worst


def _rank_correlation(anchor: np.ndarray, X: np.ndarray) -> float:
    """:func:`_correlation` of the positions' ranks (Spearman's): what the verdict on moves
    that reached :data:`MAX_MOVES` uses. A coordinate with a heavy tail (a posterior against
    a bound, whose logit runs far out) keeps a Pearson correlation of ~0.2 through a few
    tail particles that stay in the tail (measured: 0.21 with every particle moved, rank
    correlation 0.01); copies that have not moved apart keep both."""
    return _correlation(rankdata(anchor, axis=0), rankdata(X, axis=0))


def _copies_stuck(anchor: np.ndarray, X: np.ndarray) -> bool:
    """Whether positions ``X`` (moved from ``anchor``, the last resampling's) are still the
    resampled copies: the correlation of ranks above :data:`DECORRELATION` and above
    :data:`STUCK_SE` standard errors of the correlation of independent positions."""
    limit = max(DECORRELATION, STUCK_SE / math.sqrt(len(X)))
    return _rank_correlation(anchor, X) >= limit


def run_smc(
    evaluate: Callable[[np.ndarray], np.ndarray],
    reference: Reference,
    *,
    populations: int,
    particles: int,
    rng: np.random.Generator,
    progress: bool = False,
    description: str = "posterior (SMC)",
    fallback: Reference | None = None,
    gradient: bool = False,
) -> SMCRun:
    """Independent SMC runs (``populations`` of ``particles`` each) of the posterior whose
    log density ``evaluate(X (n, d)) -> (n,)`` gives (up to a constant; ``-inf`` or NaN where
    it is zero), from ``reference``; all populations' evaluations are one call per move.
    ``evaluate`` may return ``(n, 1 + m)``: the log density, then ``m`` numbers that each
    particle carries with it (``SMCRun.aux``: the noise groups' residual sums, say).
    ``gradient``: the last ``d`` of those are the log density's gradient in ``x``; the local
    moves are then MALA moves (a Langevin step along the gradient of ``pi_b``, preconditioned
    by the population's covariance, its step adapted toward :data:`MALA_ACCEPT`) instead of a
    random walk.

    ``fallback`` (the prior): used instead of ``reference`` unless the importance weights of
    all the reference's draws pooled pass the test of a direct step to ``b = 1`` (ESS at
    least FINAL_ESS of the draws, Pareto k at most FINAL_KHAT), i.e. unless the reference
    already covers the posterior. A reference placed by a Gaussian approximation that fails
    it misses a part of the posterior (the far end of a curved ridge, say) that no move can be
    relied on to find; tempering from the prior finds it, at the cost of more steps."""
    t0 = time.perf_counter()
    K, N = populations, particles
    d = len(reference.mean)
    bar = tqdm(desc=description, unit="point", disable=not progress, file=sys.stderr, leave=False)
    evaluations = 0

    def run(X):
        """Log densities ``(n,)`` and the carried numbers ``(n, m)`` of the rows of ``X``."""
        nonlocal evaluations
        out = np.asarray(evaluate(X), float)
        evaluations += len(X)
        bar.update(len(X))
        if out.ndim == 1:
            out = out[:, None]
        return np.nan_to_num(out[:, 0], nan=-np.inf), out[:, 1:]

    X, from_prior = reference.sample(rng, K * N)
    # The prior component's draws reach stiff corners of the prior whose impacts take many
    # steps; evaluated apart, they do not hold up the batches of the rest.
    order = np.argsort(from_prior, kind="stable")
    lp_flat = np.empty(K * N)
    lp_flat[order], aux_sorted = run(X[order])
    aux_flat = np.empty_like(aux_sorted)
    aux_flat[order] = aux_sorted
    X = X.reshape(K, N, d)
    lp = lp_flat.reshape(K, N)
    aux = aux_flat.reshape(K, N, -1)
    lq = np.array(reference.log_density(X.reshape(-1, d)), float).reshape(K, N)
    delta = (lp - lq).reshape(-1)
    delta = np.where(np.isfinite(delta), delta, -np.inf)
    covered = _ess(delta) >= FINAL_ESS * K * N and _khat(delta) <= FINAL_KHAT
    if fallback is not None and not covered:
        reference = fallback
        X = reference.sample(rng, K * N)[0]
        lp, aux = run(X)
        lp, aux = lp.reshape(K, N), aux.reshape(K, N, -1)
        X = X.reshape(K, N, d)
        lq = np.array(reference.log_density(X.reshape(-1, d)), float).reshape(K, N)
    if not np.any(np.isfinite(lp)):
        bar.close()
        raise ValueError("the log posterior is -inf or NaN at every draw of the reference")

    beta = np.zeros(K)
    stages = np.zeros(K, int)
    moves = np.zeros(K, int)
    log_evidence = np.zeros(K)
    final_ess = np.zeros(K)
    group = np.tile(np.arange(N) % 2, (K, 1))
    anchor = X.copy()
    moved = np.zeros(K, int)  # moves since the last resampling
    reweight = np.ones(K, bool)
    finished = np.zeros(K, bool)
    rw_scale = np.full(K, MALA_STEP / d ** (1 / 6) if gradient else 2.38 / math.sqrt(d))
    local_accept = MALA_ACCEPT if gradient else RW_ACCEPT
    correlation = np.ones(K)
    accepted = total = 0
    khat = 0.0
    stuck: list[str] = []
    importance_only = np.zeros(K, bool)

    while not np.all(finished):
        for k in np.flatnonzero(~finished):
            if not reweight[k]:
                continue
            delta = lp[k] - lq[k]
            new = _next_beta(beta[k], delta, N)
            log_w = (new - beta[k]) * delta
            log_w = np.where(np.isfinite(log_w), log_w, -np.inf)
            log_evidence[k] += logsumexp(log_w) - math.log(N)
            final_ess[k] = _ess(log_w)
            if new >= 1.0:
                khat = max(khat, _khat(log_w))
                if stages[k] == 0 and _certified(log_w, N):
                    pick = _importance_resample(rng, log_w, N)
                    X[k], lp[k], lq[k], aux[k] = X[k][pick], lp[k][pick], lq[k][pick], aux[k][pick]
                    beta[k], stages[k], reweight[k] = 1.0, 1, False
                    importance_only[k] = finished[k] = True
                    correlation[k] = math.nan
                    continue
            pick = _systematic(rng, log_w, N)
            group[k] = rng.permutation(N)[pick] % 2  # the copies of one particle together
            X[k], lp[k], lq[k], aux[k] = X[k][pick], lp[k][pick], lq[k][pick], aux[k][pick]
            beta[k], stages[k] = new, stages[k] + 1
            anchor[k], moved[k], reweight[k] = X[k].copy(), 0, False
        active = np.flatnonzero(~finished)
        if active.size == 0:
            break

        # One move of every active population: proposals, one batch of evaluations.
        proposals, log_ratio, log_proposal, langevin = [], [], [], []
        for k in active:
            chol = _covariance(X[k])
            if moved[k] % 2 == 0:  # independence proposal (see _independence_proposal)
                # Each half of the particles moves by a proposal fitted to the other half: a
                # proposal fitted to the particles it moves is densest where they already are
                # (the mixture overfits them), which favours moves away and widens the result
                # (by 3 % of the sd on the grid cases, before this split).
                Xp, ratio, own = np.empty((N, d)), np.empty(N), np.empty(N)
                for half in (0, 1):
                    moving = group[k] == half
                    if not moving.any():
                        continue
                    others = X[k][~moving] if (~moving).sum() > 2 * d else X[k]
                    draws, log_q = _independence_proposal(
                        rng, others, _covariance(others), int(moving.sum())
                    )
                    Xp[moving] = draws
                    own[moving] = log_q(draws)
                    ratio[moving] = log_q(X[k][moving]) - own[moving]
                log_ratio.append(ratio)
                log_proposal.append(own)
            elif gradient:  # MALA (its proposal ratio needs the gradient at Xp: after the run)
                h = rw_scale[k]
                drift = _tempered_gradient(beta[k], aux[k][:, -d:], reference, X[k])
                forward = X[k] + _langevin_drift(drift, chol, h)
                Xp = forward + h * rng.standard_normal((N, d)) @ chol.T
                log_ratio.append(None)
                log_proposal.append(None)
                langevin.append((k, forward, chol, h))
            else:  # random walk
                Xp = X[k] + rw_scale[k] * rng.standard_normal((N, d)) @ chol.T
                log_ratio.append(np.zeros(N))
                log_proposal.append(None)
            proposals.append(Xp)
            if len(langevin) < len(proposals):
                langevin.append(None)
        lp_new, aux_new = run(np.concatenate(proposals))
        lp_new, aux_new = lp_new.reshape(len(active), N), aux_new.reshape(len(active), N, -1)
        for i, k in enumerate(active):
            Xp = proposals[i]
            lq_new = np.array(reference.log_density(Xp), float)
            if langevin[i] is not None:
                _, forward, chol, h = langevin[i]
                drift = _tempered_gradient(beta[k], aux_new[i][:, -d:], reference, Xp)
                backward = Xp + _langevin_drift(drift, chol, h)
                there = np.linalg.solve(chol, (Xp - forward).T)
                back = np.linalg.solve(chol, (X[k] - backward).T)
                ratio = (np.sum(there**2, axis=0) - np.sum(back**2, axis=0)) / (2 * h * h)
                log_ratio[i] = np.where(np.isfinite(ratio), ratio, -np.inf)
            if beta[k] >= 1.0 and moved[k] == 0 and log_proposal[i] is not None:
                # The proposals as an importance sample of the posterior (module docstring).
                log_w = np.where(np.isfinite(lp_new[i]), lp_new[i] - log_proposal[i], -np.inf)
                if _certified(log_w, N):
                    pick = _importance_resample(rng, log_w, N)
                    X[k], lp[k], lq[k] = Xp[pick], lp_new[i][pick], lq_new[pick]
                    aux[k] = aux_new[i][pick]
                    final_ess[k], moves[k], correlation[k] = _ess(log_w), moves[k] + 1, math.nan
                    importance_only[k] = finished[k] = True
                    continue
            log_alpha = beta[k] * (lp_new[i] - lp[k]) + (1 - beta[k]) * (lq_new - lq[k])
            log_alpha = np.where(np.isfinite(lp_new[i]), log_alpha + log_ratio[i], -np.inf)
            take = np.log(rng.uniform(size=N)) < log_alpha
            X[k][take], lp[k][take], lq[k][take] = Xp[take], lp_new[i][take], lq_new[take]
            aux[k][take] = aux_new[i][take]
            rate = float(np.mean(take))
            accepted, total = accepted + int(take.sum()), total + N
            if moved[k] % 2 == 1:
                rw_scale[k] = float(np.clip(rw_scale[k] * math.exp(rate - local_accept), 0.02, 5.0))
            moved[k] += 1
            moves[k] += 1
            correlation[k] = _correlation(anchor[k], X[k])
            limit = DECORRELATION if beta[k] >= 1.0 else STAGE_DECORRELATION
            most = MAX_MOVES if beta[k] >= 1.0 else MAX_STAGE_MOVES
            if correlation[k] < limit or moved[k] >= most:
                if correlation[k] >= limit and beta[k] >= 1.0 and _copies_stuck(anchor[k], X[k]):
                    ranked = _rank_correlation(anchor[k], X[k])
                    stuck.append(
                        f"population {k + 1}: the moves left a correlation of "
                        f"{correlation[k]:.2f} (of ranks: {ranked:.2f}) with their positions "
                        f"at the last resampling after {MAX_MOVES} moves (the copies it made "
                        "have not moved apart)"
                    )
                if beta[k] >= 1.0:
                    finished[k] = True
                else:
                    reweight[k] = True
        bar.set_postfix(b=f"{np.min(beta):.3g}", refresh=False)
    bar.close()
    return SMCRun(
        draws=X,
        log_density=lp,
        stages=stages,
        moves=moves,
        acceptance=accepted / total if total else math.nan,
        correlation=correlation,
        khat=khat,
        log_evidence=log_evidence,
        evaluations=evaluations,
        seconds=time.perf_counter() - t0,
        problems=stuck,
        from_fallback=reference is fallback,
        final_ess=final_ess,
        importance_only=importance_only,
        aux=aux,
    )
