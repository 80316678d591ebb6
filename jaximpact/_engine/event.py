"""Where in its last step an impact ends: a scalar root find with an exact derivative.

The step loop stops after the step in which the event function (overlap above the contact
floor, or the scaled normal energy) changed sign; :func:`locate` finds the crossing time on
the step's dense output. Each lane iterates on its own (a bracketed Newton iteration that
falls back to bisection), so a lane's bits do not depend on its batch, and the iteration runs
on values without tangents. The derivative of the crossing time then comes from the
implicit-function theorem, ``dT = -(dg/dtheta) / (dg/dt)`` at the root, which is the exact
derivative of the discrete solution's crossing.
"""

import jax
import jax.numpy as jnp

# Enough iterations for bisection alone to shrink any step to the tolerance in float64.
MAX_ITERATIONS = 64


def locate(path, event, lower, upper, rtol, atol, *, search=None):
    """The crossing of ``event(t, path(t))`` (decreasing through zero) in ``[lower, upper]``.

    Arguments:
        path: ``t -> y``, the state along the step (its dense output).
        event: ``(t, y) -> scalar``.
        lower, upper: the step.
        rtol, atol: converged when the last change of ``t`` is below ``atol + rtol |t|`` and
            ``|event| <= atol``, or when the bracket is that narrow.
        search: ``(path, event)`` built from the same data with its derivatives stopped
            (``lax.stop_gradient``), for the iteration. Then no tangent enters the iteration's
            loop, and JAX neither differentiates it nor batches it over tangent directions
            (the fit's program: about 1 s less tracing). Default: ``path`` and ``event``.

    Returns:
        ``(t, y, found)``: the crossing time, the state there and whether the iteration
        converged. ``path`` and ``event`` may close over differentiated values: ``t`` and ``y``
        carry their derivatives (``y``'s through ``t`` as well).

    Newton's iterate is taken where it falls inside the bracket, the bracket's midpoint
    otherwise (a grazing capture crosses with almost no slope).
    """
    frozen = jax.lax.stop_gradient

    search_path, search_event = (path, event) if search is None else search

    def along(t, path=path, event=event):  # value and time derivative of the event, the state
        y, y_dot = jax.jvp(path, (t,), (jnp.ones_like(t),))
        value, slope = jax.jvp(event, (t, y), (jnp.ones_like(t), y_dot))
        return value, slope, y, y_dot

    def small(dt, t):
        return jnp.abs(dt) <= atol + rtol * jnp.abs(t)

    def body(state):
        t, lo, hi, _, _, i = state
        value, slope, _, _ = frozen(along(t, search_path, search_event))  # no tangents
        before = value > 0  # the root is later than t
        lo, hi = jnp.where(before, t, lo), jnp.where(before, hi, t)
        newton = t - value / slope
        inside = jnp.isfinite(newton) & (newton > lo) & (newton < hi)
        t_new = jnp.where(inside, newton, 0.5 * (lo + hi))
        converged = (small(t_new - t, t) & (jnp.abs(value) <= atol)) | small(hi - lo, t)
        converged = converged | (value == 0)
        t_new = jnp.where(value == 0, t, t_new)
        return t_new, lo, hi, converged, jnp.isfinite(value), i + 1

    def running(state):
        _, _, _, converged, finite, i = state
        return ~converged & finite & (i < MAX_ITERATIONS)

    lower, upper = frozen(lower), frozen(upper)
    start = (upper, lower, upper, jnp.zeros((), bool), jnp.ones((), bool), 0)
    t, _, _, converged, _, _ = jax.lax.while_loop(running, body, start)
    # The implicit-function derivative: the primal values are t and y(t) themselves
    # (value - frozen(value) is exactly 0); the tangents are dt = -d value / (d value / dt)
    # and dy + y' dt.
    value, slope, y, y_dot = along(t)
    slope = frozen(slope)
    shift = -(value - frozen(value)) / jnp.where(slope != 0, slope, 1.0)
    y = jax.tree_util.tree_map(lambda a, b: a + frozen(b) * shift, y, y_dot)
    return t + shift, y, converged
