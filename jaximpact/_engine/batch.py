"""A batch of impacts (1-D inputs) in one program: vmapped, in chunks one after another,
split over devices, or in a pool of lanes refilled as impacts finish; differentiable through
the lean step loop (:mod:`.derivatives`)."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from . import step_loop
from .derivatives import _differentiable
from .impact import T_MAX, _lean_supported, _outputs, _problem, _solve_one
from .settings import PROGRAMS, Integration
from .tsit5 import lane_group

# The pooled lean loop's tail: once no impact is left to start and at most 1/TAIL_FRACTION of
# the lanes still run, they go on in that many lanes (``step_loop.solve_pool``).
TAIL_FRACTION = 16


def _solve_flat(
    terms, cfg, params, speed, angle_deg, omega0, adjoint=None, chunk=None, shards=1, loop="lean"
):
    """The batch of impacts (1-D inputs): :func:`_solve_batch`, differentiable.

    On the lean loop (``loop`` ``"lean"`` or ``"pool"``, explicit adaptive solvers), values and
    derivatives come from that loop (:func:`_differentiable`); ``loop="diffrax"`` (and every
    solver the lean loop does not handle) differentiates ``diffeqsolve`` with ``adjoint``.
    """
    inputs = (params, speed, angle_deg, omega0)
    # XLA must not see that lanes repeat (the padding copies, a scene parameter broadcast over
    # the batch): it would compute such values once, as scalars, and the rounding of scalar
    # and vector arithmetic differ (FMA contraction follows the fusion).
    # One barrier per leaf: under autodiff a joint barrier would give every input a tangent.
    inputs = jax.tree_util.tree_map(jax.lax.optimization_barrier, inputs)
    if loop == "diffrax" or not _lean_method(cfg):
        return _solve_batch(terms, cfg, chunk, shards, "diffrax", adjoint, inputs)
    solve = functools.partial(_solve_batch, terms, cfg, chunk, shards, loop, None)
    # Derivatives take Tsit5's stages in a loop (the compact program) whatever the program of
    # the values: the tangent program of the unrolled stages compiles 4x slower (measured:
    # 64 against 16 s for output_jacobian) and runs no faster on a fit's batch.
    compact = dataclasses.replace(cfg, stages=PROGRAMS["compact"])
    solve_with_tangents = functools.partial(_solve_batch, terms, compact, chunk, shards, loop, None)
    return _differentiable(solve, solve_with_tangents)(inputs)


def _lean_method(cfg: Integration) -> bool:
    """Whether the lean step loop runs this method (explicit, adaptive, PID-controlled)."""
    return cfg.method in ("tsit5", "dopri5", "dopri8")


def _solve_batch(terms, cfg, chunk, shards, loop, adjoint, inputs):
    """The batch of impacts (1-D inputs), vmapped; with ``chunk``, in chunks one after another.

    ``chunk``: at most this many lanes per device in one vmapped solve. A larger batch becomes
    ``n`` equal chunks (the last padded with copies of a real lane) that ``lax.map`` solves one
    after another inside the compiled program. A lane's arithmetic does not depend on its chunk
    (every operation is elementwise over lanes, and a chunk holds at least 2 lanes), so outputs
    and step counts are bitwise those of the unchunked batch. ``shards``: the batch is split in
    that many contiguous parts, one per device (``_shard_over_devices``), each solved on its
    device as a batch of its own. ``loop``: see ``_solve_one``.
    """
    if shards > 1:
        # Each device solves its part on its own (``shard_map``): as one partitioned program
        # every step waited for an all-reduce of "any lane still running" over the devices
        # (measured on 2 CPU devices, 20,000 impacts: 22,400 against 19,400 impacts/s).
        per_device = functools.partial(_solve_batch, terms, cfg, chunk, 1, loop, adjoint)
        # (check_vma=False: the loops' carries start from constants that JAX's type check
        # would want cast to per-device values; nothing here crosses devices.)
        spec = jax.sharding.PartitionSpec("batch")
        return jax.shard_map(
            per_device, mesh=_batch_mesh(), in_specs=spec, out_specs=spec, check_vma=False
        )(inputs)
    params, speed, angle_deg, omega0 = inputs
    solve = lambda xs: jax.vmap(  # noqa: E731
        lambda prm, s, a, w: _solve_one(terms, cfg, prm, s, a, w, adjoint, loop)
    )(*xs)
    size = speed.shape[0]
    if not _lean_method(cfg) and size <= IMPLICIT_MAPPED_LANES:
        # A few impacts of an implicit method one after another: tracing diffrax's implicit
        # stages, root finds and event under vmap doubles the tracing (Kvaerno5, 3 impacts:
        # first call 12.4 s against 19.2 s), at about 5x the run time per impact.
        solve = lambda xs: jax.lax.map(  # noqa: E731
            lambda x: _solve_one(terms, cfg, *x, adjoint, loop), xs
        )
    # lanes per chunk: the chunks as equal as can be, whole lane groups (per_state)
    group = lane_group(speed.dtype, cfg.stages)
    n_chunks = -(-size // chunk) if chunk else 1
    width = min(-(-size // (n_chunks * group)) * group, size)
    first = jax.tree_util.tree_map(lambda x: x[0], inputs)
    if loop == "pool" and chunk and _lean_supported(_problem(terms, cfg, *first)):
        # lanes that take the next impact as theirs finish (``step_loop.solve_pool``; which
        # batches get it: ``default_loop``)
        tail = -(-width // (TAIL_FRACTION * group)) * group
        return _solve_pooled(terms, cfg, inputs, width, tail)
    if not chunk or size <= chunk:
        return solve(inputs)
    n_chunks = -(-size // width)
    pad = n_chunks * width - size

    def split(x):  # (size,) -> (n_chunks, width)
        return jnp.pad(x, (0, pad), mode="edge").reshape(n_chunks, width)

    out = jax.lax.map(solve, jax.tree_util.tree_map(split, inputs))
    return jax.tree_util.tree_map(lambda y: y.reshape(-1)[:size], out)


def _solve_pooled(terms, cfg, inputs, lanes, tail_lanes):
    """``_solve_one`` (lean loop) on a 1-D batch, with ``lanes`` lanes refilled from the batch
    (``step_loop.solve_pool``). Every impact starts through the pool's one refill code, so its
    bits do not depend on the batch, its place in it or the chunk size; they are not bitwise
    the vmapped lean loop's (in float32, 13 of 4,000 slow impacts took another step sequence
    after a last-bit difference in their first stage: another fusion of the same arithmetic)."""

    def initial(prm, s, a, w):
        prob = _problem(terms, cfg, prm, s, a, w)
        return prob.y0, prob.p

    def outputs(prm, s, a, w, sol):
        return _outputs(terms, _problem(terms, cfg, prm, s, a, w), s, w, sol)

    y0s, args = jax.vmap(initial)(*inputs)
    prob = _problem(terms, cfg, *jax.tree_util.tree_map(lambda x: x[0], inputs))
    sols = step_loop.solve_pool(
        prob.term,
        prob.solver,
        0.0,
        T_MAX,
        prob.dt0,
        y0s,
        args,
        event=prob.event,
        stepsize_controller=prob.controller,
        max_steps=cfg.max_steps,
        lanes=lanes,
        tail_lanes=tail_lanes,
    )
    return jax.vmap(outputs)(*inputs, sols)


# Batches of an implicit method (Kvaerno5) of at most this many impacts are solved one impact
# after another (``lax.map``) instead of vmapped: a few impacts' first call compiles in about
# 2/3 of the time (BENCHMARKS.md, "First result"), for about 80 ms per impact instead of 15
# (Table 1, 0.3-3 m/s). Implicit solves are not batch-exact either way (docs/open_points.md).
IMPLICIT_MAPPED_LANES = 16


def _batch_mesh():
    """The local devices as a 1-D mesh over the batch axis."""
    return jax.sharding.Mesh(np.array(jax.local_devices()), ("batch",))
