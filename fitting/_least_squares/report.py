"""Reports of a fit: JSON result, readable summary, plot of data against the fitted model."""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

import numpy as np

from jaximpact._io.paths import atomic_output
from jaximpact.tables import atomic_write_text

from .._data import OBSERVABLES
from .fit import FitResult

__all__ = ["plot_fit", "result_dict", "summary", "write_json"]

_UNITS = {
    "cor_n": "",
    "cor_t": "",
    "vt_out": "m/s",
    "omega_out": "rad/s",
    "rebound_angle_deg": "deg",
    "captured": "1 = captured",
}


def _num(x):
    """A JSON-safe float: ``None`` (null) for NaN and infinities, which JSON lacks."""
    x = float(x)
    return x if math.isfinite(x) else None


def _count(n: int, noun: str) -> str:
    """``1 observation``, ``2 observations``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def result_dict(result: FitResult) -> dict:
    """The fit as a JSON-ready dict.

    Returns:
        dict: ``status`` (converged | not converged | undetermined | misfit), ``converged``
        (``status == "converged"``), ``message``, ``problems`` (why not converged),
        ``params`` (``{name: {"value", "stderr", "sensitivity", "identifiable"}}``),
        ``correlation``, ``cost``, ``n_data``, ``dof``, ``rank``, ``condition_number``,
        ``singular_values``, ``unidentifiable`` (names), ``reduced_chi2`` and ``p_value``
        (with sigmas), ``rms_residual``, ``residual_scale``, ``sigma_known``, ``warnings``,
        ``timings`` (s), ``solver``, ``jacobian``, ``ode_method``, ``program`` (traces,
        compiles, calls, source), ``starts`` and ``data`` (source file, observation counts).
        Undefined numbers (NaN, infinite) are ``null``.
    """
    obs = result.objective.observations
    return {
        "status": result.status,
        "converged": bool(result.converged),
        "optimizer_converged": bool(result.optimizer_converged),
        "message": result.message,
        "problems": list(result.problems),
        "params": {
            n: {
                "value": _num(result.values[n]),
                "stderr": _num(result.stderr[n]),
                "sensitivity": _num(result.sensitivity.get(n, math.nan)),
                "identifiable": n not in result.unidentifiable,
            }
            for n in result.params
        },
        "correlation": [[_num(c) for c in row] for row in result.correlation],
        "cost": _num(result.cost),
        "n_data": int(result.n_data),
        "dof": int(result.dof),
        "rank": int(result.rank),
        "condition_number": _num(result.condition_number),
        "singular_values": [_num(v) for v in result.singular_values],
        "unidentifiable": list(result.unidentifiable),
        "reduced_chi2": _num(result.reduced_chi2),
        "p_value": _num(result.p_value),
        "rms_residual": _num(result.rms_residual),
        "residual_scale": _num(result.residual_scale),
        "sigma_known": bool(result.objective.sigma_known),
        "warnings": list(result.warnings),
        "timings": {k: round(float(v), 4) for k, v in result.timings.items()},
        "solver": result.solver,
        "jacobian": result.jacobian,
        "ode_method": result.objective.method,
        "program": dict(result.program),
        "starts": [
            {
                "initial": s.initial,
                "values": s.values,
                "cost": _num(s.cost),
                "converged": s.converged,
                "steps": s.steps,
                "message": s.message,
            }
            for s in result.starts
        ],
        "minima": [
            {"values": s.values, "cost": _num(s.cost), "converged": s.converged}
            for s in result.minima
        ],
        "data": {"source": obs.source, "counts": obs.counts()},
    }


def write_json(path, result: FitResult) -> None:
    """Write :func:`result_dict` as JSON, atomically (readers never see a partial file)."""
    write_json_dict(path, result_dict(result))


def write_json_dict(path, document: dict) -> None:
    """Write a JSON-ready dict, atomically."""
    atomic_write_text(path, json.dumps(document, indent=2) + "\n")


_STATUS_LINE = {
    "converged": "converged",
    "not converged": "NOT CONVERGED",
    "undetermined": "UNDETERMINED (the data do not fix every parameter; no valid uncertainty)",
    "misfit": "MISFIT (the model does not describe the data)",
}


def _source_text(source: str) -> str:
    """The data's source as a reader knows it: an embedded data set by name (not the path
    the package happens to be installed at), else the file as given."""
    from .._data import KHARAZ2001_FILE, kharaz2001_path

    try:
        if Path(source).name == KHARAZ2001_FILE and Path(source).samefile(kharaz2001_path()):
            return "embedded data set kharaz2001"
    except (OSError, ValueError):
        pass
    return source


def summary(result: FitResult) -> str:
    """A readable multi-line summary: status, values with standard errors and sensitivities,
    rank, condition number, goodness of fit, problems, warnings, timings."""
    lines = [
        f"fit of {', '.join(result.params)} to {_count(result.n_data, 'observation')} "
        f"({_source_text(result.objective.observations.source)}); solver {result.solver}, "
        f"{len(result.starts)} start(s)",
        f"status: {_STATUS_LINE.get(result.status, result.status)}",
    ]
    for problem in result.problems:
        lines.append(f"  because {problem}")
    width = max(len(n) for n in result.params)
    lines.append("parameter values, standard errors and sensitivities |dr/d ln p| (scales):")
    for n in result.params:
        v, e = result.values[n], result.stderr[n]
        rel = f" ({100 * e / abs(v):.2g} %)" if math.isfinite(e) and v != 0 else ""
        err = f"{e:.3g}" if math.isfinite(e) else ("undetermined" if e == math.inf else "n/a")
        sens = result.sensitivity.get(n, math.nan)
        flag = "  NOT IDENTIFIED" if n in result.unidentifiable else ""
        lines.append(f"  {n.ljust(width)} = {v:.6g} +- {err}{rel}; sensitivity {sens:.3g}{flag}")
    if math.isfinite(result.reduced_chi2):
        fit_quality = (
            f"reduced chi-square = {result.reduced_chi2:.4g} (dof {result.dof}, "
            f"p = {result.p_value:.3g})"
        )
    elif result.objective.sigma_known:  # sigmas, but nothing left over to test them with
        fit_quality = (
            f"rms residual = {result.rms_residual:.4g} sigma(s) (no chi-square: "
            f"{_count(result.n_data, 'observation')} for {_count(len(result.params), 'parameter')}"
            ", no degrees of freedom left)"
        )
    else:
        fit_quality = (
            f"rms residual = {result.rms_residual:.4g} scale(s) (no sigmas: no chi-square)"
        )
    lines.append(f"cost (1/2 sum r^2) = {result.cost:.6g}; {fit_quality}")
    cond = result.condition_number
    lines.append(
        f"Jacobian: rank {result.rank} of {len(result.params)}, condition number "
        + (f"{cond:.3g}" if math.isfinite(cond) else "infinite")
        + (f"; not identified: {', '.join(result.unidentifiable)}" if result.unidentifiable else "")
    )
    if len(result.params) > 1:
        lines.append("correlation:")
        for n, row in zip(result.params, result.correlation, strict=True):
            lines.append(f"  {n.ljust(width)} " + " ".join(f"{c:+.3f}" for c in row))
    for w in result.warnings:
        lines.append(f"warning: {w}")
    minima = result.minima
    if len(minima) > 1:
        lines.append("minima (distinct end points of the converged starts, lowest cost first):")
        for m in minima:
            values = ", ".join(f"{n} = {m.values[n]:.6g}" for n in result.params)
            lines.append(f"  cost {m.cost:.6g}: {values}")
    t = result.timings
    lines.append(
        f"time: {t['total']:.1f} s (compile {t['compile']:.1f} s, solve {t['solve']:.1f} s)"
    )
    return "\n".join(lines)


def plot_fit(path, result: FitResult) -> None:
    """Plot each observable's data (with error bars where sigma is given) and the fitted model.

    The x axis is the incidence angle when the data have a single speed, else the speed. The
    model is drawn at the observed impacts (open squares) and, where the data lie on lines of
    one varying coordinate, as a dense curve along each line, one legend entry per curve. The
    title gives the fitted values with their standard errors and the fit's status. Every axis
    carries its unit. The model at the data and along the curves is one ``simulate`` call
    (the compact program, rebound outputs only: one compilation of the smaller program).
    Written atomically (temporary file in the same directory, then :func:`os.replace`; through
    a symbolic link to its target), as a matplotlib ``Figure`` of its own (no pyplot: the
    caller's backend and figures, a notebook's inline ones, are left as they were).

    Arguments:
        path: output image (format from the suffix, e.g. ``.png``, ``.pdf``).
        result: a `FitResult`.
    """
    from matplotlib.figure import Figure

    obs = result.objective.observations
    imp = obs.impacts
    x_is_angle = np.unique(obs.speed).size == 1
    x = obs.angle_deg if x_is_angle else obs.speed
    names = [n for n in OBSERVABLES if np.any(obs.observable == n)]
    curves = _curves(obs, x_is_angle) if not imp.overrides else []
    model, grid_results = _plotted_model(result, curves)

    fig = Figure(figsize=(6.4, 2.8 * len(names)))
    axes = fig.subplots(len(names), 1, squeeze=False)
    for ax, name in zip(axes[:, 0], names, strict=True):
        sel = obs.observable == name
        sigma = np.where(np.isfinite(obs.sigma[sel]), obs.sigma[sel], 0.0)
        ax.errorbar(
            x[sel],
            obs.value[sel],
            yerr=sigma if np.any(sigma) else None,
            fmt="o",
            color="k",
            ms=4,
            label="data" + (" (1 sigma bars)" if np.any(sigma) else ""),
        )
        ax.plot(x[sel], model[sel], "s", mfc="none", color="C0", ms=6, label="model at the data")
        if grid_results is not None and name != "captured":
            start = imp.speed.size
            for k, c in enumerate(curves):
                stop = start + c["speed"].size
                y = np.asarray(getattr(grid_results, name))[start:stop]
                ax.plot(c["x"], y, "-", color=f"C{k + 1}", lw=1.2, label=c["label"])
                start = stop
        ax.set_ylabel(_two_lines(observable_label(name)))
        if not x_is_angle:
            ax.set_xscale("log")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel("incidence angle (deg)" if x_is_angle else "impact speed (m/s)")
    status = "" if result.converged else f" ({result.status.upper()})"
    axes[0, 0].set_title(
        "\n".join(textwrap.wrap(f"fit{status}: {fitted_values_text(result)}", 70)), fontsize=9
    )
    fig.tight_layout()
    _atomic_savefig(fig, Path(path))


def _plotted_model(result: FitResult, curves) -> tuple:
    """``(model, grid_results)``: the fitted model's value of each observation, and its
    `ImpactResult` at the observed impacts then along the ``curves`` (``None`` where the data
    have per-impact parameters: the model at the data only)."""
    import jaximpact

    objective = result.objective
    obs = objective.observations
    imp = obs.impacts
    if imp.overrides:  # per-impact parameters: the model at the data only
        model, _ = objective.model_values(result.theta)
        return model, None
    parts = [(imp.speed, imp.angle_deg, imp.omega0)]
    parts += [(c["speed"], c["angle"], c["omega0"]) for c in curves]
    speed, angle, omega = (np.concatenate([q[k] for q in parts]) for k in range(3))
    everything = jaximpact.simulate(
        result.scene.replace(solver={"outputs": "rebound"}),
        speed,
        angle,
        omega,
        method=objective.method,
        program="compact",
    )
    return _observation_values(obs, everything), everything


#: What each observable is, for axis labels (the data file's column name follows).
_DESCRIPTIONS = {
    "cor_n": "normal restitution",
    "cor_t": "tangential restitution",
    "vt_out": "tangential rebound speed",
    "omega_out": "rebound spin",
    "rebound_angle_deg": "rebound angle",
    "captured": "captured",
}


def observable_label(name: str) -> str:
    """An axis label in words with the data's column name and the unit: ``rebound angle,
    rebound_angle_deg (deg)``, ``normal restitution, cor_n (dimensionless)``."""
    words = _DESCRIPTIONS.get(name, "")
    head = f"{words}, {name}" if words and words != name else name
    return f"{head} ({_UNITS[name] or 'dimensionless'})"


def _two_lines(label: str) -> str:
    """An axis label in two lines at its first comma: a stacked panel 2.8 inches high cut
    "tangential restitution, cor_t (dimensionless)" in one line, and its neighbour's ran into
    it."""
    return label.replace(", ", ",\n", 1)


def parameter_label(name: str) -> str:
    """A fitted parameter with its SI unit: ``f0 (N/m)``, ``friction (dimensionless)``."""
    from jaximpact._model.ranges import RANGES

    unit = RANGES[name].unit
    return f"{name} ({'dimensionless' if unit == '1' else unit})"


def fitted_values_text(result: FitResult) -> str:
    """``friction = 0.0957 +- 0.0064; f0 = 312 +- 25 N/m`` (``+- ?`` where undetermined)."""
    from jaximpact._model.ranges import RANGES

    parts = []
    for n in result.params:
        unit = RANGES[n].unit
        e = result.stderr[n]
        err = f"{e:.2g}" if math.isfinite(e) else "?"
        unit = "" if unit == "1" else f" {unit}"
        parts.append(f"{n} = {result.values[n]:.4g} \u00b1 {err}{unit}")
    return "; ".join(parts)


def _observation_values(obs, res) -> np.ndarray:
    """The model value of each observation from a ``simulate`` result whose first impacts are
    ``obs.impacts`` (``captured``: 1.0 or 0.0; NaN where the impact failed)."""
    k = obs.impact_index
    status = np.asarray(res.status)[: obs.impacts.speed.size][k]
    values = np.full(len(obs), np.nan)
    for name in np.unique(obs.observable):
        sel = obs.observable == name
        if name == "captured":
            values[sel] = (status[sel] == 1).astype(float)
        else:
            values[sel] = np.asarray(getattr(res, str(name)), float)[k[sel]]
    values[status >= 2] = np.nan
    return values


def _curves(obs, x_is_angle, points=60, max_curves=8):
    """Dense model lines through the data: along the angle (single speed) or along the speed
    for each distinct (angle, omega0) pair with at least two observed speeds."""
    imp = obs.impacts
    if x_is_angle:
        keys = {(float(imp.speed[0]), float(w)) for w in imp.omega0}
    else:
        keys = {(float(a), float(w)) for a, w in zip(imp.angle_deg, imp.omega0, strict=True)}
    if len(keys) > max_curves:
        return []
    curves = []
    for a, b in sorted(keys):
        if x_is_angle:
            on = imp.omega0 == b
            grid = np.linspace(imp.angle_deg[on].min(), imp.angle_deg[on].max(), points)
            speed, angle = np.full(points, a), grid
        else:
            on = (imp.angle_deg == a) & (imp.omega0 == b)
            if np.unique(imp.speed[on]).size < 2:
                continue
            grid = np.geomspace(imp.speed[on].min(), imp.speed[on].max(), points)
            speed, angle = grid, np.full(points, a)
        spin = f", omega0 {b:g} rad/s" if any(w for _, w in keys) else ""
        where = f"{a:g} m/s" if x_is_angle else f"{a:g} deg"
        label = f"model, {where}{spin}"
        curves.append(
            {
                "x": grid,
                "speed": speed,
                "angle": angle,
                "omega0": np.full(points, b),
                "label": label,
            }
        )
    return curves


def plot_formats() -> dict[str, str]:
    """The image formats a plot can be written in: ``{suffix: description}`` (matplotlib's)."""
    from matplotlib.backend_bases import FigureCanvasBase

    return dict(FigureCanvasBase.get_supported_filetypes())


def check_plot_path(path, option: str) -> None:
    """Refuse a plot file whose suffix names no image format matplotlib writes, before
    anything is computed.

    Raises:
        FitError: naming the option, the file and the formats there are.
    """
    from .objective import FitError

    suffix = Path(path).suffix.lower().lstrip(".")
    formats = plot_formats()
    if suffix not in formats:
        found = f"unknown image format '.{suffix}'" if suffix else "no file suffix"
        raise FitError(
            f"{option} {path}: {found}; the suffix names the format, one of: "
            + ", ".join(sorted(formats))
        )


def _atomic_savefig(fig, path: Path) -> None:
    """``fig.savefig`` atomically, through a symbolic link to its target (never over a device,
    a pipe or a directory: ``FileProblem``); the format is the file's suffix."""
    with atomic_output(path, "plot") as temp:
        fig.savefig(temp, dpi=120, bbox_inches="tight", format=Path(path).suffix[1:].lower())
