"""The compiled programs of a batch: ``_solve_flat`` jitted per set of XLA options, or loaded
from the traced-program cache (``jaximpact._io.cache.compiled_program``) where the inputs are
concrete, values and derivatives alike."""

import collections
import dataclasses
import functools

import equinox as eqx
import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero

from .batch import _lean_method, _solve_batch, _solve_flat
from .derivatives import _combine, _output_columns, _rule_inputs, _zero_tangent
from .devices import compiled_alone, compiler_options, under_trace
from .results import ImpactResult
from .settings import PROGRAMS


def _simulate_flat(terms, cfg, *args, **kwargs):
    """:func:`_solve_flat`, compiled and cached; inlined where the caller is being traced
    under ``jax.jit`` already. A nested jit would make JAX trace the batch three times more
    than needed under ``jax.jacfwd``: the primal of :func:`_differentiable`'s custom JVP, and
    the whole tangent program again to batch it over the tangent directions, which act on
    the rule's last sums only (measured on the fit's program: tracing 3.4 against 6.1 s)."""
    if under_trace():
        return _solve_flat(terms, cfg, *args, **kwargs)
    # XLA options only on a program of its own (JAX refuses them on a nested jit)
    alone = compiled_alone(args)
    options = compiler_options(throughput=cfg.stages == "per_state") if alone else {}
    cached = bool(jax.config.jax_compilation_cache_dir)
    if alone and cached:
        return _from_program_cache(terms, cfg, options, *args, **kwargs)
    key = tuple(sorted(options.items()))
    if key not in _SOLVE_FLAT_JIT:
        _SOLVE_FLAT_JIT[key] = eqx.filter_jit(_solve_flat, compiler_options=options or None)
    jitted = functools.partial(_SOLVE_FLAT_JIT[key], terms, cfg)
    if cached and kwargs.get("loop") != "diffrax" and _lean_method(cfg):
        return _eagerly_differentiated(terms, cfg, jitted, *args, **kwargs)
    return jitted(*args, **kwargs)


def _eagerly_differentiated(
    terms, cfg, jitted, params, speed, angle_deg, omega0, adjoint=None, **settings
):
    """The batch under a transformation outside ``jax.jit`` (a user's ``jax.grad`` or
    ``jax.jacfwd`` of ``simulate``), with the derivatives of :func:`_differentiable` from
    programs of the traced-program cache where the primal inputs are concrete (they are under
    ``grad``, ``jacfwd`` and ``jacrev`` called eagerly): a warm process then loads the value
    and tangent programs instead of tracing the tangent program again (about 3 s). The same
    functions as the ``jitted`` path, so the same values and derivatives; other
    transformations (``vmap``, higher derivatives) take the ``jitted`` path."""

    def plain(inputs):
        return jitted(*inputs, adjoint, **settings)

    def concrete(inputs):
        return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(inputs))

    @jax.custom_jvp
    def run(inputs):
        if concrete(inputs):
            options = compiler_options(throughput=cfg.stages == "per_state")
            return _from_program_cache(terms, cfg, options, *inputs, adjoint, **settings)
        return plain(inputs)

    @functools.partial(run.defjvp, symbolic_zeros=True)
    def run_jvp(primals, tangents):
        inputs, leaves, treedef, dleaves, moved = _rule_inputs(primals, tangents)
        if not concrete(inputs):
            dleaves = [
                jnp.zeros(x.shape, x.dtype) if isinstance(d, SymbolicZero) else d
                for x, d in zip(leaves, dleaves, strict=True)
            ]
            return jax.jvp(plain, (inputs,), (treedef.unflatten(dleaves),))
        if not moved:
            out = run(inputs)
            return out, jax.tree_util.tree_map(_zero_tangent, out)
        program = _tangent_program(terms, cfg, leaves, treedef, moved, settings)
        values, columns = program(*leaves)
        out = ImpactResult(**values)
        dxs = [dleaves[i] for i in moved]
        # (the last sums of ``_differentiable``'s rule, on the program's columns)
        columns = ImpactResult(**{f: columns.get(f, v) for f, v in values.items()})
        return out, _combine(out, columns, dxs)

    return run((params, speed, angle_deg, omega0))


def _tangent_program(terms, cfg, leaves, treedef, moved, settings):
    """The compiled program of :func:`_differentiable`'s tangent solve for concrete inputs
    (``leaves`` of ``treedef``, tangents along ``moved``): ``(values, columns)``, dicts by
    ``ImpactResult`` field (columns of the float fields only), through the traced-program
    cache (``jaximpact._io.cache.compiled_program``)."""
    from .._io.cache import compiled_program

    example = [jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding) for x in leaves]
    options = compiler_options()
    settings = dict(sorted(settings.items()))
    key = repr((terms, cfg, settings, sorted(options.items()), jax.local_devices(), treedef, moved))
    memo = ("tangents", key, repr(example))
    if memo not in _CACHED_PROGRAMS:
        compact = dataclasses.replace(cfg, stages=PROGRAMS["compact"])
        solve_with_tangents = functools.partial(
            _solve_batch,
            terms,
            compact,
            settings.get("chunk"),
            settings.get("shards", 1),
            settings.get("loop", "lean"),
            None,
        )

        def tangents(*xs):
            # as in ``_solve_flat``: XLA must not see that lanes repeat
            xs = [jax.lax.optimization_barrier(x) for x in xs]
            out, cols = _output_columns(solve_with_tangents, xs, treedef, moved)
            fields = tuple(ImpactResult.__dataclass_fields__)
            values = {f: getattr(out, f) for f in fields if getattr(out, f) is not None}
            floats = [f for f in values if jnp.issubdtype(values[f].dtype, jnp.inexact)]
            return values, {f: getattr(cols, f) for f in floats}

        _CACHED_PROGRAMS[memo], _ = compiled_program(
            "tangents", tangents, example, key, options or None
        )
        while len(_CACHED_PROGRAMS) > _CACHED_PROGRAMS_KEPT:
            _CACHED_PROGRAMS.popitem(last=False)
    _CACHED_PROGRAMS.move_to_end(memo)
    return _CACHED_PROGRAMS[memo]


# ``_solve_flat`` compiled with each set of XLA options (``compiler_options``), made on first use
_SOLVE_FLAT_JIT: dict = {}
# Concrete batches' programs of this process, by settings and input shapes and shardings (the
# most recently used few).
_CACHED_PROGRAMS: collections.OrderedDict = collections.OrderedDict()
_CACHED_PROGRAMS_KEPT = 32


def _from_program_cache(
    terms, cfg, options, params, speed, angle_deg, omega0, adjoint=None, **settings
):
    """:func:`_solve_flat` on concrete inputs through the traced-program cache
    (``jaximpact._io.cache.compiled_program``): a process whose compilation cache already
    holds this batch's program loads it instead of tracing and lowering it again (about 2 s of
    a warm process's first ``simulate``). The same program as the ``jit`` path (the same
    function traced at the same shapes), so the same bits; values only (a traced input never
    comes here)."""
    from .._io.cache import compiled_program

    inputs = (params, speed, angle_deg, omega0)
    example = jax.tree_util.tree_map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding), inputs
    )
    settings = dict(sorted(settings.items()))
    key = repr((terms, cfg, adjoint, settings, sorted(options.items()), jax.local_devices()))
    memo = (key, repr(example))
    if memo not in _CACHED_PROGRAMS:
        fields = tuple(ImpactResult.__dataclass_fields__)

        def solve(params, speed, angle_deg, omega0):
            r = _solve_flat(terms, cfg, params, speed, angle_deg, omega0, adjoint, **settings)
            return tuple(getattr(r, f) for f in fields)

        program, _ = compiled_program("simulate", solve, example, key, options or None)
        _CACHED_PROGRAMS[memo] = (program, fields)
        while len(_CACHED_PROGRAMS) > _CACHED_PROGRAMS_KEPT:
            _CACHED_PROGRAMS.popitem(last=False)
    _CACHED_PROGRAMS.move_to_end(memo)
    program, fields = _CACHED_PROGRAMS[memo]
    return ImpactResult(**dict(zip(fields, program(*inputs), strict=True)))
