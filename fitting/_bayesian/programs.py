"""The compiled log-density programs that the samplers evaluate: the simulator at the
sampler's tolerance, the likelihood and the priors, batched over points and split over the
local devices, compiled once per design (and ahead of their first call where asked).
"""

from __future__ import annotations

import math
import sys
from collections import OrderedDict
from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from jaximpact._engine.devices import compiler_options, engine_jit, gathered
from jaximpact._io.cache import lowered_program, runtime_checks_as_nan

from .._least_squares.objective import FitError, Objective
from .._least_squares.transforms import to_physical
from .likelihood import (
    NOISE_FACTOR_RANGE,
    NOISE_TREATMENTS,
    group_sums,
    log_likelihood_function,
    noise_groups,
)
from .space import SamplingSpace

#: Default solver rtol of the posterior's evaluations in float64 (scenes that set their own
#: rtol keep it). The sampler needs the log density to well under 0.1 and its gradient to a few
#: per cent; rtol 1e-8 gives both with a wide margin (measured in BENCHMARKS.md: "Posterior
#: and design") in about half the steps of the fit's default 1e-10; rtol 1e-7 (the default)
#: keeps cor_n of 200 x 25 Table 1 impacts within 1.0e-5 of rtol 1e-10 (rms 2.2e-6, 0.07 % of
#: a sigma of 0.003) in 90 steps against 127 at 1e-8 and 246 at 1e-10.
SAMPLING_RTOL = 1e-7


#: Step limit of the sampler's evaluations with an explicit solver (the scene's, if smaller).
#: 20,000 Table 1 impacts over C_A 1e-3..5, C_H 0.1..0.5, f0 50..1500 s/m, N/m, 0.05-8 m/s
#: take at most 189 steps at rtol 1e-7; the prior's stiff corners (C_H of tens of s/m) take
#: up to the default 4,096 and hold up the batch they are in (prior draws evaluate 2.1x faster
#: with 1,024). An impact past the limit fails: zero posterior density there.
SAMPLING_MAX_STEPS = 1024


#: The sampler's step loop: lanes refilled as impacts finish (``jaximpact._engine.simulate``,
#: ``default_loop``). Its points from the prior need very different step counts (6 Table 1
#: impacts x 500 prior draws: median 48, 90 % 116, at most the limit of 1,024), so that chunks
#: of 128 lanes ran 7.9x the steps their impacts needed; the pool evaluated 4,700 such points
#: per second against 1,250 (2 cores), for 3.7 s more compiling.
SAMPLING_LOOP = "pool"


#: Points evaluated per compiled call of the independence sampler (times the impacts: lanes).
BLOCK = 500


def _model_residuals(objective: Objective, names, value=None, scale=None):
    """``u -> r``: the fit's weighted residuals as a JAX function (values and derivatives from
    the simulator's step loop; no host round trip); ``value``, ``scale``: observed values and
    scales in place of the objective's."""
    value = objective._value if value is None else value
    scale = objective._scale if scale is None else scale

    def residuals(u):
        theta = to_physical(names, u)
        result = objective._simulate_impl(theta)
        return objective.residuals_from_result(result, objective.hertz_time(theta), value, scale)

    return residuals


def _log_density(
    residuals, names, priors, groups, n_noise, likelihood, nu, weight=None, integrated=False
):
    """``z = (u, log noise factors) -> log posterior`` (up to a constant); ``integrated``: the
    ``n_noise`` factors integrated out (``z = u``)."""
    p = len(names)
    terms = _posterior_terms(names, priors, groups, n_noise, likelihood, nu, integrated)
    weight = None if weight is None else jnp.asarray(weight)
    return lambda z: terms(z, residuals(z[:p]), weight)


def _posterior_terms(names, priors, groups, n_noise, likelihood, nu, integrated=False):
    """``(z, r) -> log posterior`` given the residuals ``r`` at ``z``'s parameters (``z``: the
    fit's ``u`` and the log noise factors, none where ``integrated``)."""
    p = len(names)
    lo, hi = (math.log(v) for v in NOISE_FACTOR_RANGE)
    log_likelihood = log_likelihood_function(groups, n_noise, likelihood, nu, integrated)

    def log_density(z, r, weight=None):
        u, log_s = z[:p], z[p:]
        lp = sum(priors[n].log_density_u(n, u[i]) for i, n in enumerate(names))
        if n_noise and not integrated:
            inside = jnp.all((log_s >= lo) & (log_s <= hi))
            lp = lp + jnp.where(inside, 0.0, -jnp.inf)
        return lp + log_likelihood(r, log_s, weight)

    return log_density


def _noise_groups(objective: Objective) -> tuple[np.ndarray, tuple[str, ...]]:
    """Noise factor of each observation (index, -1 where the data give sigma) and the names."""
    return noise_groups(objective.observations.observable, objective.observations.sigma)


def _integrates(noise: str, likelihood: str, noise_names) -> bool:
    """Whether the noise factors ``noise_names`` are integrated out (``noise``: one of
    :data:`NOISE_TREATMENTS`; a bad combination is a ``FitError``)."""
    if noise not in NOISE_TREATMENTS:
        raise FitError(f"noise must be one of {', '.join(NOISE_TREATMENTS)}, got {noise!r}")
    if noise == "integrated" and likelihood != "gaussian":
        raise FitError(
            "noise='integrated' needs likelihood='gaussian' (the Student-t likelihood has no "
            "closed-form integral over its noise factors: use noise='sampled' or 'auto')"
        )
    return bool(noise_names) and likelihood == "gaussian" and noise != "sampled"


def _at_tolerance(objective: Objective, rtol: float | None, loop: str | None = None) -> Objective:
    """The objective that the sampler evaluates: the fit's, with the step loop ``loop``
    (default the simulator's) and, in float64, solver tolerance ``rtol`` (atol ``rtol / 100``)
    and, for an explicit solver, at most :data:`SAMPLING_MAX_STEPS` steps per impact, unless
    ``rtol`` is None or the scene sets its own (float32's default is looser)."""
    scene = objective.scene
    solver = scene.solver
    if rtol is not None and solver.rtol is None and jnp.result_type(float) == jnp.float64:
        if not 0 < rtol < 1:
            raise FitError(f"rtol must be in (0, 1), got {rtol!r}")
        settings = {"rtol": rtol, "atol": solver.atol or rtol / 100}
        if not objective.method.startswith("kvaerno"):
            settings["max_steps"] = min(solver.max_steps, SAMPLING_MAX_STEPS)
        scene = scene.replace(solver=settings)
    return Objective(
        scene,
        objective.observations,
        objective.params,
        failure_residual=objective.failure_residual,
        method=objective.method,
        loop=loop,
    )


def _model_values(objective: Objective, names):
    """``U (n, p) -> model values (n, n_data)``: cor_n continued below zero where captured,
    as the residuals see it (one compiled program, draws as a batch)."""
    zero, one = jnp.zeros_like(objective._value), jnp.ones_like(objective._scale)
    return engine_jit(jax.vmap(_model_residuals(objective, names, zero, one)))


def _likelihood_of(space: SamplingSpace, groups, likelihood, nu, integrated: int):
    """The log likelihood ``(r, log s, weight) -> ...`` of a posterior in ``space`` whose
    noise factors are its coordinates, or (``integrated``: their number) integrated out."""
    n_noise = integrated or len(space.noise)
    return log_likelihood_function(np.asarray(groups), n_noise, likelihood, nu, integrated > 0)


def _x_log_density(
    residuals, space: SamplingSpace, groups, likelihood, nu, weight=None, integrated: int = 0,
    gradient: bool = False,
):  # fmt: skip
    """``x -> (log posterior, S_1 .. S_k[, its gradient in x])`` (up to a constant) from
    ``residuals: u -> r`` (JAX); ``S_j``: the residual sum of squares of each of the
    ``integrated`` noise groups (what their factors' conditional draws need; none where the
    factors are sampled); ``gradient``: the log posterior's gradient appended (MALA moves)."""
    log_likelihood = _likelihood_of(space, groups, likelihood, nu, integrated)
    weight = None if weight is None else jnp.asarray(weight)

    def log_density(x):
        u, log_s = space.to_u(x)
        r = residuals(u)
        lp = space.log_prior(x) + log_likelihood(r, log_s, weight)
        return jnp.concatenate([lp[None], group_sums(r, groups, integrated, weight)[0]])

    if not gradient:
        return log_density

    def with_gradient(x):  # one evaluation for the value, the sums and the gradient
        def value(y):
            out = log_density(y)
            return out[0], out

        grad, out = jax.grad(value, has_aux=True)(x)
        return jnp.concatenate([out, grad])

    return with_gradient


def _x_batch_log_density(
    objective: Objective,
    space: SamplingSpace,
    groups,
    likelihood,
    nu,
    weight=None,
    integrated: int = 0,
    gradient: bool = False,
):
    """``X (n, d) -> (n, 1 + integrated [+ d])``: the log posterior of each row and its integrated
    noise groups' residual sums of squares (:func:`_x_log_density`), every row's impacts in
    one simulation (a flat batch of ``n x impacts`` lanes; the simulator under ``vmap`` costs
    2-3x that), compiled by :func:`over_devices` with the observed values, scales and
    likelihood weights (``weight``, default 1: one program for a posterior and its
    leave-one-out refits) as inputs. (The simulator called on its own, outside this program,
    runs about 1.7x faster but compiles in 35 s instead of 9 s on 2 cores: the wrong trade
    here.) ``gradient``: each row's gradient of its log posterior in ``x`` appended (forward
    mode through the simulator: one tangent per coordinate, rows independent)."""
    names, p = space.names, len(space.names)
    log_likelihood = _likelihood_of(space, groups, likelihood, nu, integrated)
    objective = _at_tolerance(objective, None, SAMPLING_LOOP)

    def log_density(X, value, scale, weight):
        def prepare(x):
            u, log_s = space.to_u(x)
            return to_physical(names, u), log_s, space.log_prior(x)

        theta, log_s, log_prior = jax.vmap(prepare)(X)
        result = objective._simulate_impl(tuple(theta[:, i : i + 1] for i in range(p)))

        def one(result, th, ls, lp):
            r = objective.residuals_from_result(result, objective.hertz_time(th), value, scale)
            lp = lp + log_likelihood(r, ls, weight)
            return jnp.concatenate([lp[None], group_sums(r, groups, integrated, weight)[0]])

        return jax.vmap(one)(result, theta, log_s, log_prior)

    def log_density_and_gradient(X, value, scale, weight):
        def values(Y):
            return log_density(Y, value, scale, weight)

        # One simulation: the primal is not batched over the tangents (one per coordinate).
        basis = jnp.broadcast_to(jnp.eye(X.shape[1])[:, None, :], (X.shape[1], *X.shape))
        out, tangents = jax.vmap(lambda t: jax.jvp(values, (X,), (t,)))(basis)
        return jnp.concatenate([out[0], tangents[:, :, 0].T], axis=1)

    key = "|".join(
        [objective.fingerprint(), "x", repr(space), repr(np.asarray(groups).tolist())]
        + [likelihood, repr(float(nu)), f"integrated={integrated}", f"gradient={gradient}"]
    )
    program = log_density_and_gradient if gradient else log_density
    weight = _weights(len(objective.observations)) if weight is None else weight
    return over_devices(program, key, objective._value, objective._scale, weight)


def _batch_log_density(
    objective: Objective, names, priors, groups, n_noise, likelihood, nu, weight=None,
    integrated=False,
):  # fmt: skip
    """``Z (n, d) -> log posterior (n,)``: every row's impacts in one simulation (a flat
    batch of ``n x impacts`` lanes; the simulator under ``vmap`` costs 2-3x that)."""
    p = len(names)
    terms = _posterior_terms(names, priors, groups, n_noise, likelihood, nu, integrated)

    def log_density(Z, value, scale, weight):
        theta = jax.vmap(lambda u: to_physical(names, u))(Z[:, :p])
        result = objective._simulate_impl(tuple(theta[:, i : i + 1] for i in range(p)))

        def one(result, th, z):
            r = objective.residuals_from_result(result, objective.hertz_time(th), value, scale)
            return terms(z, r, weight)

        return jax.vmap(one)(result, theta, Z)

    key = "|".join(
        [
            objective.fingerprint(),
            "u",
            repr(names),
            repr(dict(priors)),
            repr(np.asarray(groups).tolist()),
        ]
        + [str(n_noise), likelihood, repr(float(nu)), f"integrated={integrated}"]
    )
    weight = _weights(len(objective.observations)) if weight is None else weight
    return over_devices(log_density, key, objective._value, objective._scale, weight)


def _weights(n: int, leave_out: Sequence[int] = ()) -> np.ndarray:
    """Likelihood weight of each of ``n`` observations: 0 for those left out, else 1."""
    weight = np.ones(n)
    weight[list(leave_out)] = 0.0
    return weight


#: Compiled log-density programs of this process: key -> compiled (the last few).
_PROGRAMS: OrderedDict = OrderedDict()


_PROGRAMS_KEPT = 4


_COMPILER: list[ThreadPoolExecutor] = []


def _compiler() -> ThreadPoolExecutor:
    """The thread that compiles programs prepared ahead of their first call (one: XLA's
    compile of a program is single-threaded, and the caller's own work takes the other core)."""
    if not _COMPILER:
        _COMPILER.append(ThreadPoolExecutor(max_workers=1, thread_name_prefix="jaximpact-xla"))
    return _COMPILER[0]


def over_devices(log_density, key: str, *data):
    """``X -> log_density(X, *data)`` (rows independent) compiled once per row count, with
    the data as the program's inputs: kept in this process (:data:`_PROGRAMS`) and, with the
    compilation cache on, on disk (``jaximpact._io.cache.lowered_program``), so a second data
    set of the same design (a calibration's replications, a user's next sample) neither traces
    nor compiles again. ``key``: a digest of everything ``log_density`` closes over.

    The rows are split over the local devices (``shard_map``; ``data`` replicated): on a CPU
    with one device per core (``jaximpact.use_all_cpu_cores``, as the CLI does) every core
    runs its share of the step loop. 500 rows of 25 impacts: 0.38 s on 2 cores against 0.82 s
    on one, the same values, the same compile time. Rows are padded (copies of the first) to a
    multiple of the device count."""
    devices = jax.local_devices()
    mesh = jax.sharding.Mesh(np.array(devices), ("rows",))
    rows = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec("rows"))
    whole = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    fn = log_density
    if len(devices) > 1:
        # (check_vma=False: the solver's loops start from constants that JAX's type check
        # would want cast to per-device values; nothing crosses devices.)
        fn = jax.shard_map(
            log_density, mesh=mesh, in_specs=(rows.spec,) + (whole.spec,) * len(data),
            out_specs=rows.spec, check_vma=False,
        )  # fmt: skip
    data = tuple(jax.device_put(jnp.asarray(a), whole) for a in data)

    def compiled(shape, dtype, background=False):
        """The program for rows of this shape: from this process's programs (a compile in
        flight is waited for), else traced here and compiled, in a background thread where
        ``background`` (then its future is returned)."""
        program_key = f"{key}|{shape}|{dtype}|{len(devices)}"
        if program_key in _PROGRAMS:
            _PROGRAMS.move_to_end(program_key)
            program = _PROGRAMS[program_key]
            if isinstance(program, Future) and not background:
                program = program.result()  # a failed compile raises here, as it would inline
                _PROGRAMS[program_key] = program
            return program
        example = (jax.ShapeDtypeStruct(shape, dtype, sharding=rows),) + tuple(
            jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=whole) for a in data
        )
        # Equinox's run-time checks as NaN (a rejected point): a raising check is a host
        # callback, which would keep the program out of the caches.
        with runtime_checks_as_nan():
            lowered, _ = lowered_program("posterior", fn, example, program_key)
        options = compiler_options() or None
        program = _compiler().submit(lowered.compile, options) if background else None
        _PROGRAMS[program_key] = program or lowered.compile(options)
        while len(_PROGRAMS) > _PROGRAMS_KEPT:
            _PROGRAMS.popitem(last=False)
        return _PROGRAMS[program_key]

    def rows_shape(n):
        return n + (-n % len(devices))

    def call(X):
        X = jnp.asarray(X)
        n, pad = X.shape[0], -X.shape[0] % len(devices)
        if pad:
            X = jnp.concatenate([X, jnp.repeat(X[:1], pad, axis=0)])
        program = compiled(tuple(X.shape), X.dtype)
        out = program(jax.device_put(X, rows), *data)
        return (gathered(out) if len(devices) > 1 else out)[:n]

    def prepare(n, d):
        """Trace the program for ``n`` rows of ``d`` coordinates now and compile it in a
        background thread (XLA releases the GIL): the caller's next work (a least-squares
        fit, its own compile) runs meanwhile, and the first ``call`` of that shape waits for
        it."""
        compiled((rows_shape(n), d), jnp.result_type(float), background=True)

    call.prepare = prepare
    return call


def _blocks(log_density, block):
    """``X (n, d) -> (n,)`` numpy, ``block`` rows per call of ``log_density`` (one compiled
    shape: the last block is padded with copies of its first row)."""

    def evaluate(X):
        X = np.asarray(X, float)
        out = []
        for i in range(0, len(X), block):
            part = X[i : i + block]
            pad = block - len(part)
            if pad:
                part = np.concatenate([part, np.repeat(part[:1], pad, axis=0)])
            out.append(np.asarray(log_density(jnp.asarray(part)))[: block - pad])
        return np.concatenate(out) if out else np.zeros(0)

    return evaluate


def _progress_bar(total, desc, unit, progress):
    """A progress bar on stderr (none unless ``progress``)."""
    return tqdm(
        total=total, desc=desc, unit=unit, disable=not progress, file=sys.stderr, leave=False
    )
