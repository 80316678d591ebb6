"""What a posterior run returns (:class:`PosteriorResult`) and how it is judged
(R-hat, ESS, divergences).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from .._least_squares.fit import FitResult
from .._least_squares.objective import Objective
from .._least_squares.transforms import to_physical
from . import diagnostics
from .priors import Prior

#: Largest Pareto shape of the importance weights at which the independence sampler's
#: proposal is trusted (Vehtari et al. 2024, "Pareto smoothed importance sampling").
MAX_KHAT = 0.7
#: A run with a larger split R-hat for any parameter is not called converged.
MAX_RHAT = 1.01


#: SMC: a run is called converged only with every bulk and tail ESS at least MIN_ESS and every
#: rank-normalized R-hat (over the independent populations) at most MAX_RHAT; while either
#: fails, ``chains`` more populations are run, up to SMC_EXTENSIONS times.
MIN_ESS = 400


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
