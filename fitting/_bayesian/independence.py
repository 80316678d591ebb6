"""The independence sampler (``sampler="independence"``): independence Metropolis with a
Student-t proposal placed by the fit and a pilot, every proposal of every chain evaluated in
a few large batches; right only where the proposal covers the posterior (Pareto k).
"""

from __future__ import annotations

import time

import numpy as np

from . import diagnostics
from .programs import BLOCK, _blocks, _progress_bar
from .result import MAX_KHAT, MAX_RHAT

#: Pilot draws that place the independence sampler's proposal.
PILOT = 1000


#: Proposal: Student-t with this many degrees of freedom, covariance inflated by this factor.
PROPOSAL_NU = 7.0


PROPOSAL_INFLATION = 1.15


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


def _normalized(log_w):
    w = np.exp(log_w - np.max(log_w))
    return w / np.sum(w)
