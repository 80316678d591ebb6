"""Numerically safe elementary functions and the smooth switches of the model.

Every function here has a finite value, gradient and Hessian at the points where the physics
has a kink or a root singularity (first touch ``n = 0``, turning point ``ndot = 0``, rolling
``s = 0``). ``jnp.sqrt(jnp.maximum(x, 0))`` alone has an infinite derivative at 0 and turns
into NaN gradients through ``jnp.where``; the "double where" below masks the input as well.
"""

import jax.numpy as jnp


def safe_sqrt(x):
    """``sqrt(max(x, 0))`` whose derivatives are 0 (not inf/NaN) for ``x <= 0``."""
    positive = x > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, x, 1.0)), 0.0)


def safe_pow(x, p):
    """``max(x, 0) ** p`` for ``p > 0`` with derivatives that are 0 for ``x <= 0``.

    Half-integer powers (the Hertz laws' 0.5, 1.5, 2.5) are computed as ``x^k sqrt(x)``: one
    shared square root instead of an ``exp(p log x)`` per law, a large saving in the ODE.
    """
    k = p - 0.5
    if float(k).is_integer() and k >= 0:
        return safe_sqrt(x) * jnp.maximum(x, 0.0) ** int(k)
    positive = x > 0
    return jnp.where(positive, jnp.where(positive, x, 1.0) ** p, 0.0)


def smooth_sign_flat(z):
    """Odd smooth sign with a flat zero: ``sign(z) * tanh(z**2)``.

    It equals ``sign(z)`` to 1e-7 for ``|z| > 3`` and behaves as ``z|z|`` near 0. The flat zero
    (zero slope at ``z = 0``) is what keeps the regularized friction law from being stiff
    during pure rolling: the slip relaxes algebraically instead of through a fast exponential.
    """
    return jnp.sign(z) * jnp.tanh(z * z)


def smooth_step_flat(z):
    """Even companion of :func:`smooth_sign_flat`: ``tanh(z**2)``, 0 at 0, 1 for large ``|z|``."""
    return jnp.tanh(z * z)
