"""Sequential Monte Carlo on the posterior (``sampler="smc"``, the default): its reference
(a t on the fit, mixed with the prior, covering the fit's other minima), the runs (extended
while the populations disagree), the noise factors drawn afterwards, and the verdict.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np

from jaximpact._engine.devices import engine_jit

from .._least_squares.transforms import dphys_du, to_physical
from .likelihood import (
    draw_noise_factors,
)
from .programs import BLOCK, _blocks, _x_log_density
from .result import MAX_RHAT, MIN_ESS, PosteriorResult, _posterior_result, _summarize
from .smc import IMPORTANCE_KHAT, IMPORTANCE_MAX_WEIGHT, Reference, SMCRun, run_smc
from .space import SamplingSpace

#: SMC's reference: a Student-t with REFERENCE_NU degrees of freedom on the fit, its standard
#: deviations REFERENCE_WIDTH times the fit's (at most the prior's), mixed with the prior
#: (share PRIOR_SHARE).
REFERENCE_NU = 4.0


REFERENCE_WIDTH = 1.3


PRIOR_SHARE = 0.05


SMC_EXTENSIONS = 2


#: A fit's other minimum joins the reference where its posterior density is at least this
#: fraction of the mixture's weight (its share: its density at the minimum over the sum).
MIN_MINIMUM_SHARE = 1e-3


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
    result.reason = _smc_reason(run, sampler, minima_note, gradient)
    _describe_noise(result, integrated, all_noise)
    return result


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


def _smc_reason(run: SMCRun, sampler: str, minima_note: str, gradient: bool) -> str:
    """What ran, for ``PosteriorResult.reason``: the populations, where they started, the
    tempering steps and moves, how many ended as importance samples."""
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
    return (
        f"SMC ({'the default' if sampler == 'auto' else 'as asked'}; values only, no Gaussian "
        f"shape assumed): {run.draws.shape[0]} independent populations of "
        f"{run.draws.shape[1]} particles, {start}{minima_note}; {steps}"
        + ("; local moves: MALA (the log density's gradient)" if gradient else "")
    )
