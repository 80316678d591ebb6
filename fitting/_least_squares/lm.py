"""Levenberg-Marquardt on the host, driven by the compiled residual-and-Jacobian program.

All starts advance together: one call of the program per iteration evaluates every start's
trial point, residuals and Jacobian at once (see ``_program``). The linear algebra (a few
parameters) is numpy. Each start keeps its own damping and stops on its own; a start that has
stopped is evaluated again at its final point (the batch has a fixed shape, so the program
never recompiles) and left unchanged.

Step: ``min |r + J d|^2 + lam |D d|^2`` with ``D^2`` the running maximum of ``diag(J^T J)``
(Moré's scaling: invariant to the units of ``u``), solved as a least-squares problem by SVD.
No step moves a variable by more than ``MAX_STEP`` (1 in ``u``: a factor e for the log
parameters; a longer step is shortened along its direction): a trust region in the max-norm
that keeps a linear model from leaping across the capture threshold into a far-off region.
A trial is accepted when it reduces the cost by at least 1e-4 of the reduction the linear
model predicts; the damping then shrinks by ``max(1/3, 1 - (2 rho - 1)^3)`` (Nielsen), else
it grows by a factor that doubles with every rejection in a row.

Converged (``rtol``, ``atol`` as for the ``u`` variables):
- an accepted step with ``|d_i| <= atol + rtol |u_i|`` for every parameter; or
- an accepted step whose actual and predicted relative cost reductions are both ``<= rtol``;
- a rejected step already that small (the cost cannot be lowered at that resolution); or
- a zero cost.

Not converged: the iteration limit; a Jacobian that is zero (the residuals do not depend on
the parameters there: nothing to follow); non-finite residuals at the start; a damping that
grows past 1e16 without an acceptable step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LMOutcome", "levenberg_marquardt"]

_ACCEPT = 1e-4
MAX_STEP = 1.0
_MAX_DAMPING = 1e16


@dataclass
class LMOutcome:
    """Final state of every start: ``u (S, p)``, ``r (S, m)``, ``jac (S, m, p)``,
    ``status (S, n_impacts)``, ``cost (S,)``, ``converged (S,)``, ``steps (S,)`` (program
    evaluations after the first), ``message`` (one per start), ``iterations`` (calls)."""

    u: np.ndarray
    r: np.ndarray
    jac: np.ndarray
    status: np.ndarray
    cost: np.ndarray
    converged: np.ndarray
    steps: np.ndarray
    message: list
    iterations: int


def _step(jac, r, lam, d2):
    """The damped Gauss-Newton step, shortened to at most ``MAX_STEP`` in every variable, and
    the cost reduction the linear model predicts for it."""
    p = jac.shape[1]
    a = np.vstack([jac, np.diag(np.sqrt(lam * d2))])
    b = np.concatenate([-r, np.zeros(p)])
    step = np.linalg.lstsq(a, b, rcond=None)[0]
    longest = np.max(np.abs(step))
    if longest > MAX_STEP:
        step = step * (MAX_STEP / longest)
    predicted = 0.5 * (r @ r - np.sum((r + jac @ step) ** 2))
    return step, predicted


def levenberg_marquardt(evaluate, U0, *, rtol, atol, max_steps, on_iteration=None) -> LMOutcome:
    """Run Levenberg-Marquardt from every row of ``U0`` at once.

    **Arguments:**
    - `evaluate`: ``U (S, p) -> (r (S, m), J (S, m, p), status (S, k))``, numpy.
    - `U0`: ``(S, p)`` starting points.
    - `rtol`, `atol`: tolerances (see the module docstring).
    - `max_steps`: iteration limit (program calls after the first).
    - `on_iteration`: called after each iteration with ``(iteration, cost (S,), active (S,))``.

    **Returns:** an `LMOutcome`.
    """
    U = np.array(U0, dtype=float)
    S, p = U.shape
    r, jac, status = evaluate(U)
    r, jac, status = r.copy(), jac.copy(), status.copy()
    cost = 0.5 * np.sum(r**2, axis=1)
    converged = np.zeros(S, bool)
    active = np.isfinite(cost) & np.all(np.isfinite(jac), axis=(1, 2))
    message = ["" if a else "non-finite residuals or Jacobian at the start" for a in active]
    steps = np.zeros(S, int)
    lam = np.full(S, 1e-3)
    grow = np.full(S, 2.0)
    d2 = np.sum(jac**2, axis=1)
    tiny = np.finfo(float).tiny

    def stop(s, ok, why):
        active[s] = False
        converged[s] = ok
        message[s] = why

    for s in range(S):
        if active[s] and cost[s] == 0:
            stop(s, True, "zero cost")
        elif active[s] and not np.any(jac[s]):
            stop(s, False, "the Jacobian is zero: the residuals do not depend on the parameters")

    iteration = 0
    while np.any(active) and iteration < max_steps:
        iteration += 1
        trial = U.copy()
        steps_s = np.zeros_like(U)
        predicted = np.zeros(S)
        for s in np.flatnonzero(active):
            d2[s] = np.maximum(d2[s], np.sum(jac[s] ** 2, axis=0))
            steps_s[s], predicted[s] = _step(jac[s], r[s], lam[s], np.maximum(d2[s], tiny))
            trial[s] = U[s] + steps_s[s]
        r_t, jac_t, status_t = evaluate(trial)
        for s in np.flatnonzero(active):
            steps[s] += 1
            cost_t = 0.5 * float(np.sum(r_t[s] ** 2))
            small = bool(np.all(np.abs(steps_s[s]) <= atol + rtol * np.abs(U[s])))
            finite = np.isfinite(cost_t) and np.all(np.isfinite(jac_t[s]))
            rho = (cost[s] - cost_t) / predicted[s] if predicted[s] > 0 else -np.inf
            if finite and rho > _ACCEPT:
                reduction = (cost[s] - cost_t) / max(cost[s], tiny)
                U[s], r[s], jac[s], status[s] = trial[s], r_t[s], jac_t[s], status_t[s]
                predicted_rel = predicted[s] / max(cost[s], tiny)
                cost[s] = cost_t
                lam[s] *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
                grow[s] = 2.0
                if cost_t == 0:
                    stop(s, True, "zero cost")
                elif small:
                    stop(s, True, "step below tolerance")
                elif reduction <= rtol and predicted_rel <= rtol:
                    stop(s, True, "cost change below tolerance")
                elif not np.any(jac[s]):
                    stop(
                        s,
                        False,
                        "the Jacobian is zero: the residuals do not depend on the parameters",
                    )
            else:
                lam[s] *= grow[s]
                grow[s] *= 2.0
                if small:
                    stop(s, True, "no lower cost within the step tolerance")
                elif lam[s] > _MAX_DAMPING:
                    stop(s, False, "no step lowers the cost (damping overflow)")
        if on_iteration is not None:
            on_iteration(iteration, cost.copy(), active.copy())
    for s in np.flatnonzero(active):
        stop(s, False, f"iteration limit ({max_steps}) reached")
    return LMOutcome(U, r, jac, status, cost, converged, steps, message, iteration)
