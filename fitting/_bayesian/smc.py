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
from .smc_moves import _independence_proposal, _langevin_drift, _tempered_gradient

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
    counter = [0]

    def run(X):
        """Log densities ``(n,)`` and the carried numbers ``(n, m)`` of the rows of ``X``."""
        out = np.asarray(evaluate(X), float)
        counter[0] += len(X)
        bar.update(len(X))
        if out.ndim == 1:
            out = out[:, None]
        return np.nan_to_num(out[:, 0], nan=-np.inf), out[:, 1:]

    try:
        pop, reference = _first_draws(run, reference, fallback, K, N, rng)
    except ValueError:
        bar.close()
        raise
    pop.rw_scale[:] = MALA_STEP / d ** (1 / 6) if gradient else 2.38 / math.sqrt(d)
    local_accept = MALA_ACCEPT if gradient else RW_ACCEPT
    while not np.all(pop.finished):
        for k in np.flatnonzero(~pop.finished):
            if pop.reweight[k]:
                _reweight(pop, k, rng)
        active = np.flatnonzero(~pop.finished)
        if active.size == 0:
            break
        # One move of every active population: proposals, one batch of evaluations.
        proposed = [_propose(pop, k, rng, reference, gradient) for k in active]
        lp_new, aux_new = run(np.concatenate([p.X for p in proposed]))
        lp_new, aux_new = lp_new.reshape(len(active), N), aux_new.reshape(len(active), N, -1)
        for i, k in enumerate(active):
            _accept(pop, k, proposed[i], lp_new[i], aux_new[i], rng, reference, local_accept)
        bar.set_postfix(b=f"{np.min(pop.beta):.3g}", refresh=False)
    bar.close()
    return SMCRun(
        draws=pop.X, log_density=pop.lp, stages=pop.stages, moves=pop.moves,
        acceptance=pop.accepted / pop.total if pop.total else math.nan,
        correlation=pop.correlation, khat=pop.khat, log_evidence=pop.log_evidence,
        evaluations=counter[0], seconds=time.perf_counter() - t0, problems=pop.stuck,
        from_fallback=reference is fallback, final_ess=pop.final_ess,
        importance_only=pop.importance_only, aux=pop.aux,
    )  # fmt: skip


@dataclass
class _Populations:
    """The state of :func:`run_smc`'s ``K`` populations of ``N`` particles: positions ``X``
    ``(K, N, d)``, their log posterior ``lp`` and reference ``lq`` densities and carried
    numbers ``aux``, and per population its temperature, counts and verdicts."""

    X: np.ndarray
    lp: np.ndarray
    lq: np.ndarray
    aux: np.ndarray

    def __post_init__(self):
        K, N = self.lp.shape
        self.beta = np.zeros(K)
        self.stages = np.zeros(K, int)
        self.moves = np.zeros(K, int)
        self.log_evidence = np.zeros(K)
        self.final_ess = np.zeros(K)
        self.group = np.tile(np.arange(N) % 2, (K, 1))
        self.anchor = self.X.copy()
        self.moved = np.zeros(K, int)  # moves since the last resampling
        self.reweight = np.ones(K, bool)
        self.finished = np.zeros(K, bool)
        self.rw_scale = np.zeros(K)
        self.correlation = np.ones(K)
        self.accepted = self.total = 0
        self.khat = 0.0
        self.stuck: list[str] = []
        self.importance_only = np.zeros(K, bool)

    def take(self, k, pick, X=None, lp=None, lq=None, aux=None):
        """Population ``k``'s particles become rows ``pick`` of its own (or of the given)."""
        self.X[k] = (self.X[k] if X is None else X)[pick]
        self.lp[k] = (self.lp[k] if lp is None else lp)[pick]
        self.lq[k] = (self.lq[k] if lq is None else lq)[pick]
        self.aux[k] = (self.aux[k] if aux is None else aux)[pick]


def _first_draws(run, reference, fallback, K, N, rng):
    """The populations drawn from ``reference`` (or from ``fallback`` where the reference's
    pooled importance weights fail the test of a direct step to b = 1: see :func:`run_smc`),
    and the reference they came from."""
    X, from_prior = reference.sample(rng, K * N)
    d = X.shape[1]
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
        raise ValueError("the log posterior is -inf or NaN at every draw of the reference")
    return _Populations(X, lp, lq, aux), reference


def _reweight(pop: _Populations, k: int, rng) -> None:
    """Population ``k``'s next tempering step: reweight to the next ``b``, then resample (or,
    at ``b = 1`` straight from the reference with certified weights, end it as an importance
    sample)."""
    N = pop.lp.shape[1]
    delta = pop.lp[k] - pop.lq[k]
    new = _next_beta(pop.beta[k], delta, N)
    log_w = (new - pop.beta[k]) * delta
    log_w = np.where(np.isfinite(log_w), log_w, -np.inf)
    pop.log_evidence[k] += logsumexp(log_w) - math.log(N)
    pop.final_ess[k] = _ess(log_w)
    if new >= 1.0:
        pop.khat = max(pop.khat, _khat(log_w))
        if pop.stages[k] == 0 and _certified(log_w, N):
            pop.take(k, _importance_resample(rng, log_w, N))
            pop.beta[k], pop.stages[k], pop.reweight[k] = 1.0, 1, False
            pop.importance_only[k] = pop.finished[k] = True
            pop.correlation[k] = math.nan
            return
    pick = _systematic(rng, log_w, N)
    pop.group[k] = rng.permutation(N)[pick] % 2  # the copies of one particle together
    pop.take(k, pick)
    pop.beta[k], pop.stages[k] = new, pop.stages[k] + 1
    pop.anchor[k], pop.moved[k], pop.reweight[k] = pop.X[k].copy(), 0, False


@dataclass
class _Proposal:
    """One population's proposals ``X``, the log proposal ratio ``q(x | x') / q(x' | x)``
    (None for MALA until the gradient at ``X`` is known), the independence proposal's own
    log density at ``X`` (None for local moves) and MALA's ``(forward, chol, h)``."""

    X: np.ndarray
    log_ratio: np.ndarray | None
    log_proposal: np.ndarray | None = None
    langevin: tuple | None = None


def _propose(pop: _Populations, k: int, rng, reference: Reference, gradient: bool) -> _Proposal:
    """Population ``k``'s proposals: an independence proposal on even moves, else a random
    walk (or a MALA step where ``gradient``), scaled by the population's covariance."""
    Xk = pop.X[k]
    N, d = Xk.shape
    chol = _covariance(Xk)
    if pop.moved[k] % 2 == 0:  # independence proposal (see _independence_proposal)
        # Each half of the particles moves by a proposal fitted to the other half: a
        # proposal fitted to the particles it moves is densest where they already are
        # (the mixture overfits them), which favours moves away and widens the result
        # (by 3 % of the sd on the grid cases, before this split).
        Xp, ratio, own = np.empty((N, d)), np.empty(N), np.empty(N)
        for half in (0, 1):
            moving = pop.group[k] == half
            if not moving.any():
                continue
            others = Xk[~moving] if (~moving).sum() > 2 * d else Xk
            draws, log_q = _independence_proposal(
                rng, others, _covariance(others), int(moving.sum())
            )
            Xp[moving] = draws
            own[moving] = log_q(draws)
            ratio[moving] = log_q(Xk[moving]) - own[moving]
        return _Proposal(Xp, ratio, own)
    h = pop.rw_scale[k]
    if gradient:  # MALA (its proposal ratio needs the gradient at Xp: after the run)
        drift = _tempered_gradient(pop.beta[k], pop.aux[k][:, -d:], reference, Xk)
        forward = Xk + _langevin_drift(drift, chol, h)
        Xp = forward + h * rng.standard_normal((N, d)) @ chol.T
        return _Proposal(Xp, None, langevin=(forward, chol, h))
    return _Proposal(Xk + h * rng.standard_normal((N, d)) @ chol.T, np.zeros(N))


def _accept(pop, k, prop: _Proposal, lp_new, aux_new, rng, reference, local_accept) -> None:
    """Population ``k``'s Metropolis-Hastings step on its proposals' log densities ``lp_new``
    (or, at ``b = 1`` on the first move after resampling, the proposals kept as a certified
    importance sample), the local step's scale adapted, and the verdict on its moves."""
    N, d = prop.X.shape
    Xp, log_ratio = prop.X, prop.log_ratio
    lq_new = np.array(reference.log_density(Xp), float)
    if prop.langevin is not None:
        forward, chol, h = prop.langevin
        drift = _tempered_gradient(pop.beta[k], aux_new[:, -d:], reference, Xp)
        backward = Xp + _langevin_drift(drift, chol, h)
        there = np.linalg.solve(chol, (Xp - forward).T)
        back = np.linalg.solve(chol, (pop.X[k] - backward).T)
        ratio = (np.sum(there**2, axis=0) - np.sum(back**2, axis=0)) / (2 * h * h)
        log_ratio = np.where(np.isfinite(ratio), ratio, -np.inf)
    if pop.beta[k] >= 1.0 and pop.moved[k] == 0 and prop.log_proposal is not None:
        # The proposals as an importance sample of the posterior (module docstring).
        log_w = np.where(np.isfinite(lp_new), lp_new - prop.log_proposal, -np.inf)
        if _certified(log_w, N):
            pop.take(k, _importance_resample(rng, log_w, N), Xp, lp_new, lq_new, aux_new)
            pop.final_ess[k], pop.moves[k] = _ess(log_w), pop.moves[k] + 1
            pop.correlation[k] = math.nan
            pop.importance_only[k] = pop.finished[k] = True
            return
    b = pop.beta[k]
    log_alpha = b * (lp_new - pop.lp[k]) + (1 - b) * (lq_new - pop.lq[k])
    log_alpha = np.where(np.isfinite(lp_new), log_alpha + log_ratio, -np.inf)
    take = np.log(rng.uniform(size=N)) < log_alpha
    pop.X[k][take], pop.lp[k][take], pop.lq[k][take] = Xp[take], lp_new[take], lq_new[take]
    pop.aux[k][take] = aux_new[take]
    rate = float(np.mean(take))
    pop.accepted, pop.total = pop.accepted + int(take.sum()), pop.total + N
    if pop.moved[k] % 2 == 1:
        pop.rw_scale[k] = float(np.clip(pop.rw_scale[k] * math.exp(rate - local_accept), 0.02, 5.0))
    pop.moved[k] += 1
    pop.moves[k] += 1
    _judge_moves(pop, k)


def _judge_moves(pop: _Populations, k: int) -> None:
    """After a move: population ``k`` done with this stage once its positions decorrelated
    from the last resampling's (or after the stage's most moves, said where the copies are
    still stuck at b = 1); then the next reweighting, or the end at b = 1."""
    pop.correlation[k] = _correlation(pop.anchor[k], pop.X[k])
    final = pop.beta[k] >= 1.0
    limit = DECORRELATION if final else STAGE_DECORRELATION
    most = MAX_MOVES if final else MAX_STAGE_MOVES
    if pop.correlation[k] < limit or pop.moved[k] >= most:
        if pop.correlation[k] >= limit and final and _copies_stuck(pop.anchor[k], pop.X[k]):
            ranked = _rank_correlation(pop.anchor[k], pop.X[k])
            pop.stuck.append(
                f"population {k + 1}: the moves left a correlation of "
                f"{pop.correlation[k]:.2f} (of ranks: {ranked:.2f}) with their positions "
                f"at the last resampling after {MAX_MOVES} moves (the copies it made "
                "have not moved apart)"
            )
        if final:
            pop.finished[k] = True
        else:
            pop.reweight[k] = True
