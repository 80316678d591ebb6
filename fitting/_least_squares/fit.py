"""Fitting driver: solvers, multi-start, uncertainty, identifiability and misfit checks.

The solvers (``solvers``) work on unconstrained variables ``u`` (``_transforms``: ``p =
exp(u)`` for positive parameters, a scaled sigmoid for friction). The default solver is
Levenberg-Marquardt (``_lm``), driven on the host by one compiled program that returns the
residuals and their Jacobian (forward mode) for all starts at once (``_program``); optax Adam
or L-BFGS minimize ``cost = 1/2 sum r^2`` in a compiled loop instead, with the gradient ``J^T
r`` from forward mode as well, and use the same program for the final Jacobian.

Uncertainty (``diagnose``): with ``J`` the Jacobian of the residuals in ``u`` at the optimum,
the covariance of ``u`` is ``s^2 (J^T J)^+``, where ``s^2 = 2 cost / (n - p)`` (the residual
variance) unless every observation carries its own sigma (then ``s^2 = 1``). The physical
covariance follows by the delta method, ``D cov_u D`` with ``D = diag(dp/du)``; correlations
are the same in both. Rank and condition number are those of ``J`` in ``u`` (relative
sensitivities for the log parameters); a singular value below ``1/MAX_CONDITION`` of the
largest counts as zero, and the parameters that its direction involves are reported as not
identified by the data, with infinite standard errors; so is a parameter whose standard error
exceeds its value.

A fit is reported ``converged`` (``verdict``) only if the optimizer converged, no impact
failed, the uncertainty is defined (full rank, finite standard errors) and the model describes
the data (:data:`MISFIT_P_VALUE`, :data:`MISFIT_RMS`); otherwise its ``status`` says which,
and ``problems`` says why. What a fit returns is in ``results``.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence

import jax
import numpy as np

import jaximpact
from jaximpact.tables import number_text

from .._data import Observations, load_observations
from .diagnose import _diagnose
from .objective import FitError, Objective, check_names, get_parameter
from .program import JACOBIAN_MODES, ResidualProgram
from .results import SAME_COST, SAME_VALUES, STATUSES, FitResult, StartResult, distinct_minima
from .solvers import _physical, _ranked_runs, _solve_lm, _solve_optax, _start_points
from .transforms import BOUNDS, to_physical, to_unbounded
from .verdict import _implausible_impacts, _verdict

__all__ = [
    "BOUNDS",
    "SOLVERS",
    "STATUSES",
    "FitResult",
    "StartResult",
    "fit",
    "to_physical",
    "to_unbounded",
]

# Names other modules, tests and notebooks import from here (the driver's pieces moved to
# ``results``, ``solvers`` and ``verdict``).
_REEXPORTED = (FitError, SAME_COST, SAME_VALUES, distinct_minima, _diagnose, _implausible_impacts)

#: Solver names accepted by :func:`fit`.
SOLVERS = ("lm", "adam", "lbfgs")


def fit(
    scene: jaximpact.Scene,
    observations,
    params: Sequence[str],
    *,
    initial: Mapping[str, float] | None = None,
    solver: str = "lm",
    starts: int = 1,
    spread: float = 3.0,
    seed: int = 0,
    max_steps: int = 200,
    rtol: float = 1e-6,
    atol: float = 1e-8,
    learning_rate: float = 0.05,
    progress: bool = True,
    method: str | None = None,
    jacobian: str = "fwd",
) -> FitResult:
    """Fit scene parameters to observations by weighted least squares.

    **Arguments:**
    - `scene`: the `jaximpact.Scene`; it gives every parameter not fitted and, unless
      `initial` says otherwise, the starting values of the fitted ones.
    - `observations`: an `Observations` or the path of a data file (wide or long CSV).
    - `params`: names to fit, from ``C_A, C_H, f0, friction, K, G_star, w, p_y, lambda,
      radius, density`` (``G_star`` with ``model.tangential = "mindlin"``, ``w`` with the
      DMT, JKR and Thornton-Ning normal laws, ``p_y`` with Thornton-Ning's).
    - `initial`: starting values ``{name: value}`` (SI) overriding the scene's.
    - `solver`: ``"lm"`` (Levenberg-Marquardt, default), ``"adam"`` or ``"lbfgs"`` (optax).
    - `starts`: number of starts: the initial guess, then a Latin-hypercube spread of
      ``starts - 1`` points up to a factor `spread` away (see `_start_points`). The start
      with the lowest cost among the converged ones (else among all) is reported. With
      ``"lm"`` all starts run as one batch.
    - `seed`: seed of the spread.
    - `max_steps`: iteration limit per start; a start that reaches it is not converged.
    - `rtol`, `atol`: convergence tolerances on the step in ``u`` and the change in cost.
    - `learning_rate`: Adam's step size (in ``u``, i.e. relative for log parameters).
    - `progress`: show what is compiled (with its time) and a progress bar, on stderr.
    - `method`: ODE method (default: the scene's; ``"auto"`` is resolved from the stiffness at
      the starting points).
    - `jacobian`: ``"fwd"`` (forward mode, default) or ``"rev"`` (reverse mode, slower; for
      comparison).

    **Returns:** a `FitResult`; check ``status`` (or ``converged``) and ``problems``.

    **Raises:** `FitError` (a `ValueError`) for unknown parameter names, unusable data,
    starting values out of range, an unknown solver or a bad option; `DataError` for a
    malformed data file.
    """
    t_start = time.perf_counter()
    _warn_if_float32()
    names = check_names(params, scene)
    initial = _check_options(names, solver, jacobian, starts, max_steps, spread, initial)
    p0 = [float(initial.get(n, get_parameter(scene, n))) for n in names]
    u0 = to_unbounded(names, p0)
    points = _start_points(names, u0, starts, spread, seed)
    start_values = [_physical(names, u) for u in points]
    if not isinstance(observations, Observations):
        observations = load_observations(observations)
    check_enough_observations(observations, names)

    objective = Objective(scene, observations, names, method=method, check_values=start_values)
    program = ResidualProgram(objective, len(points), jacobian=jacobian)
    t_compile = program.compile(status=progress)

    t0 = time.perf_counter()
    if solver == "lm":
        out = _solve_lm(program, points, rtol, atol, max_steps, progress)
    else:
        out, loop_compile = _solve_optax(
            objective, program, names, points, solver, learning_rate, rtol, atol, max_steps,
            progress,
        )  # fmt: skip
        t_compile += loop_compile
    t_solve = time.perf_counter() - t0

    runs = _ranked_runs(names, start_values, out)
    timings = {"compile": t_compile, "solve": t_solve}
    return _fit_result(objective, program, names, runs, starts, solver, jacobian, timings, t_start)


def _warn_if_float32() -> None:
    """A warning (pointing at the caller of :func:`fit`) where JAX runs in float32."""
    if not jax.config.jax_enable_x64:
        warnings.warn(
            "fit: JAX runs in float32 here; the fit's tolerances and uncertainties need "
            'float64: call jax.config.update("jax_enable_x64", True) before any JAX array '
            "is made (the command line does)",
            UserWarning,
            stacklevel=3,
        )


def _fit_result(objective, program, names, runs, starts, solver, jacobian, timings, t_start):
    """The ``FitResult`` of the best start: its diagnosis, verdict, problems and warnings."""
    best, residuals, jac, status = runs[0]
    theta = np.array([best.values[n] for n in names])
    n, p = objective.n_data, len(names)
    d = _diagnose(jac, best.cost, n, names, theta, objective.sigma_known)
    status_name, problems, warnings, scene_values = _verdict(
        objective, names, theta, runs, status, d, starts
    )
    message = status_name if not problems else f"{status_name}: " + "; ".join(problems)
    return FitResult(
        params=names,
        values=dict(best.values),
        stderr=d["stderr"],
        correlation=d["correlation"],
        covariance=d["covariance"],
        cost=best.cost,
        converged=status_name == "converged",
        n_data=n,
        condition_number=d["condition_number"],
        residual_scale=d["residual_scale"],
        warnings=warnings,
        timings={**timings, "total": time.perf_counter() - t_start},
        solver=solver,
        starts=[run[0] for run in runs],
        residuals=residuals,
        scene=objective.scene_at(scene_values),
        objective=objective,
        message=message,
        status=status_name,
        optimizer_converged=best.converged,
        problems=problems,
        dof=n - p,
        rank=d["rank"],
        singular_values=d["singular_values"],
        sensitivity=d["sensitivity"],
        unidentifiable=d["unidentifiable"],
        reduced_chi2=d["reduced_chi2"],
        p_value=d["p_value"],
        rms_residual=math.sqrt(2 * best.cost / n) if math.isfinite(best.cost) else math.nan,
        jacobian=jacobian,
        program=dict(program.stats),
    )


def _check_options(names, solver, jacobian, starts, max_steps, spread, initial) -> dict:
    """``fit``'s options checked (``FitError`` naming the bad one); the initial values."""
    if solver not in SOLVERS:
        raise FitError(f"unknown solver {solver!r}; choose from {', '.join(SOLVERS)}")
    if jacobian not in JACOBIAN_MODES:
        raise FitError(f"jacobian must be one of {', '.join(JACOBIAN_MODES)}, got {jacobian!r}")
    if not (isinstance(starts, int) and starts >= 1):
        raise FitError(f"starts must be an integer >= 1, got {number_text(starts)}")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise FitError(f"max_steps must be an integer >= 1, got {number_text(max_steps)}")
    if not spread > 1:
        raise FitError(f"spread must be > 1, got {number_text(spread)}")
    initial = dict(initial or {})
    for name in initial:
        if name not in names:
            raise FitError(f"initial value for {name!r}, which is not fitted ({list(names)})")
    return initial


def check_enough_observations(observations: Observations, names: Sequence[str]) -> None:
    """Refuse, before anything is compiled, data that cannot determine the parameters: fewer
    independent observations (distinct pairs of impact and observable: a repeated
    measurement of the same thing adds no direction) than parameters.

    Raises:
        FitError: naming both counts.
    """
    pairs = {
        (int(i), str(o))
        for i, o in zip(observations.impact_index, observations.observable, strict=True)
    }
    if len(pairs) < len(names):
        n_rows = len(observations)
        repeats = f" ({n_rows} rows)" if n_rows != len(pairs) else ""
        raise FitError(
            f"{observations.source}: {_count(len(pairs), 'independent observation')}"
            f"{repeats} for {_count(len(names), 'parameter')} ({', '.join(names)}): the data "
            f"cannot determine them; measure at least {len(names)} distinct quantities "
            "(observables at distinct impacts), or fit fewer parameters"
        )


def _count(n: int, noun: str) -> str:
    """``1 observation``, ``2 observations``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"
