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
    r, jac, status = evaluate(U)
    st = _Starts.first(U, r.copy(), jac.copy(), status.copy())
    iteration = 0
    while np.any(st.active) and iteration < max_steps:
        iteration += 1
        trial, steps, predicted = _trials(st)
        r_t, jac_t, status_t = evaluate(trial)
        for s in np.flatnonzero(st.active):
            st.steps[s] += 1
            _judge(st, s, trial[s], steps[s], predicted[s], r_t[s], jac_t[s], status_t[s],
                   rtol, atol)  # fmt: skip
        if on_iteration is not None:
            on_iteration(iteration, st.cost.copy(), st.active.copy())
    for s in np.flatnonzero(st.active):
        st.stop(s, False, f"iteration limit ({max_steps}) reached")
    return LMOutcome(
        st.U, st.r, st.jac, st.status, st.cost, st.converged, st.steps, st.message, iteration
    )


_ZERO_JACOBIAN = "the Jacobian is zero: the residuals do not depend on the parameters"


@dataclass
class _Starts:
    """Every start's state during the iteration (arrays over the starts, updated in place):
    its point, residuals, Jacobian, impact status and cost, whether it is still running
    (``active``), how it stopped (``converged``, ``message``), its evaluations, its damping
    ``lam`` and that damping's growth factor, and the running maximum ``d2`` of
    ``diag(J^T J)``."""

    U: np.ndarray
    r: np.ndarray
    jac: np.ndarray
    status: np.ndarray
    cost: np.ndarray
    converged: np.ndarray
    active: np.ndarray
    message: list
    steps: np.ndarray
    lam: np.ndarray
    grow: np.ndarray
    d2: np.ndarray

    @classmethod
    def first(cls, U, r, jac, status) -> _Starts:
        """The state at the starting points; a start with a zero cost or a zero Jacobian
        there stops at once."""
        S = U.shape[0]
        cost = 0.5 * np.sum(r**2, axis=1)
        active = np.isfinite(cost) & np.all(np.isfinite(jac), axis=(1, 2))
        message = ["" if a else "non-finite residuals or Jacobian at the start" for a in active]
        st = cls(
            U, r, jac, status, cost, np.zeros(S, bool), active, message, np.zeros(S, int),
            np.full(S, 1e-3), np.full(S, 2.0), np.sum(jac**2, axis=1),
        )  # fmt: skip
        for s in range(S):
            if st.active[s] and st.cost[s] == 0:
                st.stop(s, True, "zero cost")
            elif st.active[s] and not np.any(st.jac[s]):
                st.stop(s, False, _ZERO_JACOBIAN)
        return st

    def stop(self, s, ok, why) -> None:
        self.active[s] = False
        self.converged[s] = ok
        self.message[s] = why


def _trials(st: _Starts):
    """Each running start's trial point, its step and the cost reduction the linear model
    predicts (the stopped starts: their own point, a zero step)."""
    tiny = np.finfo(float).tiny
    trial = st.U.copy()
    steps = np.zeros_like(st.U)
    predicted = np.zeros(st.U.shape[0])
    for s in np.flatnonzero(st.active):
        st.d2[s] = np.maximum(st.d2[s], np.sum(st.jac[s] ** 2, axis=0))
        steps[s], predicted[s] = _step(st.jac[s], st.r[s], st.lam[s], np.maximum(st.d2[s], tiny))
        trial[s] = st.U[s] + steps[s]
    return trial, steps, predicted


def _judge(st: _Starts, s, trial, step, predicted, r_t, jac_t, status_t, rtol, atol) -> None:
    """Start ``s``'s trial accepted or rejected, its damping updated, and whether it stops
    (module docstring)."""
    tiny = np.finfo(float).tiny
    cost_t = 0.5 * float(np.sum(r_t**2))
    small = bool(np.all(np.abs(step) <= atol + rtol * np.abs(st.U[s])))
    finite = np.isfinite(cost_t) and np.all(np.isfinite(jac_t))
    rho = (st.cost[s] - cost_t) / predicted if predicted > 0 else -np.inf
    if finite and rho > _ACCEPT:
        reduction = (st.cost[s] - cost_t) / max(st.cost[s], tiny)
        st.U[s], st.r[s], st.jac[s], st.status[s] = trial, r_t, jac_t, status_t
        predicted_rel = predicted / max(st.cost[s], tiny)
        st.cost[s] = cost_t
        st.lam[s] *= max(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
        st.grow[s] = 2.0
        if cost_t == 0:
            st.stop(s, True, "zero cost")
        elif small:
            st.stop(s, True, "step below tolerance")
        elif reduction <= rtol and predicted_rel <= rtol:
            st.stop(s, True, "cost change below tolerance")
        elif not np.any(st.jac[s]):
            st.stop(s, False, _ZERO_JACOBIAN)
    else:
        st.lam[s] *= st.grow[s]
        st.grow[s] *= 2.0
        if small:
            st.stop(s, True, "no lower cost within the step tolerance")
        elif st.lam[s] > _MAX_DAMPING:
            st.stop(s, False, "no step lowers the cost (damping overflow)")
