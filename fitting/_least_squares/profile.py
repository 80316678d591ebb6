"""Profile likelihood of one fitted parameter: the others re-optimized along a grid of it.

Each grid point is a least-squares fit of the other parameters with the profiled one held
fixed, by the fit's own Levenberg-Marquardt on the fit's own compiled program (the profiled
column of the Jacobian is dropped; no new compilation), all grid points of a batch at once,
each started from the optimum.

The profile deviance is ``D(x) = 2 (cost(x) - cost_min) / s^2`` (``s``: the fit's residual
scale, 1 when the data give sigma); the likelihood-ratio 95 % interval is where ``D`` stays
below the chi-square(1) quantile 3.84, interpolated linearly in ``u`` (log scale) between grid
points. On a near-linear problem it equals the symmetric ``value +- 1.96 stderr``; on a
curved one it is asymmetric, which the symmetric standard error cannot show.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .fit import FitResult, _physical
from .lm import levenberg_marquardt
from .objective import FitError
from .program import ResidualProgram
from .transforms import dphys_du, to_unbounded

__all__ = ["CHI2_95", "Profile", "plot_profile", "profile", "profile_summary"]

#: 95 % quantile of chi-square with one degree of freedom.
CHI2_95 = 3.841458820694124


@dataclass
class Profile:
    """A profile: ``name``, the ``grid`` (physical), ``deviance`` at each point, the others'
    re-fitted values ``others`` ``{name: array}``, ``converged`` per point, the fit's
    ``value`` and ``stderr``, and the likelihood-ratio interval ``lower``, ``upper`` (NaN
    where the profile does not rise above 3.84 inside the grid)."""

    name: str
    grid: np.ndarray
    deviance: np.ndarray
    others: dict
    converged: np.ndarray
    value: float
    stderr: float
    lower: float
    upper: float

    def as_dict(self) -> dict:
        num = lambda x: float(x) if math.isfinite(float(x)) else None  # noqa: E731
        return {
            "name": self.name,
            "value": num(self.value),
            "stderr": num(self.stderr),
            "symmetric_95": [
                num(self.value - 1.96 * self.stderr),
                num(self.value + 1.96 * self.stderr),
            ],
            "likelihood_ratio_95": [num(self.lower), num(self.upper)],
            "grid": [num(x) for x in self.grid],
            "deviance": [num(x) for x in self.deviance],
            "converged": [bool(c) for c in self.converged],
            "others": {k: [num(x) for x in v] for k, v in self.others.items()},
        }


def profile(
    result: FitResult,
    name: str,
    *,
    points: int = 15,
    width: float = 3.5,
    max_steps: int = 100,
    progress: bool = False,
) -> Profile:
    """Profile likelihood of ``name`` around a converged fit.

    **Arguments:**
    - `result`: the `FitResult` (its objective and compiled program are reused).
    - `name`: one of ``result.params``.
    - `points`: grid points, evenly spaced in ``u`` over ``+-width`` standard errors.
    - `max_steps`: LM iterations per point.

    **Returns:** a `Profile`.

    **Raises:** `FitError`: an unknown name, too few points, or a fit without a finite
    standard error for ``name``.
    """
    names = result.params
    if name not in names:
        raise FitError(f"profile: {name!r} is not fitted ({list(names)})")
    if points < 3:
        raise FitError(f"profile points must be >= 3, got {points}")
    k = names.index(name)
    theta = result.theta
    u_hat = to_unbounded(names, theta)
    se_u = result.stderr[name] / dphys_du(names, theta)[k]
    if not (math.isfinite(se_u) and se_u > 0):
        raise FitError(f"profile: the fit gives no finite standard error for {name}")
    grid_u = u_hat[k] + np.linspace(-width, width, points) * se_u
    program = ResidualProgram(result.objective, max(len(result.starts), 1))
    program.compile()
    s2 = result.residual_scale**2 if math.isfinite(result.residual_scale) else 1.0
    costs, others, ok = profile_costs(
        program,
        program.starts,
        u_hat,
        k,
        grid_u,
        max_steps=max_steps,
        progress=progress,
        label=name,
    )
    deviance, lower_u, upper_u = likelihood_ratio_interval(grid_u, costs, result.cost, s2, u_hat[k])
    free = [i for i in range(len(names)) if i != k]
    grid = np.array([_physical([name], [x])[name] for x in grid_u])
    to_phys = lambda x: _physical([name], [x])[name] if math.isfinite(x) else math.nan  # noqa: E731
    other_names = [names[i] for i in free]
    return Profile(
        name=name,
        grid=grid,
        deviance=deviance,
        others={
            n: np.array([_physical([n], [v])[n] for v in others[:, j]])
            for j, n in enumerate(other_names)
        },
        converged=ok,
        value=float(theta[k]),
        stderr=float(result.stderr[name]),
        lower=to_phys(lower_u),
        upper=to_phys(upper_u),
    )


def profile_costs(evaluate, size, u_hat, k, grid_u, *, max_steps=100, progress=False, label=""):
    """Least-squares cost at each grid value of ``u[k]`` with the other variables re-fitted by
    Levenberg-Marquardt from ``u_hat``, ``size`` grid points per batch.

    ``evaluate``: ``U (size, p) -> (r, J, status)`` (a `ResidualProgram` or any function).
    Returns ``(cost (G,), others (G, p - 1) in u, converged (G,))``."""
    p = len(u_hat)
    free = [i for i in range(p) if i != k]
    points = len(grid_u)
    costs = np.empty(points)
    others = np.empty((points, len(free)))
    ok = np.zeros(points, bool)
    for start in tqdm(
        range(0, points, size),
        desc=f"profile {label}",
        disable=not progress,
        file=sys.stderr,
        leave=False,
    ):
        fixed = grid_u[start : start + size]
        fixed_full = np.concatenate([fixed, np.repeat(fixed[-1:], size - len(fixed))])

        def restricted(V, fixed_full=fixed_full):
            U = np.empty((size, p))
            U[:, free] = V
            U[:, k] = fixed_full
            r, jac, status = evaluate(U)
            return r, jac[:, :, free], status

        V0 = np.repeat(np.asarray(u_hat, float)[free][None], size, axis=0)
        if free:
            out = levenberg_marquardt(restricted, V0, rtol=1e-8, atol=1e-10, max_steps=max_steps)
            cost, u, conv = out.cost, out.u, out.converged
        else:  # nothing else to re-fit
            r, _, _ = restricted(V0)
            cost, u, conv = 0.5 * np.sum(r**2, axis=1), V0, np.ones(size, bool)
        n = len(fixed)
        costs[start : start + n] = cost[:n]
        others[start : start + n] = u[:n]
        ok[start : start + n] = conv[:n]
    return costs, others, ok


def likelihood_ratio_interval(grid_u, costs, cost_min, s2, u_hat_k):
    """Deviance ``2 (cost - cost_min) / s2`` on the grid and the 95 % interval in ``u``.

    The crossing of 3.84 is found on the signed root ``sign(u - u_hat) sqrt(deviance)``,
    interpolated linearly: that root is exactly linear for a Gaussian likelihood, so the
    interval then equals ``u_hat +- 1.96 se`` whatever the grid spacing."""
    deviance = np.maximum(2 * (np.asarray(costs) - cost_min) / s2, 0.0)
    root = np.sign(grid_u - u_hat_k) * np.sqrt(deviance)
    level = math.sqrt(CHI2_95)
    lower = upper = math.nan
    for target in (-level, level):
        # grid points on that side, from the centre outward
        side = (
            np.flatnonzero(grid_u < u_hat_k)[::-1]
            if target < 0
            else np.flatnonzero(grid_u > u_hat_k)
        )
        prev_x, prev_r = u_hat_k, 0.0
        for j in side:
            if abs(root[j]) >= level:
                t = (target - prev_r) / (root[j] - prev_r) if root[j] != prev_r else 0.0
                x = prev_x + t * (grid_u[j] - prev_x)
                lower, upper = (x, upper) if target < 0 else (lower, x)
                break
            prev_x, prev_r = grid_u[j], root[j]
    return deviance, lower, upper


def profile_summary(p: Profile) -> str:
    fmt = lambda x: f"{x:.5g}" if math.isfinite(x) else "beyond the grid"  # noqa: E731
    bad = int(np.sum(~p.converged))
    return (
        f"profile of {p.name}: likelihood-ratio 95 % interval [{fmt(p.lower)}, {fmt(p.upper)}]; "
        f"symmetric value +- 1.96 stderr: [{fmt(p.value - 1.96 * p.stderr)}, "
        f"{fmt(p.value + 1.96 * p.stderr)}]"
        + (f" ({bad} grid point(s) not converged)" if bad else "")
    )


def plot_profile(path, p: Profile) -> None:
    """The profile deviance against the parameter, with the 95 % threshold and both
    intervals."""
    from matplotlib.figure import Figure

    from jaximpact._model.ranges import RANGES

    from .report import _atomic_savefig, parameter_label

    unit = RANGES[p.name].unit
    unit = "" if unit == "1" else f" {unit}"
    fig = Figure(figsize=(5.6, 3.6))
    ax = fig.subplots()
    ax.plot(p.grid, p.deviance, "o-", color="C0", label="profile deviance")
    ax.plot(
        p.grid,
        ((p.grid - p.value) / p.stderr) ** 2,
        "--",
        color="C1",
        label="quadratic (from stderr)",
    )
    ax.axhline(CHI2_95, color="k", ls=":", lw=1, label="95 % (3.84)")
    for k, x in enumerate((p.lower, p.upper)):
        if math.isfinite(x):
            first = k == 0 or not math.isfinite(p.lower)
            label = "likelihood-ratio 95 % interval" if first else None
            ax.axvline(x, color="C0", lw=0.8, label=label)
    ax.set_xlabel(parameter_label(p.name))
    ax.set_ylabel("deviance 2 (cost - cost_min) / s^2 (dimensionless)")
    show = lambda x: f"{x:.4g}" if math.isfinite(x) else "?"  # noqa: E731
    ax.set_title(
        f"{p.name} = {p.value:.4g} \u00b1 {show(p.stderr)}{unit}; likelihood-ratio 95 %: "
        f"[{show(p.lower)}, {show(p.upper)}]{unit}",
        fontsize=9,
    )
    ax.set_ylim(
        0,
        max(
            2 * CHI2_95,
            float(np.nanmax(p.deviance[np.isfinite(p.deviance)]))
            if np.any(np.isfinite(p.deviance))
            else 10,
        ),
    )
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    _atomic_savefig(fig, Path(path))
