"""The solvers of a fit: the starting points, Levenberg-Marquardt over all starts as one
batch, and optax's Adam or L-BFGS for one start at a time, each ending in a :class:`_Solved`
(every start's end point, residuals, Jacobian and impact status), ranked best first.

The solvers work on unconstrained variables ``u`` (``_transforms``: ``p = exp(u)`` for positive
parameters, a scaled sigmoid for friction). Levenberg-Marquardt (``_lm``) is driven on the host
by one compiled program that returns the residuals and their Jacobian (forward mode) for all
starts at once (``_program``); optax Adam or L-BFGS minimize ``cost = 1/2 sum r^2`` in a
compiled loop instead, with the gradient ``J^T r`` from forward mode as well, and use the same
program for the final Jacobian.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

from jaximpact._engine.devices import compiler_options
from jaximpact._io.cache import runtime_checks_as_nan
from jaximpact.parameters import PARAMETERS

from .lm import levenberg_marquardt
from .results import StartResult
from .transforms import to_physical


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


def _dtype():
    return jnp.result_type(float)


def _physical(names, u) -> dict[str, float]:
    """``to_physical`` in numpy (no JAX dispatch for a handful of numbers): each parameter's
    transform of the registry (``jaximpact.parameters``)."""
    return {
        name: PARAMETERS[name].to_physical(x)
        for name, x in zip(names, np.asarray(u, dtype=float), strict=True)
    }
