"""Tsitouras' 5(4) Runge-Kutta pair whose every lane gives the same bits in any batch.

``diffrax.Tsit5`` forms its stage sums and its dense output with ``jnp.tensordot`` over the
stacked stages. Under ``vmap`` that becomes a matrix product whose summation order (and so its
rounding) depends on the batch size, and an adaptive solve turns a one-ulp difference into a
different sequence of accepted steps: outputs then moved by ~1e-6 and derivatives by up to a
factor 6 with what else was in the batch (issue 10). Here every sum is written out term by
term, in a fixed order, with elementwise operations only, so a lane's arithmetic is the same
whatever the batch (checked in tests/test_derivatives.py: alone, batched, shuffled, sharded).

Two forms of the same arithmetic (``LaneTsit5.stages``), each batch-independent, not bitwise
equal to each other (XLA fuses them differently); measured in BENCHMARKS.md:

- ``"per_state"`` (default): the sums run per state variable, on arrays of one value per
  lane: no concatenations and slices between stages. Against the state flattened into one
  array per stage (the form before issue 12): 1.9x the impacts per CPU-second at 20,000
  lanes, 2.1x at 1,000, 1.8x at 100, and within 10 % on the fit's and the sampler's small
  forward-mode batches. XLA's CPU code vectorizes these arrays along the lanes, and lanes
  left over after the last full SIMD vector take a scalar path whose rounding can differ
  (measured: one lane of 5 or 13 moved, none of any multiple of 4): ``simulate`` therefore
  pads every batch to a multiple of :func:`lane_group` lanes per device and chunk.
- ``"loop"``: the state flattened per stage, and the six stages in a ``lax.fori_loop``, so
  the vector field is traced and compiled once instead of six times: half the compile time
  (the 25-impact fit: tracing 6.5 -> 4.1 s, XLA 10.5 -> 4.9 s) for about 2x the time per
  call. For one-off work that compiling dominates (``simulate(program="compact")``).

The method is Tsit5 itself (same tableau, same embedded error estimate, same 4th-order dense
output), so accuracy and step counts match ``diffrax.Tsit5``. Only ODE terms are supported.
"""

from collections.abc import Callable
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.tree_util as jtu
import numpy as np
from jax.flatten_util import ravel_pytree

_TABLEAU = diffrax.Tsit5.tableau
# The tableau as arrays for the stage loop: row i gives stage i + 1 from stages 0..5 (zeros
# past the diagonal: adding an exact 0 * 0 leaves a finite sum's bits unchanged).
_A = np.zeros((6, 6))
for _i, _row in enumerate(_TABLEAU.a_lower):
    _A[_i, : len(_row)] = _row
_C = np.array([float(c) for c in _TABLEAU.c])

STAGE_FORMS = ("per_state", "loop")


def lane_group(dtype, stages="per_state") -> int:
    """Lanes per device and chunk are a multiple of this: in the ``per_state`` form a 512-bit
    vector of ``dtype``, so every lane takes the vectorized path (module docstring); 1 in the
    ``loop`` form."""
    return 64 // jnp.dtype(dtype).itemsize if stages == "per_state" else 1


# Dense output of Tsitouras (2011): y(t0 + theta h) = y0 + h sum_i b_i(theta) k_i with
# b_i(theta) = sum_j R[i][j] theta^(j+1) (the continuous extension's coefficients, as published
# and as used by OrdinaryDiffEq.jl; tests check them against diffrax.Tsit5's interpolation).
_DENSE = (
    (1.0, -2.763706197274826, 2.9132554618219126, -1.0530884977290216),
    (0.0, 0.13169999999999998, -0.2234, 0.1017),
    (0.0, 3.9302962368947516, -5.941033872131505, 2.490627285651253),
    (0.0, -12.411077166933676, 30.33818863028232, -16.548102889244902),
    (0.0, 37.50931341651104, -88.1789048947664, 47.37952196281928),
    (0.0, -27.896526289197286, 65.09189467479366, -34.87065786149661),
    (0.0, 1.5, -4.0, 2.5),
)


def _combine(weights, ks):
    """``sum_i weights[i] * ks[i]``, one term at a time, in index order (arrays).

    Zero weights are skipped (they are exact zeros of the tableau, known in Python)."""
    acc = None
    for c, k in zip(weights, ks, strict=True):
        if isinstance(c, float) and c == 0.0:
            continue
        acc = c * k if acc is None else acc + c * k
    return acc


class LaneTsit5Interpolation(diffrax.AbstractLocalInterpolation):
    """Tsit5's 4th-order dense output, summed term by term (used to locate events)."""

    t0: float
    t1: float
    y0: dict
    k: object  # the 7 stages: a tuple of state pytrees (per_state), or (7, states) (loop)

    def __init__(self, *, t0, t1, y0, y1, k):
        del y1  # diffrax passes it; the dense output does not need it
        self.t0, self.t1, self.y0, self.k = t0, t1, y0, k

    def evaluate(self, t0, t1=None, left=True):
        del left
        if t1 is not None:
            return jtu.tree_map(lambda a, b: b - a, self.evaluate(t0), self.evaluate(t1))
        h = self.t1 - self.t0
        theta = jnp.asarray((t0 - self.t0) / h)  # an array: no weight is skipped as a zero
        # Horner in theta for each b_i(theta), then the sum over stages in a fixed order.
        weights = [
            theta * (r1 + theta * (r2 + theta * (r3 + theta * r4))) for r1, r2, r3, r4 in _DENSE
        ]
        if isinstance(self.k, tuple):  # per_state
            return jtu.tree_map(lambda y, *k: y + h * _combine(weights, list(k)), self.y0, *self.k)
        y0, unravel = ravel_pytree(self.y0)
        return unravel(y0 + h * _combine(weights, [self.k[i] for i in range(7)]))


class LaneTsit5(diffrax.AbstractAdaptiveSolver):
    """``diffrax.Tsit5`` with batch-independent arithmetic (see the module docstring).

    ``stages``: ``"per_state"`` (default) or ``"loop"`` (see the module docstring).
    """

    term_structure: ClassVar = diffrax.AbstractTerm
    interpolation_cls: ClassVar[Callable[..., LaneTsit5Interpolation]] = LaneTsit5Interpolation
    stages: str = eqx.field(static=True, default="per_state")

    def __check_init__(self):
        if self.stages not in STAGE_FORMS:
            raise ValueError(f"stages must be one of {STAGE_FORMS}, got {self.stages!r}")

    def order(self, terms):
        return 5

    def error_order(self, terms):
        return 5

    def init(self, terms, t0, t1, y0, args):
        k0 = terms.vf(t0, y0, args)  # first stage, reused (FSAL)
        return k0 if self.stages == "per_state" else ravel_pytree(k0)[0]

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        # made_jump is never true here: simulate passes no jump times or discontinuities.
        del made_jump
        if self.stages == "loop":
            return self._step_in_loop(terms, t0, t1, y0, args, solver_state)
        h = t1 - t0
        ks = [solver_state]
        for c, a_row in zip(_TABLEAU.c, _TABLEAU.a_lower, strict=True):
            weights = [float(a) for a in a_row]
            stage = jtu.tree_map(lambda y, *k, w=weights: y + h * _combine(w, list(k)), y0, *ks)
            ks.append(terms.vf(t0 + float(c) * h, stage, args))
        b_error = [float(b) for b in _TABLEAU.b_error]
        y_error = jtu.tree_map(lambda *k: h * _combine(b_error, list(k)), *ks)
        dense_info = dict(y0=y0, y1=stage, k=tuple(ks))  # the last stage's point is y1
        return stage, y_error, dense_info, ks[-1], diffrax.RESULTS.successful

    def _step_in_loop(self, terms, t0, t1, y0, args, k0):
        """``step`` with the stages in a loop (``loop``): same sums, same order."""
        h = t1 - t0
        flat0, unravel = ravel_pytree(y0)
        a_tab, c_tab = jnp.asarray(_A, flat0.dtype), jnp.asarray(_C, flat0.dtype)

        def stage_sum(a, ks):
            return _combine([a[j] for j in range(6)], [ks[j] for j in range(6)])

        def add_stage(i, ks):
            stage = flat0 + h * stage_sum(a_tab[i], ks)
            k = ravel_pytree(terms.vf(t0 + c_tab[i] * h, unravel(stage), args))[0]
            return ks.at[i + 1].set(k)

        ks = jnp.zeros((7, *flat0.shape), flat0.dtype).at[0].set(k0)
        ks = jax.lax.fori_loop(0, 6, add_stage, ks)
        y1 = unravel(flat0 + h * stage_sum(a_tab[5], ks))  # the last stage's point is y1
        error = _combine([float(b) for b in _TABLEAU.b_error], [ks[i] for i in range(7)])
        dense_info = dict(y0=y0, y1=y1, k=ks)
        return y1, unravel(h * error), dense_info, ks[6], diffrax.RESULTS.successful

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)
