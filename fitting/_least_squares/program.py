"""The fit's one compiled program: residuals and their Jacobian at a batch of points,
``U -> (r, J, status)``, compiled once per objective, batch size and mode
(design notes: docs/fitting_program.md)."""

from __future__ import annotations

import sys
import time
from collections import OrderedDict

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from jaximpact._engine.devices import compiler_options
from jaximpact._io.cache import compiled_program, runtime_checks_as_nan

from .objective import Objective
from .transforms import to_physical

__all__ = ["JACOBIAN_MODES", "ResidualProgram"]

JACOBIAN_MODES = ("fwd", "rev")

# Compiled programs of this process: key -> (compiled, source); at most _MEMORY_SIZE.
_MEMORY: OrderedDict = OrderedDict()
_MEMORY_SIZE = 4


class ResidualProgram:
    """Residuals, Jacobian and status at ``starts`` points, as one compiled program.

    **Arguments:**
    - `objective`: the `Objective`.
    - `starts`: the batch size (number of points evaluated per call).
    - `jacobian`: ``"fwd"`` (default) or ``"rev"``.
    - `program`: the simulator's program (``jaximpact.simulate(program=...)``): ``"compact"``
      (default) compiles in half the time for about 2x the time per call, the right trade for
      a fit's tens of calls; a sampler's thousands of calls want ``"throughput"``.

    Call :meth:`compile` once (it reports what it did on stderr when asked), then call the
    instance with a ``(starts, p)`` array as often as needed: it never traces or compiles
    again. :attr:`stats` counts traces, compilations and calls.
    """

    def __init__(
        self,
        objective: Objective,
        starts: int,
        *,
        jacobian: str = "fwd",
        program: str = "compact",
    ):
        if jacobian not in JACOBIAN_MODES:
            raise ValueError(f"jacobian must be one of {JACOBIAN_MODES}, got {jacobian!r}")
        self.objective = objective
        self.names = objective.params
        self.starts = int(starts)
        self.jacobian = jacobian
        self.simulator_program = program
        self.stats = {"traces": 0, "compiles": 0, "calls": 0, "source": None}
        self.compile_seconds = 0.0
        self._compiled = None

    # -- the computation ------------------------------------------------------------------

    def _one_start(self, u, value, scale):
        """``(r, J, status)`` at one point ``u`` (traced once, inside the batch's vmap)."""
        self.stats["traces"] += 1
        objective, names = self.objective, self.names
        adjoint = diffrax.ForwardMode() if self.jacobian == "fwd" else None

        def residuals(u):
            theta = to_physical(names, u)
            result = objective._simulate_impl(theta, adjoint, self.simulator_program)
            hertz_time = objective.hertz_time(theta)
            r = objective.residuals_from_result(result, hertz_time, value, scale)
            return r, (r, result.status)

        differentiate = jax.jacfwd if self.jacobian == "fwd" else jax.jacrev
        jac, (r, status) = differentiate(residuals, has_aux=True)(u)
        return r, jac, status

    def _batch(self, U, value, scale):
        if self.starts == 1:  # no vmap to trace through (about 2 s of a cold fit's tracing)
            return jax.tree_util.tree_map(lambda x: x[None], self._one_start(U[0], value, scale))
        return jax.vmap(self._one_start, in_axes=(0, None, None))(U, value, scale)

    @property
    def key(self) -> str:
        return (
            f"{self.objective.fingerprint()}|{self.jacobian}|{self.starts}|{self.simulator_program}"
        )

    def describe(self) -> str:
        n_imp, n_obs = self.objective._speed.size, self.objective.n_data
        starts = f", {self.starts} starts batched" if self.starts > 1 else ""
        mode = "forward" if self.jacobian == "fwd" else "reverse"
        return (
            f"residuals and Jacobian for {_count(n_imp, 'impact')} "
            f"({_count(n_obs, 'observation')}) x {_count(len(self.names), 'parameter')} "
            f"({mode} mode{starts})"
        )

    def compile(self, *, status: bool = False) -> float:
        """Build the compiled program (from memory, the cache, or by tracing and compiling).

        Arguments:
            status: print what is being done and how long it took to stderr.

        Returns:
            float: seconds spent.
        """
        t0 = time.perf_counter()
        key = self.key
        if key in _MEMORY:
            _MEMORY.move_to_end(key)
            self._compiled, _ = _MEMORY[key]
            self.stats["source"] = "memory"
            self.compile_seconds = time.perf_counter() - t0
            return self.compile_seconds
        if status:
            print(f"compiling {self.describe()} ...", end="", file=sys.stderr, flush=True)
        dtype = jnp.result_type(float)
        n_data = self.objective.n_data
        example = (
            jax.ShapeDtypeStruct((self.starts, len(self.names)), dtype),
            jax.ShapeDtypeStruct((n_data,), dtype),
            jax.ShapeDtypeStruct((n_data,), dtype),
        )
        # Equinox's checks as NaN: a raising check is a host callback, which would keep the
        # program out of the caches; a NaN Jacobian is a rejected point for the solvers.
        with runtime_checks_as_nan():
            self._compiled, source = compiled_program(
                "fit", self._batch, example, key, compiler_options()
            )
        self.stats["compiles"] += 1
        self.stats["source"] = source
        _MEMORY[key] = (self._compiled, source)
        while len(_MEMORY) > _MEMORY_SIZE:
            _MEMORY.popitem(last=False)
        self.compile_seconds = time.perf_counter() - t0
        if status:
            how = "loaded traced program" if source == "cache" else "traced"
            print(f" {self.compile_seconds:.1f} s ({how})", file=sys.stderr, flush=True)
        return self.compile_seconds

    def __call__(self, U, value=None, scale=None):
        """``(r, J, status)`` as numpy arrays at the ``(starts, p)`` points ``U``.

        ``value``, ``scale``: observed values and scales in place of the objective's (same
        observables and impacts), e.g. ``value = 0, scale = 1`` for the model values
        themselves (cor_n continued below zero where the model captures)."""
        if self._compiled is None:
            self.compile()
        self.stats["calls"] += 1
        dtype = jnp.result_type(float)
        U = jnp.asarray(np.reshape(U, (self.starts, len(self.names))), dtype)
        obj = self.objective
        value = (
            obj._value
            if value is None
            else jnp.broadcast_to(jnp.asarray(value, dtype), (obj.n_data,))
        )
        scale = (
            obj._scale
            if scale is None
            else jnp.broadcast_to(jnp.asarray(scale, dtype), (obj.n_data,))
        )
        r, jac, status = self._compiled(U, value, scale)
        return np.asarray(r), np.asarray(jac), np.asarray(status)


def _count(n: int, noun: str) -> str:
    """``1 impact``, ``25 impacts``."""
    return f"{n} {noun}" + ("" if n == 1 else "s")
