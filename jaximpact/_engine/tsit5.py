"""Tsitouras' 5(4) Runge-Kutta pair whose every lane gives the same bits in any batch.

Every stage sum is written out term by term, elementwise, so a lane's arithmetic does not
depend on the batch; the two forms of the sums and why: docs/engine.md."""

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
    vector of ``dtype``, so every lane takes the vectorized path (docs/engine.md); 1 in the
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
    """``diffrax.Tsit5`` with batch-independent arithmetic (docs/engine.md).

    ``stages``: ``"per_state"`` (default) or ``"loop"`` (docs/engine.md).
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

    def empty_dense_info(self, y0):
        """Zeros shaped as ``step``'s dense output at state ``y0`` (no vector field traced)."""
        zeros = jtu.tree_map(jnp.zeros_like, y0)
        if self.stages == "loop":
            flat = ravel_pytree(y0)[0]
            return dict(y0=zeros, y1=zeros, k=jnp.zeros((7, *flat.shape), flat.dtype))
        return dict(y0=zeros, y1=zeros, k=tuple(zeros for _ in range(7)))

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)
