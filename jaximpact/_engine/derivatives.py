"""Derivatives of a batch from forward mode through its own step loop: a custom JVP whose
rule computes each input's per-lane Jacobian column and sums them against the tangents
(linear in the tangents, so JAX transposes it for ``jax.grad``)."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_derivatives import SymbolicZero


def _differentiable(solve, solve_with_tangents):
    """``solve`` (inputs -> ``ImpactResult``, each lane a function of its own inputs), with
    derivatives from forward mode through the same step loop: ``solve_with_tangents``, the
    same integration in the program form used for derivatives (it also gives the values that
    come with derivatives).

    The rule computes, for every input leaf that carries a tangent, the per-lane Jacobian
    column ``d out / d x`` (:func:`_output_columns`), then returns ``sum_j column_j *
    tangent_j``. That is linear in the tangents with coefficients that depend on the primal
    values only, so JAX can transpose it: ``jax.grad`` (reverse mode) works on the
    forward-only ``lax.while_loop`` at the cost of one tangent solve per perturbed input (a
    few per impact: a scene's parameters and the impact's inputs)."""

    @jax.custom_jvp
    def run(inputs):
        return solve(inputs)

    @functools.partial(run.defjvp, symbolic_zeros=True)
    def run_jvp(primals, tangents):
        inputs, leaves, treedef, dleaves, moved = _rule_inputs(primals, tangents)
        if not moved:
            out = solve(inputs)
            return out, jax.tree_util.tree_map(_zero_tangent, out)
        out, columns = _output_columns(solve_with_tangents, leaves, treedef, moved)
        return out, _combine(out, columns, [dleaves[i] for i in moved])

    return run


def _rule_inputs(primals, tangents):
    """A JVP rule's ``(inputs, leaves, treedef, tangent leaves, moved)``: ``moved``, the
    indices of the input leaves that carry a tangent (not a symbolic zero)."""
    (inputs,), (dinputs,) = primals, tangents
    leaves, treedef = jax.tree_util.tree_flatten(inputs)
    dleaves = treedef.flatten_up_to(dinputs)
    moved = [i for i, d in enumerate(dleaves) if not isinstance(d, SymbolicZero)]
    return inputs, leaves, treedef, dleaves, moved


def _output_columns(solve_with_tangents, leaves, treedef, moved):
    """``(out, columns)``: the outputs and, stacked on a leading axis, their per-lane
    derivatives along each input leaf in ``moved`` (``jax.jvp`` along a ones-vector: lanes are
    independent, so one tangent solve gives the column of every lane)."""

    def of_moved(xs):
        full = list(leaves)
        for i, x in zip(moved, xs, strict=True):
            full[i] = x
        return solve_with_tangents(treedef.unflatten(full))

    xs = [leaves[i] for i in moved]
    basis = [
        [jnp.full_like(x, 1.0 if i == j else 0.0) for j, x in enumerate(xs)] for i in range(len(xs))
    ]
    basis = jax.tree_util.tree_map(lambda *b: jnp.stack(b), *basis)
    return jax.vmap(lambda t: jax.jvp(of_moved, (xs,), (t,)), out_axes=(None, 0))(basis)


def _combine(out, columns, dxs):
    """The outputs' tangents ``sum_j column_j * dx_j`` (zero for integer outputs)."""

    def combine(y, col):
        if not jnp.issubdtype(y.dtype, jnp.inexact):
            return _zero_tangent(y)
        acc = col[0] * dxs[0]
        for j in range(1, len(dxs)):
            acc = acc + col[j] * dxs[j]
        return acc

    return jax.tree_util.tree_map(combine, out, columns)


def _zero_tangent(y):
    if jnp.issubdtype(y.dtype, jnp.inexact):
        return jnp.zeros_like(y)
    return np.zeros(y.shape, jax.dtypes.float0)
