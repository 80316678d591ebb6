"""Choice of the diffrax solver and step-size controller from the scene's ``[solver]`` section."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .tsit5 import LaneTsit5


class RungeKuttaGill(diffrax.AbstractERK):
    """The classical 4th-order Runge-Kutta-Gill method (used by Brach & Dunn), fixed step only."""

    tableau = diffrax.ButcherTableau(
        c=np.array([0.5, 0.5, 1.0]),
        b_sol=np.array([1 / 6, (2 - np.sqrt(2)) / 6, (2 + np.sqrt(2)) / 6, 1 / 6]),
        b_error=np.zeros(4),
        a_lower=(
            np.array([0.5]),
            np.array([(np.sqrt(2) - 1) / 2, (2 - np.sqrt(2)) / 2]),
            np.array([0.0, -np.sqrt(2) / 2, 1 + np.sqrt(2) / 2]),
        ),
    )
    interpolation_cls = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

    def order(self, terms):
        return 4


# Numerical settings that keep derivatives right at the model's singular points (Hertz units;
# measured in BENCHMARKS.md, "Derivatives"). The overlap below which the contact is integrated
# in closed form: there the adhesion force grows like sqrt(n), whose infinite slope at n = 0
# left the derivatives of every adhesive rebound ~0.5 % off at any tolerance. Its effect on the
# outputs is of the order of the shell's share of the work, (f0 sqrt(r)) floor^1.5 ~ 1e-6.
CONTACT_FLOOR = 1e-4
# Rate of the linear pull toward rolling inside the slip width (see friction_force): fast
# against an impact (~3 Hertz times) yet slow enough for Tsit5's steps.
SLIP_RELAXATION = 20.0

# Width of the Mindlin spring's switch to slip, as a fraction of the Coulomb cap (see
# laws.mindlin_slip_rate): the spring force reaches the cap to about this fraction.
CAP_WIDTH = 1e-3

EXPLICIT = {"tsit5": LaneTsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8}
IMPLICIT = {"kvaerno3": diffrax.Kvaerno3, "kvaerno5": diffrax.Kvaerno5}


def default_tolerances(dtype, rtol, atol):
    """Tolerances by precision: float64 1e-10/1e-12, float32 5e-6/1e-7 (unless given).

    float64 at 1e-10 keeps the derivatives within ~1e-3 of finite differences of the exact
    reference on every scene type measured (at 1e-8 up to 8e-3 off, the outputs themselves
    ~2e-7: derivatives of a discretized solve converge more slowly than its values;
    BENCHMARKS.md, "Derivatives"). float32 at 5e-6 keeps ``cor_n`` of oblique spinning impacts
    within 3e-4 of the exact reference (1.5-1.7e-4 on 100 impacts; 3.0-3.1e-4 at 1e-5) for 5 %
    more steps (BENCHMARKS.md, "Loop kernels").
    """
    if jnp.finfo(dtype).bits >= 64:
        return (rtol or 1e-10), (atol or 1e-12)
    return (rtol or 5e-6), (atol or 1e-7)


def default_slip_width(dtype, slip_width, rtol=None):
    """Slip-sign regularization width (fraction of the normal speed) unless given.

    float64: ``max(3e-4, 100 rtol)``; float32: ``max(3e-3, 100 rtol)``, whose rounding noise in
    the slip would otherwise reach the steep part of the switch and cost many small steps.
    The width sets the error of an impact that passes from sliding to rolling under a rolling
    moment (about linear in the width: at 1e-3 derivatives up to 1.6e-3 off on lambda-law
    scenes, at 3e-4 8e-4, for 5 % more steps; BENCHMARKS.md, "Derivatives"). Below ~3e-4 the
    transition gets too sharp for the tangents at rtol 1e-10 (whose error the step-size control
    does not see). ``100 rtol`` keeps the width well above the solver's noise at loose
    tolerances (``auto`` turns implicit below ``30 rtol``).
    """
    if slip_width is not None:
        return slip_width
    rtol, _ = default_tolerances(dtype, rtol, None)
    floor = 3e-4 if jnp.finfo(dtype).bits >= 64 else 3e-3
    return max(floor, 100 * float(rtol))


def make_solver(method: str, dtype, stages: str = "per_state"):
    """The diffrax solver for ``method`` (``auto`` must be resolved before); ``stages``: the
    form of Tsit5's stage sums (``LaneTsit5.stages``)."""
    if method == "tsit5":
        return LaneTsit5(stages=stages)
    if method in EXPLICIT:
        return EXPLICIT[method]()
    if method == "rk4":
        return RungeKuttaGill()
    if method in IMPLICIT:
        tol = 1e3 * float(jnp.finfo(dtype).eps)
        return IMPLICIT[method](root_finder=optx.Chord(rtol=tol, atol=tol))
    raise ValueError(f"solver.method {method!r} cannot be used here")


class LanePIDController(diffrax.PIDController):
    """diffrax's PID controller with each new step size rounded to 24 significant bits.

    The step-size arithmetic (powers of the error ratio, fused differently by XLA for different
    batch shapes) can differ in the last bit between a lane alone and the same lane in a batch,
    and an adaptive solve amplifies that into a different sequence of steps. Rounding the step
    to a coarse binary grid makes such one-ulp differences vanish (unless a step lands within
    1e-16 of a grid point, about once in 1e8 steps) and changes nothing else: a step 6e-8 shorter
    or longer than the controller's choice.
    """

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order, state):
        keep, next_t0, next_t1, jump, state, result = super().adapt_step_size(
            t0, t1, y0, y1_candidate, args, y_error, error_order, state
        )
        mantissa, exponent = jnp.frexp(jax.lax.stop_gradient(next_t1 - next_t0))
        dt = jnp.ldexp(jnp.round(mantissa * 2.0**24) / 2.0**24, exponent)
        return keep, next_t0, next_t0 + dt, jump, state, result


def make_controller(method, rtol, atol, dt, norm):
    if method == "rk4":
        return diffrax.ConstantStepSize(), dt
    return LanePIDController(rtol=rtol, atol=atol, norm=norm), 1e-2
