"""Choice of the diffrax solver and step-size controller from the scene's ``[solver]`` section."""

import diffrax
import jax.numpy as jnp
import numpy as np
import optimistix as optx


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


EXPLICIT = {"tsit5": diffrax.Tsit5, "dopri5": diffrax.Dopri5, "dopri8": diffrax.Dopri8}
IMPLICIT = {"kvaerno3": diffrax.Kvaerno3, "kvaerno5": diffrax.Kvaerno5}


def default_tolerances(dtype, rtol, atol):
    """Tolerances by precision: float64 1e-8/1e-10, float32 1e-5/1e-7 (unless given).

    float64 at 1e-8 keeps the outputs within ~4e-6 of the exact switched reference and closes
    the energy ledger to ~1e-6 (measured, see BENCHMARKS.md).
    """
    if jnp.finfo(dtype).bits >= 64:
        return (rtol or 1e-8), (atol or 1e-10)
    return (rtol or 1e-5), (atol or 1e-7)


def default_slip_width(dtype, slip_width):
    """Slip-sign regularization width: 1e-3 (float64) or 3e-3 (float32) unless given."""
    if slip_width is not None:
        return slip_width
    return 1e-3 if jnp.finfo(dtype).bits >= 64 else 3e-3


def make_solver(method: str, dtype):
    """The diffrax solver for ``method`` (``auto`` must be resolved before)."""
    if method in EXPLICIT:
        return EXPLICIT[method]()
    if method == "rk4":
        return RungeKuttaGill()
    if method in IMPLICIT:
        tol = 1e3 * float(jnp.finfo(dtype).eps)
        return IMPLICIT[method](root_finder=optx.Chord(rtol=tol, atol=tol))
    raise ValueError(f"solver.method {method!r} cannot be used here")


def make_controller(method, rtol, atol, dt, norm):
    if method == "rk4":
        return diffrax.ConstantStepSize(), dt
    return diffrax.PIDController(rtol=rtol, atol=atol, norm=norm), 1e-2
