"""Fitting driver: solvers, multi-start, uncertainty, identifiability and misfit checks.

The solvers work on unconstrained variables ``u`` (``_transforms``: ``p = exp(u)`` for positive
parameters, a scaled sigmoid for friction). The default solver is Levenberg-Marquardt
(``_lm``), driven on the host by one compiled program that returns the residuals and their
Jacobian (forward mode) for all starts at once (``_program``); optax Adam or L-BFGS minimize
``cost = 1/2 sum r^2`` in a compiled loop instead, with the gradient ``J^T r`` from forward mode
as well, and use the same program for the final Jacobian.

Uncertainty: with ``J`` the Jacobian of the residuals in ``u`` at the optimum, the covariance
of ``u`` is ``s^2 (J^T J)^+``, where ``s^2 = 2 cost / (n - p)`` (the residual variance) unless
every observation carries its own sigma (then ``s^2 = 1``). The physical covariance follows
by the delta method, ``D cov_u D`` with ``D = diag(dp/du)``; correlations are the same in both.
Rank and condition number are those of ``J`` in ``u`` (relative sensitivities for the log
parameters); a singular value below ``1/MAX_CONDITION`` of the largest counts as zero, and
the parameters that its direction involves are reported as not identified by the data, with
infinite standard errors; so is a parameter whose standard error exceeds its value.

A fit is reported ``converged`` only if the optimizer converged, no impact failed, the
uncertainty is defined (full rank, finite standard errors) and the model describes the data
(:data:`MISFIT_P_VALUE`, :data:`MISFIT_RMS`); otherwise its ``status`` says which, and
``problems`` says why.
"""

from __future__ import annotations

import math
import sys
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

import jaximpact
from jaximpact._engine.devices import compiler_options
from jaximpact._io.cache import runtime_checks_as_nan
from jaximpact._model.ranges import IMPLAUSIBLE, RANGES, implausible
from jaximpact.tables import number_text

from .._data import Observations, load_observations
from .diagnose import _diagnose
from .lm import levenberg_marquardt
from .objective import FitError, Objective, check_names, get_parameter
from .program import JACOBIAN_MODES, ResidualProgram
from .transforms import BOUNDS, to_physical, to_unbounded

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

#: Solver names accepted by :func:`fit`.
SOLVERS = ("lm", "adam", "lbfgs")

#: Values of :attr:`FitResult.status`, in the order they are checked.
STATUSES = ("not converged", "undetermined", "misfit", "converged")


@dataclass
class StartResult:
    """One start of a multi-start fit: initial and final values, cost, convergence."""

    initial: dict[str, float]
    values: dict[str, float]
    cost: float
    converged: bool
    steps: int
    message: str


@dataclass
class FitResult:
    """Result of :func:`fit`.

    Attributes:
        params: fitted parameter names.
        values, stderr: ``{name: float}``, physical units (stderr ``inf`` where the data do not
            determine the parameter, NaN where no residual variance exists).
        correlation, covariance: ``(p, p)`` numpy arrays, physical parameters.
        cost: ``1/2 sum r^2`` at the optimum (residuals in scales).
        status: ``"converged"``, ``"not converged"`` (optimizer, failed impacts, or stuck
            where the model captures impacts that the data show rebounding),
            ``"undetermined"`` (the uncertainty is undefined: rank-deficient Jacobian or
            non-finite standard errors) or ``"misfit"`` (the model does not describe the data).
        converged: ``status == "converged"``: the only state in which the values and standard
            errors can be taken as the answer.
        optimizer_converged: the best start met the optimizer's convergence test.
        problems: why the status is not ``"converged"`` (empty when it is).
        n_data, dof: observations, and ``n_data - len(params)``.
        rank, condition_number, singular_values: of the residual Jacobian in the solver
            variables.
        sensitivity: ``{name: |dr/d ln p|}``: how much the residual vector (in scales) changes
            per relative change of each parameter.
        unidentifiable: names of the parameters the data do not determine.
        reduced_chi2: ``2 cost / dof`` when every observation has a sigma, else NaN;
            ``p_value``: its chi-square upper tail probability.
        rms_residual: ``sqrt(2 cost / n_data)``, in scales.
        residual_scale: ``s``, the factor applied to the standard errors (1 if sigma is known).
        warnings: human-readable warnings (identifiability, convergence, failures).
        timings: seconds: ``compile`` (the programs, or loading them), ``solve`` (all starts),
            ``total`` (including data loading and checks).
        solver, jacobian: ``"lm"``, ``"adam"`` or ``"lbfgs"``; ``"fwd"`` or ``"rev"``.
        program: counts of the residual program's ``traces``, ``compiles`` and ``calls``, and
            where it came from (``source``: traced, cache (traced before; compiled, or
            loaded from JAX's compilation cache) or memory).
        starts: every start, best first.
        residuals: the weighted residuals at the optimum.
        scene: the scene with the fitted values in place.
        objective: the `Objective` (for reports and plots).
        message: the status and its reasons, one line.
    """

    params: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    correlation: np.ndarray
    covariance: np.ndarray
    cost: float
    converged: bool
    n_data: int
    condition_number: float
    residual_scale: float
    warnings: list[str]
    timings: dict[str, float]
    solver: str
    starts: list[StartResult]
    residuals: np.ndarray
    scene: jaximpact.Scene
    objective: Objective = field(repr=False)
    message: str = ""
    status: str = "converged"
    optimizer_converged: bool = True
    problems: list[str] = field(default_factory=list)
    dof: int = 0
    rank: int = 0
    singular_values: np.ndarray = field(default_factory=lambda: np.zeros(0))
    sensitivity: dict[str, float] = field(default_factory=dict)
    unidentifiable: list[str] = field(default_factory=list)
    reduced_chi2: float = math.nan
    p_value: float = math.nan
    rms_residual: float = math.nan
    jacobian: str = "fwd"
    program: dict = field(default_factory=dict)

    @property
    def theta(self) -> np.ndarray:
        """Fitted values as an array in :attr:`params` order."""
        return np.array([self.values[n] for n in self.params])

    @property
    def minima(self) -> list[StartResult]:
        """The distinct minima the converged starts ended at, best first (one start each):
        :func:`distinct_minima` of :attr:`starts`."""
        return distinct_minima(self.starts, self.params)


#: Two converged starts ended at the same minimum when their costs agree to this relative
#: tolerance and their values (in the solver's variables: ln p, a logit for friction) to
#: this absolute one.
SAME_COST = 1e-3
SAME_VALUES = 1e-3


def distinct_minima(starts: Sequence[StartResult], names: Sequence[str]) -> list[StartResult]:
    """The converged ``starts`` with one start per distinct end point, lowest cost first."""
    kept: list[tuple[StartResult, np.ndarray]] = []
    for start in sorted((s for s in starts if s.converged), key=lambda s: s.cost):
        u = np.asarray(to_unbounded(list(names), [start.values[n] for n in names]), float)
        same = any(
            abs(start.cost - other.cost) <= SAME_COST * max(abs(other.cost), 1e-12)
            and np.max(np.abs(u - v)) <= SAME_VALUES
            for other, v in kept
        )
        if not same:
            kept.append((start, u))
    return [start for start, _ in kept]


def _start_points(names, u0, starts, spread, seed) -> np.ndarray:
    """``starts`` points in u: the initial guess, then a Latin-hypercube spread around it.

    Positive parameters vary by a factor up to ``spread`` either way; bounded ones by
    ``+-log(spread)`` in logit space (about the same relative spread for small friction).
    """
    points = [np.asarray(u0, dtype=float)]
    if starts > 1:
        rng = np.random.default_rng(seed)
        n = starts - 1
        # Latin hypercube in [-1, 1]^p: each parameter's range is covered evenly.
        cube = np.stack(
            [(rng.permutation(n) + rng.uniform(size=n)) / n * 2 - 1 for _ in names], axis=1
        )
        points.extend(np.asarray(u0) + math.log(spread) * cube)
    return np.stack(points)


def _cost_with_forward_gradient(objective, names):
    """``cost(u) = 1/2 |r(u)|^2`` whose reverse-mode derivative (what optax asks for) is
    computed in forward mode, ``J^T r`` with ``J`` from ``jax.jacfwd``: the simulator's
    forward mode compiles and runs several times faster than its reverse mode."""

    def residuals(u):
        theta = to_physical(names, u)
        result = objective._simulate_impl(theta, diffrax.ForwardMode())
        r = objective.residuals_from_result(result, objective.hertz_time(theta))
        return r, r

    @jax.custom_vjp
    def cost(u):
        return 0.5 * jnp.sum(residuals(u)[0] ** 2)

    def cost_fwd(u):
        jac, r = jax.jacfwd(residuals, has_aux=True)(u)
        return 0.5 * jnp.sum(r**2), jac.T @ r

    def cost_bwd(grad, g):
        return (g * grad,)

    cost.defvjp(cost_fwd, cost_bwd)
    return cost


def _optax_solver(objective, names, kind, learning_rate, rtol, atol, max_steps):
    """Minimize ``cost`` with optax in a ``lax.while_loop``; converged when the step in ``u``
    and the relative change in cost both fall below tolerance (checked over 2 steps in a row
    for Adam, whose steps do not shrink by themselves until near the optimum)."""
    cost_fn = _cost_with_forward_gradient(objective, names)
    if kind == "adam":
        opt = optax.adam(learning_rate)
    else:
        opt = optax.lbfgs()
    if kind == "adam":  # Adam keeps no value or gradient in its state
        plain = jax.value_and_grad(cost_fn)
        value_and_grad = lambda u, state: plain(u)  # noqa: E731
    else:  # L-BFGS reuses those of its line search
        value_and_grad = optax.value_and_grad_from_state(cost_fn)

    def solve(u0):
        def body(carry):
            u, state, cost, _, k, calm = carry
            value, grad = value_and_grad(u, state=state)
            if kind == "adam":
                updates, state = opt.update(grad, state, u)
            else:
                updates, state = opt.update(
                    grad, state, u, value=value, grad=grad, value_fn=cost_fn
                )
            new = optax.apply_updates(u, updates)
            step_small = jnp.max(jnp.abs(new - u)) < atol + rtol * jnp.max(jnp.abs(u))
            cost_small = jnp.abs(cost - value) <= atol + rtol * jnp.abs(value)
            calm = jnp.where(step_small & cost_small, calm + 1, 0)
            return new, state, value, grad, k + 1, calm

        def cond(carry):
            *_, k, calm = carry
            return (k < max_steps) & (calm < 2)

        state = opt.init(u0)
        big = jnp.asarray(jnp.inf, u0.dtype)
        init = (u0, state, big, jnp.zeros_like(u0), jnp.asarray(0), jnp.asarray(0))
        u, _, _, _, k, calm = jax.lax.while_loop(cond, body, init)
        return u, calm >= 2, k

    return solve


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
    if not jax.config.jax_enable_x64:
        warnings.warn(
            "fit: JAX runs in float32 here; the fit's tolerances and uncertainties need "
            'float64: call jax.config.update("jax_enable_x64", True) before any JAX array '
            "is made (the command line does)",
            UserWarning,
            stacklevel=2,
        )
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


@dataclass
class _Solved:
    """Every start's end point ``u``, residuals, Jacobian, impact status and convergence."""

    u: np.ndarray
    r: np.ndarray
    jac: np.ndarray
    status: np.ndarray
    converged: list
    steps: list
    message: list


def _solve_lm(program, points, rtol, atol, max_steps, progress) -> _Solved:
    """All starts by Levenberg-Marquardt as one batch, with a progress bar."""
    bar = tqdm(
        total=max_steps,
        desc=f"fit (lm, {len(points)} start{'s' if len(points) > 1 else ''})",
        unit="it",
        disable=not progress,
        file=sys.stderr,
        leave=False,
    )

    def on_iteration(k, cost, active):
        bar.update(1)
        bar.set_postfix(cost=f"{np.min(cost):.4g}", running=int(np.sum(active)))

    try:
        out = levenberg_marquardt(
            program,
            points,
            rtol=rtol,
            atol=atol,
            max_steps=max_steps,
            on_iteration=on_iteration,
        )
    finally:
        bar.close()
    return _Solved(out.u, out.r, out.jac, out.status, out.converged, out.steps, out.message)


def _solve_optax(
    objective, program, names, points, solver, learning_rate, rtol, atol, max_steps, progress
) -> tuple[_Solved, float]:
    """Each start in turn by an optax solver (its loop compiled once); the compile time."""
    solve = _optax_solver(objective, names, solver, learning_rate, rtol, atol, max_steps)
    t1 = time.perf_counter()
    if progress:
        print(f"compiling the {solver} loop ...", end="", file=sys.stderr, flush=True)
    with runtime_checks_as_nan():
        lowered = jax.jit(solve).lower(jnp.asarray(points[0], _dtype()))
        compiled = lowered.compile(compiler_options())
    loop_compile = time.perf_counter() - t1
    if progress:
        print(f" {loop_compile:.1f} s", file=sys.stderr, flush=True)
    finals, ok_all, steps_all = [], [], []
    for k in tqdm(
        range(len(points)),
        desc=f"fit ({solver})",
        unit="start",
        disable=not progress,
        file=sys.stderr,
        leave=False,
    ):
        u, ok, steps = compiled(jnp.asarray(points[k], _dtype()))
        finals.append(np.asarray(u))
        ok_all.append(bool(ok))
        steps_all.append(int(steps))
    U = np.stack(finals)
    r_all, jac_all, status_all = program(U)
    messages = ["converged" if ok else f"iteration limit ({max_steps}) reached" for ok in ok_all]
    return _Solved(U, r_all, jac_all, status_all, ok_all, steps_all, messages), loop_compile


def _ranked_runs(names, start_values, out: _Solved) -> list:
    """``(StartResult, residuals, Jacobian, status)`` of each start, the best first: lowest
    cost among converged starts, else lowest cost overall."""
    runs = []
    for k in range(len(start_values)):
        cost = 0.5 * float(np.sum(out.r[k] ** 2))
        ok = bool(out.converged[k]) and math.isfinite(cost)
        message = "non-finite cost" if out.converged[k] and not ok else out.message[k]
        start = StartResult(
            start_values[k], _physical(names, out.u[k]), cost, ok, int(out.steps[k]), message
        )
        runs.append((start, out.r[k], out.jac[k], out.status[k]))
    runs.sort(key=lambda run: (not run[0].converged, run[0].cost))
    return runs


def _verdict(objective, names, theta, runs, status, d, starts) -> tuple:
    """The fit's status name, its problems and warnings, and the values for its scene (a
    value outside its documented range replaced by the nearest inside)."""
    best = runs[0][0]
    n_failed = int(np.sum(status >= jaximpact.Status.MAX_STEPS))
    warnings, problems = list(d["warnings"]), []
    if not best.converged:
        problems.append(f"the optimizer did not converge: {best.message}")
    if n_failed:
        problems.append(f"{n_failed} impact(s) failed to simulate at the final values")
    problems.extend(d["undetermined"])
    problems.extend(d["misfit"])
    n_captured = _capture_mismatch(objective, status)
    if n_captured:
        problems.insert(
            len(problems) - len(d["undetermined"]) - len(d["misfit"]),
            f"the fit ended where the model captures {n_captured} impact(s) that the data "
            "show rebounding (stuck in the capture region: start with less adhesion or "
            "damping, or use more starts)",
        )
    # A fitted value outside its documented range (a log-scale parameter has no upper end):
    # not an answer; the result's scene holds the nearest value inside, for reports and plots.
    outside = {nm: v for nm, v in best.values.items() if not RANGES[nm].contains(v)}
    for nm, v in outside.items():
        problems.append(
            f"{nm} = {v:.4g} left its documented range {RANGES[nm].interval()} "
            "(docs/input_ranges.md)"
        )
    scene_values = {
        nm: float(np.clip(v, RANGES[nm].lo, RANGES[nm].hi)) if nm in outside else v
        for nm, v in best.values.items()
    }
    warnings += _value_warnings(objective, names, theta, runs, starts, scene_values)
    if not best.converged or n_failed or n_captured or outside:
        status_name = "not converged"
    elif d["undetermined"]:
        status_name = "undetermined"
    elif d["misfit"]:
        status_name = "misfit"
    else:
        status_name = "converged"
    return status_name, problems, warnings, scene_values


def _value_warnings(objective, names, theta, runs, starts, scene_values) -> list[str]:
    """Warnings on the fitted values: implausible impacts, a value at its bound, starts that
    converged to different minima."""
    warnings = []
    implausible_at = _implausible_impacts(objective, objective.scene_at(scene_values))
    if implausible_at:
        warnings.append(
            f"physically implausible at {implausible_at} of {objective._speed.size} impact(s): "
            f"{IMPLAUSIBLE['large_overlap']} (elastic Hertz estimate at the fitted values)"
        )
    for i, nm in enumerate(names):
        if nm in BOUNDS:
            lo, hi = BOUNDS[nm]
            if min(theta[i] - lo, hi - theta[i]) < 1e-3 * (hi - lo):
                warnings.append(f"{nm} = {theta[i]:.4g} is at its bound ({lo}, {hi})")
    n_conv = sum(run[0].converged for run in runs)
    minima = distinct_minima([run[0] for run in runs], names)
    if starts > 1 and len(minima) > 1:
        warnings.append(
            f"{n_conv} of {starts} starts converged to {len(minima)} distinct minima (costs "
            f"{minima[0].cost:.6g} .. {minima[-1].cost:.6g}; each listed under 'minima'): "
            "the values above are the lowest; a posterior's reference covers each one with "
            "posterior mass"
        )
    return warnings


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


def _dtype():
    return jnp.result_type(float)


def _physical(names, u) -> dict[str, float]:
    """``to_physical`` in numpy (no JAX dispatch for a handful of numbers)."""
    out = {}
    for name, x in zip(names, np.asarray(u, dtype=float), strict=True):
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            out[name] = float(lo + (hi - lo) / (1.0 + math.exp(-x)))
        else:
            out[name] = float(math.exp(x))
    return out


def _implausible_impacts(objective: Objective, scene) -> int:
    """How many of the data's impacts the fitted scene makes physically implausible
    (``jaximpact._ranges.implausible``, from the elastic Hertz estimate of the overlap)."""
    imp = objective.observations.impacts
    n = imp.speed.size

    def value(name, section, field):
        given = imp.overrides.get(name)
        return np.broadcast_to(
            given if given is not None else np.asarray(getattr(getattr(scene, section), field)),
            (n,),
        )

    flags = implausible(
        value("radius", "particle", "radius"),
        np.full(n, np.nan),
        value("density", "particle", "density"),
        value("K", "contact", "K"),
        imp.speed,
        imp.angle_deg,
    )
    return int(np.sum(flags != ""))


def _capture_mismatch(objective: Objective, status) -> int:
    """Impacts the model captures although the data show a rebound there."""
    obs = objective.observations
    rebound = (obs.observable != "captured") | (obs.value < 0.5)
    captured = np.asarray(status)[obs.impact_index] == jaximpact.Status.CAPTURED
    return int(np.unique(obs.impact_index[rebound & captured]).size)
