"""Fitting driver: parameter transforms, solvers, multi-start, uncertainty.

The solvers work on unconstrained variables ``u`` that map to physical values: ``p = exp(u)``
for positive parameters (C_A, C_H, f0, K, lambda, radius, density) and
``p = lo + (hi - lo) sigmoid(u)`` for the friction coefficient in ``(0, 1.5)``. The default
solver is optimistix's Levenberg-Marquardt on the residuals; optax Adam or L-BFGS minimize
``cost = 1/2 sum r^2`` instead. The Jacobian is computed in reverse mode, since the simulator's
ODE solve (diffrax, checkpointed adjoint) supports only reverse-mode differentiation.

Uncertainty: with ``J`` the Jacobian of the residuals in ``u`` at the optimum, the covariance
of ``u`` is ``s^2 (J^T J)^-1``, where ``s^2 = 2 cost / (n - p)`` (the residual variance) unless
every observation carries its own sigma (then ``s^2 = 1``). The physical covariance follows
by the delta method, ``D cov_u D`` with ``D = diag(dp/du)``; correlations are the same in both.
The condition number reported is that of ``J`` in ``u`` (i.e. relative sensitivities for the
log-transformed parameters).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
from tqdm.auto import tqdm

import jaximpact

from ._objective import FitError, Objective, check_names, get_parameter

__all__ = ["BOUNDS", "SOLVERS", "FitResult", "StartResult", "fit", "to_physical", "to_unbounded"]

#: Bounded parameters: ``name -> (lo, hi)``; all other fittable parameters are positive.
BOUNDS = {"friction": (0.0, 1.5)}

#: Solver names accepted by :func:`fit`.
SOLVERS = ("lm", "adam", "lbfgs")

#: Thresholds of the identifiability warning.
MAX_CORRELATION = 0.95
MAX_CONDITION = 1e8


def to_unbounded(names: Sequence[str], values) -> np.ndarray:
    """Physical values -> unconstrained solver variables (log, or logit for bounded ones).

    Raises:
        FitError: a value outside its allowed range (<= 0, or outside ``BOUNDS``).
    """
    u = []
    for name, p in zip(names, np.asarray(values, dtype=float), strict=True):
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            if not lo < p < hi:
                raise FitError(f"initial {name} = {p!r} must be in ({lo}, {hi})")
            x = (p - lo) / (hi - lo)
            u.append(math.log(x / (1 - x)))
        else:
            if not (p > 0 and math.isfinite(p)):
                raise FitError(
                    f"initial {name} = {p!r} must be finite and > 0 (it is fitted on a log "
                    "scale); give a positive starting value"
                )
            u.append(math.log(p))
    return np.array(u)


def to_physical(names: Sequence[str], u):
    """Unconstrained variables -> physical values (works on numpy or JAX arrays)."""
    out = []
    for i, name in enumerate(names):
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            out.append(lo + (hi - lo) * jax.nn.sigmoid(u[i]))
        else:
            out.append(jnp.exp(u[i]))
    return jnp.stack(out)


def _dphys_du(names, p) -> np.ndarray:
    d = []
    for name, v in zip(names, p, strict=True):
        if name in BOUNDS:
            lo, hi = BOUNDS[name]
            d.append((v - lo) * (hi - v) / (hi - lo))
        else:
            d.append(v)
    return np.array(d)


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
        values, stderr: ``{name: float}``, physical units (stderr ``inf`` if undetermined).
        correlation, covariance: ``(p, p)`` numpy arrays, physical parameters.
        cost: ``1/2 sum r^2`` at the optimum (residuals in scales).
        converged: the best start met the solver's convergence criterion and no impact failed
            at the optimum.
        n_data: number of observations; ``dof = n_data - len(params)``.
        condition_number: of the residual Jacobian in the solver variables.
        residual_scale: ``s``, the factor applied to the standard errors (1 if sigma is known).
        warnings: human-readable warnings (identifiability, convergence, failures).
        timings: seconds: ``compile`` (solver and Jacobian programs), ``solve`` (all starts,
            with each start's Jacobian), ``total`` (including data loading and checks).
        solver: ``"lm"``, ``"adam"`` or ``"lbfgs"``.
        starts: every start, best first.
        residuals: the weighted residuals at the optimum.
        scene: the scene with the fitted values in place.
        objective: the `Objective` (for reports and plots).
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

    @property
    def theta(self) -> np.ndarray:
        """Fitted values as an array in :attr:`params` order."""
        return np.array([self.values[n] for n in self.params])


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


def _lm_solver(objective, names, rtol, atol, max_steps):
    fn = lambda u, _: objective._residuals_impl(to_physical(names, u))
    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol)

    def solve(u0):
        sol = optx.least_squares(
            fn, solver, u0, options={"jac": "bwd"}, max_steps=max_steps, throw=False
        )
        return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]

    return solve


def _optax_solver(objective, names, kind, learning_rate, rtol, atol, max_steps):
    """Minimize ``cost`` with optax in a ``lax.while_loop``; converged when the step in ``u``
    and the relative change in cost both fall below tolerance (checked over 2 steps in a row
    for Adam, whose steps do not shrink by themselves until near the optimum)."""
    cost_fn = lambda u: 0.5 * jnp.sum(objective._residuals_impl(to_physical(names, u)) ** 2)
    if kind == "adam":
        opt = optax.adam(learning_rate)
    else:
        opt = optax.lbfgs()
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
) -> FitResult:
    """Fit scene parameters to observations by weighted least squares.

    **Arguments:**
    - `scene`: the `jaximpact.Scene`; it gives every parameter not fitted and, unless
      `initial` says otherwise, the starting values of the fitted ones.
    - `observations`: an `Observations` or the path of a data file (wide or long CSV).
    - `params`: names to fit, from ``C_A, C_H, f0, friction, K, lambda, radius, density``.
    - `initial`: starting values ``{name: value}`` (SI) overriding the scene's.
    - `solver`: ``"lm"`` (optimistix Levenberg-Marquardt, default), ``"adam"`` or
      ``"lbfgs"`` (optax).
    - `starts`: number of starts: the initial guess, then a Latin-hypercube spread of
      ``starts - 1`` points up to a factor `spread` away (see `_start_points`). The start
      with the lowest cost among the converged ones (else among all) is reported.
    - `seed`: seed of the spread.
    - `max_steps`: iteration limit per start; a start that reaches it is not converged.
    - `rtol`, `atol`: convergence tolerances on the step in ``u`` and the change in cost.
    - `learning_rate`: Adam's step size (in ``u``, i.e. relative for log parameters).
    - `progress`: show a tqdm progress bar over the starts.
    - `method`: ODE method (default: the scene's; ``"auto"`` is resolved from the stiffness at
      the starting points).

    **Returns:** a `FitResult`.

    **Raises:** `FitError` (a `ValueError`) for unknown parameter names, unusable data,
    starting values out of range, an unknown solver or a bad option; `DataError` for a
    malformed data file.
    """
    t_start = time.perf_counter()
    names = check_names(params)
    if solver not in SOLVERS:
        raise FitError(f"unknown solver {solver!r}; choose from {', '.join(SOLVERS)}")
    if not (isinstance(starts, int) and starts >= 1):
        raise FitError(f"starts must be an integer >= 1, got {starts!r}")
    if not (isinstance(max_steps, int) and max_steps >= 1):
        raise FitError(f"max_steps must be an integer >= 1, got {max_steps!r}")
    if not spread > 1:
        raise FitError(f"spread must be > 1, got {spread!r}")
    initial = dict(initial or {})
    for name in initial:
        if name not in names:
            raise FitError(f"initial value for {name!r}, which is not fitted ({list(names)})")
    p0 = [float(initial.get(n, get_parameter(scene, n))) for n in names]
    u0 = to_unbounded(names, p0)
    points = _start_points(names, u0, starts, spread, seed)
    start_values = [
        dict(zip(names, map(float, to_physical(names, u)), strict=True)) for u in points
    ]

    objective = Objective(scene, observations, names, method=method, check_values=start_values)
    if solver == "lm":
        solve = _lm_solver(objective, names, rtol, atol, max_steps)
    else:
        solve = _optax_solver(objective, names, solver, learning_rate, rtol, atol, max_steps)
    dtype = jnp.result_type(float)

    def evaluate(u):
        # Residuals, their Jacobian in u (reverse mode) and the impacts' status, in one
        # compiled program: used for every start's cost and for the uncertainty.
        def r_aux(u):
            result = objective._simulate_impl(to_physical(names, u))
            r = objective.residuals_from_result(result)
            return r, (r, result.status)

        jac, (r, status) = jax.jacrev(r_aux, has_aux=True)(u)
        return r, jac, status

    t0 = time.perf_counter()
    u_first = jnp.asarray(points[0], dtype)
    compiled = jax.jit(solve).lower(u_first).compile()
    evaluate = jax.jit(evaluate).lower(u_first).compile()
    t_compile = time.perf_counter() - t0

    t0 = time.perf_counter()
    runs = []
    for k in tqdm(range(len(points)), desc=f"fit ({solver})", unit="start", disable=not progress):
        u, ok, steps = compiled(jnp.asarray(points[k], dtype))
        r, jac, status = (np.asarray(x) for x in evaluate(u))
        cost = 0.5 * float(np.sum(r**2))
        ok = bool(ok) and math.isfinite(cost)
        values = dict(zip(names, map(float, to_physical(names, u)), strict=True))
        start = StartResult(
            start_values[k], values, cost, ok, int(steps), "converged" if ok else "not converged"
        )
        runs.append((start, r, jac, status))
    t_solve = time.perf_counter() - t0

    # Best start: lowest cost among converged starts, else lowest cost overall.
    runs.sort(key=lambda run: (not run[0].converged, run[0].cost))
    best, residuals, jac, status = runs[0]
    if best.steps >= max_steps:
        best.message = f"iteration limit ({max_steps}) reached"
    theta = np.array([best.values[n] for n in names])
    n_failed = int(np.sum(status >= jaximpact.Status.MAX_STEPS))

    n, p = objective.n_data, len(names)
    warnings = []
    dof = n - p
    if objective.sigma_known:
        s2 = 1.0
    elif dof > 0:
        s2 = 2 * best.cost / dof
    else:
        s2 = math.nan
        warnings.append(f"{n} observations for {p} parameters: no residual variance, no stderr")
    cov, corr, cond = _covariance(jac, s2, _dphys_du(names, theta))
    stderr = {
        nm: float(np.sqrt(cov[i, i])) if cov[i, i] >= 0 else math.nan for i, nm in enumerate(names)
    }

    if not np.isfinite(cond) or cond > MAX_CONDITION:
        warnings.append(
            f"ill-conditioned: condition number of the Jacobian {cond:.3g} > {MAX_CONDITION:g}; "
            "some parameter combination is not determined by the data"
        )
    for i in range(p):
        for j in range(i + 1, p):
            if abs(corr[i, j]) > MAX_CORRELATION:
                warnings.append(
                    f"strongly correlated: {names[i]} and {names[j]} (corr {corr[i, j]:+.3f}); "
                    "the data determine a combination of them, not each one"
                )
    converged = best.converged and n_failed == 0
    if not best.converged:
        warnings.append(f"NOT CONVERGED: {best.message}")
    if n_failed:
        warnings.append(f"{n_failed} impact(s) failed to simulate at the fitted values")
    for i, nm in enumerate(names):
        if nm in BOUNDS:
            lo, hi = BOUNDS[nm]
            if min(theta[i] - lo, hi - theta[i]) < 1e-3 * (hi - lo):
                warnings.append(f"{nm} = {theta[i]:.4g} is at its bound ({lo}, {hi})")
    n_conv = sum(run[0].converged for run in runs)
    if starts > 1:
        spread_costs = [run[0].cost for run in runs if run[0].converged]
        if n_conv and max(spread_costs) > best.cost * (1 + 1e-3) + 1e-9:
            warnings.append(
                f"{n_conv} of {starts} starts converged, not all to the same minimum "
                f"(costs {min(spread_costs):.6g} .. {max(spread_costs):.6g})"
            )
    message = (
        "converged"
        if converged
        else (best.message if not best.converged else f"{n_failed} impact(s) failed")
    )
    return FitResult(
        params=names,
        values=dict(best.values),
        stderr=stderr,
        correlation=corr,
        covariance=cov,
        cost=best.cost,
        converged=converged,
        n_data=n,
        condition_number=cond,
        residual_scale=math.sqrt(s2) if math.isfinite(s2) else math.nan,
        warnings=warnings,
        timings={
            "compile": t_compile,
            "solve": t_solve,
            "total": time.perf_counter() - t_start,
        },
        solver=solver,
        starts=[run[0] for run in runs],
        residuals=residuals,
        scene=objective.scene_at(best.values),
        objective=objective,
        message=message,
    )


def _covariance(jac, s2, dpdu):
    """Physical covariance, correlation and condition number from the Jacobian in ``u``.

    The pseudo-inverse by SVD: a direction the data do not determine (zero singular value)
    gives an infinite variance rather than an arbitrary finite one.
    """
    p = jac.shape[1]
    if not np.all(np.isfinite(jac)):
        nan = np.full((p, p), np.nan)
        return nan, nan, math.inf
    _, sv, vt = np.linalg.svd(jac, full_matrices=False)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    with np.errstate(divide="ignore"):
        inv_sv2 = np.where(sv > sv[0] * 1e-15, 1.0 / sv**2, np.inf)
    if np.all(np.isfinite(inv_sv2)):
        cov_u = (vt.T * inv_sv2) @ vt * s2
    else:
        cov_u = np.full((p, p), np.inf)
    cov = cov_u * np.outer(dpdu, dpdu)
    d = np.sqrt(np.abs(np.diag(cov_u)))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_u / np.outer(d, d)
    return cov, corr, cond
