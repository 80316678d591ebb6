"""Reports of a posterior: JSON fields, summary lines, corner plot, predictive band, draws file."""

from __future__ import annotations

import math
import textwrap
import warnings
from pathlib import Path

import numpy as np

from jaximpact._io.paths import atomic_output

from .._data import OBSERVABLES
from .._least_squares.objective import FitError
from .._least_squares.report import (
    _atomic_savefig,
    _num,
    _two_lines,
    observable_label,
    parameter_label,
)
from .posterior import posterior_predictive
from .result import PosteriorResult

__all__ = [
    "plot_corner",
    "plot_predictive",
    "posterior_fields",
    "posterior_summary",
    "write_draws",
]


def posterior_fields(result: PosteriorResult) -> dict:
    """What a posterior adds to the fit's JSON: ``{"params": {name: {"posterior": {...}}},
    "posterior": {...}}`` (see :func:`add_to_result_dict`)."""
    return {
        "status": result.status,
        "converged": bool(result.converged),
        "problems": list(result.problems),
        "likelihood": result.likelihood,
        "nu": result.nu if result.likelihood == "student-t" else None,
        "priors": {n: p.describe() for n, p in result.priors.items()},
        "chains": int(result.chains),
        "draws_per_chain": int(result.draws.shape[1]),
        "sampler": result.sampler,
        "reason": result.reason,
        "log_evidence": _num(result.log_evidence),
        "pareto_k": _num(result.khat),
        "divergences": int(result.divergences),
        "acceptance": _num(result.acceptance),
        "step_size": [_num(s) for s in np.atleast_1d(result.step_size)],
        "evaluations": int(result.evaluations),
        "correlation": [[_num(c) for c in row] for row in result.correlation],
        "noise": {n: _stats(result.summary[n]) for n in result.noise},
        "noise_treatment": result.noise_treatment,
        "timings": {k: round(float(v), 4) for k, v in result.timings.items()},
    }


_SAMPLER_NAMES = {
    "independence": "independence Metropolis",
    "hmc": "HMC",
    "smc": "sequential Monte Carlo",
}


def _stats(s: dict) -> dict:
    keys = ("mean", "median", "sd", "q05", "q95", "rhat", "ess", "ess_tail")
    return {k: _num(s[k]) for k in keys}


def add_to_result_dict(d: dict, result: PosteriorResult) -> dict:
    """The fit's JSON dict ``d`` with ``posterior`` beside each parameter's ``value`` and
    ``stderr``, and a top-level ``posterior`` section (diagnostics, correlation of the
    draws)."""
    for n in result.params:
        d["params"][n]["posterior"] = _stats(result.summary[n])
    d["posterior"] = posterior_fields(result)
    return d


def posterior_summary(result: PosteriorResult) -> str:
    """Readable lines: status, each parameter's posterior next to its least-squares value."""
    units = ("populations", "particles") if result.sampler == "smc" else ("chains", "draws")
    lines = [
        f"posterior ({result.likelihood}; {result.chains} {units[0]} x {result.draws.shape[1]} "
        f"{units[1]}, {_SAMPLER_NAMES[result.sampler]}): "
        + ("converged" if result.converged else "NOT CONVERGED"),
    ]
    if result.reason:
        lines.append(f"  sampler: {result.reason}")
    for problem in result.problems:
        lines.append(f"  because {problem}")
    names = list(result.params) + list(result.noise)
    width = max(len(n) for n in names)
    lines.append("  name".ljust(width + 2) + "    median        90 % interval        R-hat   ESS")
    for n in names:
        s = result.summary[n]
        lines.append(
            f"  {n.ljust(width)} {s['median']:10.5g}  [{s['q05']:10.5g}, {s['q95']:10.5g}]  "
            f"{s['rhat']:.4f}  {s['ess']:6.0f}"
        )
    if len(result.params) > 1:
        lines.append("correlation of the draws:")
        for n, row in zip(result.params, result.correlation, strict=True):
            lines.append(f"  {n.ljust(width)} " + " ".join(f"{c:+.3f}" for c in row))
    if result.sampler == "independence":
        how = f"Pareto k {result.khat:.2f}; {result.evaluations} log-density evaluations"
    elif result.sampler == "smc":
        steps = int(np.max(result.stages))
        how = (
            f"{result.chains} independent populations, up to {steps} tempering "
            f"step{'' if steps == 1 else 's'}; {result.evaluations} log-density evaluations"
        )
    else:
        how = f"divergences {result.divergences}; {result.evaluations} gradient evaluations"
    accept = (
        f"mean acceptance {result.acceptance:.2f}"
        if math.isfinite(result.acceptance)
        else "no Metropolis moves (importance samples)"
    )
    lines.append(
        f"{how}; {accept}; time " + ", ".join(f"{k} {v:.1f} s" for k, v in result.timings.items())
    )
    return "\n".join(lines)


def import_arviz(what: str = "--draws"):
    """arviz, imported quietly (it warns about its own coming refactor on import); ``what``
    needs it (named in the error).

    Raises:
        FitError: arviz is not installed (``pip install "jaximpact[posterior]"``).
    """
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            import arviz
    except ImportError:
        raise FitError(f'{what} needs arviz: pip install "jaximpact[posterior]"') from None
    return arviz


def write_draws(path, result: PosteriorResult) -> None:
    """Write the draws as ArviZ InferenceData (netCDF), atomically.

    Raises:
        FitError: arviz is not installed (``pip install "jaximpact[posterior]"``).
    """
    try:
        import arviz as az
    except ImportError:
        raise FitError('--draws needs arviz: pip install "jaximpact[posterior]"') from None
    posterior = {n: result.draws[..., i] for i, n in enumerate(result.params)}
    posterior.update({n: result.noise_draws[..., j] for j, n in enumerate(result.noise)})
    with warnings.catch_warnings():
        # arviz guesses that more chains than draws is a transposed array; here the shape is
        # (chains, draws) by construction (short SMC runs extended to many populations).
        warnings.filterwarnings("ignore", message="More chains", category=UserWarning)
        data = az.from_dict(
            posterior=posterior,
            sample_stats={"lp": result.log_density},
            attrs={"likelihood": result.likelihood, "status": result.status},
        )
    with atomic_output(path, "draws file") as temp:
        data.to_netcdf(str(temp))


def read_draws(path, names) -> np.ndarray:
    """``(draws, p)`` draws of ``names`` from an ArviZ netCDF file (as :func:`write_draws`
    writes), all chains together.

    Raises:
        FitError: arviz missing, not a draws file, or no draws of a name.
    """
    from jaximpact._io.paths import check_readable

    check_readable(path, "draws file")
    az = import_arviz()
    try:
        posterior = az.from_netcdf(str(path)).posterior
    except Exception as err:  # not netCDF, or no posterior group
        raise FitError(f"{path}: not a draws file with a posterior group ({err})") from None
    missing = [n for n in names if n not in posterior]
    if missing:
        raise FitError(f"{path}: no draws of {', '.join(missing)} (it has {list(posterior)})")
    return np.stack([np.asarray(posterior[n].values).reshape(-1) for n in names], axis=1)


def plot_corner(path, result: PosteriorResult, max_points: int = 4000) -> None:
    """Corner plot of the draws (histograms on the diagonal, scatter below; log axes for
    positive parameters), the least-squares optimum marked."""
    from matplotlib.figure import Figure

    names, p = result.params, len(result.params)
    flat = result.draws.reshape(-1, p)
    pick = np.linspace(0, len(flat) - 1, min(max_points, len(flat))).astype(int)
    best = result.fit.values if result.fit is not None else None
    # one parameter: a histogram of readable size (2.4 inches would leave it small under the
    # title)
    size = 2.4 * p if p > 1 else 4.8
    fig = Figure(figsize=(size, size * (0.75 if p == 1 else 1)))
    axes = fig.subplots(p, p, squeeze=False)
    for i in range(p):
        for j in range(p):
            ax = axes[i, j]
            if j > i:
                ax.axis("off")
                continue
            if i == j:
                ax.hist(flat[:, i], bins=40, color="C0", alpha=0.8)
                s = result.summary[names[i]]
                for q in (s["q05"], s["q95"]):
                    ax.axvline(q, color="k", ls=":", lw=1)
                ax.set_yticks([])
                # The marginal: median with the 90 % interval around it.
                ax.set_title(
                    f"{names[i]} = {s['median']:.3g}{_unit(names[i])}\n"
                    f"90 %: [{s['q05']:.3g}, {s['q95']:.3g}]",
                    fontsize=8,
                )
            else:
                ax.plot(flat[pick, j], flat[pick, i], ".", ms=1.5, alpha=0.4, color="C0")
                if best is not None:
                    ax.plot(best[names[j]], best[names[i]], "r+", ms=10)
            if i == p - 1:
                ax.set_xlabel(parameter_label(names[j]))
            if j == 0 and i > 0:
                ax.set_ylabel(parameter_label(names[i]))
    units = ("populations", "particles") if getattr(result, "sampler", "") == "smc" else (
        "chains", "draws",
    )  # fmt: skip
    title = (
        f"posterior ({result.chains} {units[0]} x {result.draws.shape[1]} {units[1]}); "
        + ("converged" if result.converged else "NOT CONVERGED")
        + ("; red +: the least-squares optimum" if best is not None and p > 1 else "")
    )
    # Wrapped to the figure's width (about 11 characters of 9-point text per inch), with room
    # above the panels for every line (tight_layout alone would let the title be cut).
    height = size * (0.75 if p == 1 else 1)
    lines = textwrap.wrap(title, int(11 * size))
    fig.suptitle("\n".join(lines), fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - (0.1 + 0.2 * len(lines)) / height))
    _atomic_savefig(fig, Path(path))


def _observable_panels(obs, draw):
    """One panel per observable (``captured`` aside) against impact speed, or incidence angle
    where every impact has one speed: ``draw(ax, order, x)`` adds the model's bands at the
    rows ``order`` (sorted by ``x``), then the data with their sigmas. Returns ``(fig, axes)``."""
    import matplotlib.ticker
    from matplotlib.figure import Figure

    x_is_angle = np.unique(obs.speed).size == 1
    x = obs.angle_deg if x_is_angle else obs.speed
    names = [k for k in OBSERVABLES if k != "captured" and np.any(obs.observable == k)]
    fig = Figure(figsize=(6.4, 2.8 * len(names)))
    axes = fig.subplots(len(names), 1, squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        sel = np.flatnonzero(obs.observable == name)
        draw(ax, sel[np.argsort(x[sel], kind="stable")], x)
        sigma = np.where(np.isfinite(obs.sigma[sel]), obs.sigma[sel], 0.0)
        ax.errorbar(x[sel], obs.value[sel], yerr=sigma if np.any(sigma) else None, fmt="o",
                    color="k", ms=3, label="data")  # fmt: skip
        ax.set_ylabel(_two_lines(observable_label(name)))
        if not x_is_angle:
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("incidence angle (deg)" if x_is_angle else "impact speed (m/s)")
    return fig, axes


def plot_predictive(path, result: PosteriorResult, n: int = 200) -> None:
    """Data against the posterior: the 90 % band of the model (dark) and of new data
    (light, the model plus the likelihood's noise) at each observed impact."""
    model, predicted = posterior_predictive(result, n)

    def draw(ax, order, x):
        for band, color, label in (
            (predicted, "C0", "90 % predictive"),
            (model, "C1", "90 % model"),
        ):
            lo, hi = np.quantile(band[:, order], [0.05, 0.95], axis=0)
            ax.vlines(
                x[order],
                lo,
                hi,
                color=color,
                lw=4 if band is predicted else 2,
                alpha=0.35 if band is predicted else 0.9,
                label=label,
            )
        # The model's median as a line: where the posterior leaves the model certain (rolling
        # impacts below the sliding angle: cor_t is 5/7 whatever the parameters) its band has
        # zero width and would be invisible.
        ax.plot(x[order], np.median(model[:, order], axis=0), "_-", color="C1", lw=1, ms=8,
                label="model median")  # fmt: skip

    fig, axes = _observable_panels(result.fit.objective.observations, draw)
    axes[0, 0].legend(fontsize=8)
    axes[0, 0].set_title(
        "posterior predictive: "
        + "; ".join(
            f"{nm} = {result.summary[nm]['median']:.3g} [{result.summary[nm]['q05']:.3g}, "
            f"{result.summary[nm]['q95']:.3g}]{_unit(nm)}"
            for nm in result.params
        )
        + " (median [90 %])",
        fontsize=8,
        wrap=True,
    )
    fig.tight_layout()
    _atomic_savefig(fig, Path(path))


def _unit(name: str) -> str:
    from jaximpact._model.ranges import RANGES

    unit = RANGES[name].unit
    return "" if unit == "1" else f" {unit}"


def comparison_summary(rows: list[dict]) -> str:
    """The table of :func:`fitting.compare_models`'s rows (best first), with each model's
    PSIS-LOO problems below it: ``exact``, the observations refitted exactly; ``k>0.7``, those
    whose estimate is still unreliable (Pareto k above 0.7 and not refitted, or a refit that
    did not converge)."""
    lines = [
        "model comparison by PSIS-LOO (elpd: expected log predictive density of a new "
        "observation; higher is better)",
        f"  {'model':28s} {'elpd_loo':>10s} {'se':>7s} {'elpd_diff':>10s} {'se_diff':>8s} "
        f"{'p_loo':>6s} {'max k':>6s} {'exact':>5s} {'k>0.7':>5s}",
    ]
    for r in rows:
        lines.append(
            f"  {r['name'][:28]:28s} {r['elpd']:10.2f} {r['se']:7.2f} {r['elpd_diff']:10.2f} "
            f"{r['se_diff']:8.2f} {r['p_loo']:6.2f} {r['max_khat']:6.2f} "
            f"{r.get('refitted', 0):5d} {_unreliable(r):5d}"
        )
    lines += [f"  {r['name']}: {p}" for r in rows for p in r["problems"]]
    best, *others = rows
    ahead = [r for r in others if r["elpd_diff"] < -2.0 * r["se_diff"]]
    # A lead that rests in part on unreliable leave-one-out terms says so.
    clear = [r["name"] for r in ahead if not (_unreliable(best) or _unreliable(r))]
    flagged = [r["name"] for r in ahead if r["name"] not in clear]
    close = [r["name"] for r in others if r not in ahead]
    if clear:
        lines.append(f"  {best['name']} predicts better than {', '.join(clear)} (more than "
                     "2 standard errors of the difference)")  # fmt: skip
    if flagged:
        lines.append(
            f"  {best['name']} predicts better than {', '.join(flagged)} (more than 2 standard "
            "errors of the difference), but the estimate includes observations with Pareto k "
            "above 0.7 (listed above): not reliable where the difference is near 2 standard "
            "errors"
        )
    if close:
        lines.append(f"  {best['name']} and {', '.join(close)}: within 2 standard errors of "
                     "the difference (the data do not tell them apart)")  # fmt: skip
    return "\n".join(lines)


def _unreliable(row: dict) -> int:
    """A comparison row's unreliable leave-one-out terms (rows without the count: one if it
    lists any problem)."""
    return int(row.get("unreliable", 1 if row["problems"] else 0))


def plot_comparison(path, results: dict[str, PosteriorResult], n: int = 200) -> None:
    """Data against each model's posterior: its median and 90 % band at each observed
    impact, side by side (one panel per observable)."""
    first = next(iter(results.values()))
    obs = first.fit.objective.observations
    models = {label: posterior_predictive(r, n)[0] for label, r in results.items()}
    x_is_angle = np.unique(obs.speed).size == 1
    # A small offset along x per model, so that bands at the same impact stay apart.
    spread = 0.012 if x_is_angle else 0.02

    def draw(ax, order, x):
        for k, (label, model) in enumerate(models.items()):
            shift = (k - 0.5 * (len(models) - 1)) * spread
            xs = x[order] + shift * np.ptp(x) if x_is_angle else x[order] * (1.0 + shift)
            lo, mid, hi = np.quantile(model[:, order], [0.05, 0.5, 0.95], axis=0)
            ax.vlines(xs, lo, hi, color=f"C{k}", lw=3, alpha=0.5)
            ax.plot(xs, mid, "_-", color=f"C{k}", lw=1, ms=8,
                    label=f"{Path(label).name} (median, 90 %)")  # fmt: skip

    fig, axes = _observable_panels(obs, draw)
    axes[0, 0].legend(fontsize=7)
    axes[0, 0].set_title("the models' posteriors against the data", fontsize=9)
    fig.tight_layout()
    _atomic_savefig(fig, Path(path))
