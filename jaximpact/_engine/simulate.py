"""``simulate``: the one public driver. It checks and flattens the inputs, stands nominal
inputs in for invalid traced lanes, pads and shards the batch and picks its chunk and step
loop; the batch itself is solved in :mod:`.batch` (one impact: :mod:`.impact`)."""

import dataclasses

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .._model.scene import Scene, SceneError, _is_concrete, check_impact
from . import step_loop as step_loop
from .batch import IMPLICIT_MAPPED_LANES as IMPLICIT_MAPPED_LANES
from .batch import _batch_mesh, _lean_method
from .devices import compiled_alone, gathered, loop_kernels
from .impact import CONTROLLED_STATES as CONTROLLED_STATES
from .impact import T_MAX as T_MAX
from .impact import _problem as _problem
from .impact import _solve_one as _solve_one
from .programs import _CACHED_PROGRAMS as _CACHED_PROGRAMS
from .programs import _simulate_flat as _simulate_flat
from .results import ImpactResult, Status
from .settings import PARAMETERS as PARAMETERS
from .settings import PROGRAMS as PROGRAMS
from .settings import Integration as Integration
from .settings import _scaled as _scaled
from .settings import integration_settings as integration_settings
from .settings import required_terms as required_terms
from .settings import scene_parameters as scene_parameters
from .settings import stiffness_estimate as stiffness_estimate
from .shells import _shell_friction as _shell_friction
from .tsit5 import lane_group

# (The names imported "as" themselves are kept importable from here, where tests, benchmarks
# and the fitting package import them.)


# Lanes per device that one chunk of a large batch integrates at a time, on a CPU, in float64
# (float32: twice as many, the same bytes); issue 12, measured in BENCHMARKS.md, "Throughput
# (issue 12)". A vmapped solve walks its whole state once per step, which a chunk keeps in a
# core's caches; XLA also splits the operations of a large batch over all cores, which a small
# chunk forgoes, so one device gets large chunks, and the smaller ones are for a batch sharded
# over one device per core (``use_all_cpu_cores``). Retuned for the per-state stage sums
# (fourth session; 20,000 impacts, medians of 3): 2 devices, chunk 2048 float64 12,729/s
# against 10,839 at 512 and 9,508 whole; float32 chunk 4096 92,710/s against 46,814 at 512
# and 73,795 whole; 1 device float64 8192 10,770/s against 9,255 at 4096. No chunks on GPUs,
# where a larger batch is better.
CHUNK = 2048
CHUNK_ONE_DEVICE = 8192
# With step loops compiled as single kernels (``use_all_cpu_cores(loop_kernels=True)``, as
# the CLI does) a device's chunk runs on one core from its caches. Unfused (the throughput
# program, ``compiler_options``), 128 lanes ran 31,500 float64 impacts/s on 2 cores against
# 30,500 at 256 and 33,900 at 64 (which compiled in 24 s against 9 s); fused, 64 lanes ran
# 23,600, 16 21,300 and 256 19,200 (measured with 256-bit vectors).
CHUNK_LOOP_KERNEL = 128


def default_loop(dtype) -> str:
    """The step loop of a batch of ``dtype`` whose steps per impact nobody knows in advance:
    ``"pool"`` (lanes refilled as impacts finish) in float32, ``"lean"`` (chunks of lanes,
    each waiting for its slowest) in float64. Measured (issue 12): in float32 the pool ran
    9-12x the chunked loop on slow impacts near capture, where a few grazing ones take 40x
    the median steps, and 0.95-1.01x on the oblique benchmark; in float64 0.86-0.93x on that
    benchmark (1.31x near capture). Where the steps per impact spread widely (a posterior's
    points drawn from the prior: chunks of 128 lanes ran 7.9x the steps their impacts
    needed), the pool pays in float64 too: ``loop="pool"`` (3.8x the points per second)."""
    return "pool" if jnp.finfo(dtype).bits < 64 else "lean"


def _default_chunk(shards: int, dtype=None) -> int:
    if jax.default_backend() != "cpu":
        return 0
    if loop_kernels():
        per_float64 = CHUNK_LOOP_KERNEL
    else:
        per_float64 = CHUNK if shards > 1 else CHUNK_ONE_DEVICE
    return per_float64 * 8 // jnp.dtype(dtype or jnp.result_type(float)).itemsize


def simulate(
    scene: Scene,
    speed=None,
    angle_deg=None,
    omega0=None,
    *,
    method: str | None = None,
    adjoint: diffrax.AbstractAdjoint | None = None,
    program: str = "throughput",
) -> ImpactResult:
    """Simulate impacts of the scene's sphere on its surface.

    **Arguments:**
    - `scene`: a `Scene` (see `load_scene`, `table1_scene`). Any float parameter may be an array
      broadcastable against the impacts: one value per impact.
    - `speed`: impact speed (m/s, > 0); default ``scene.impact.speed``.
    - `angle_deg`: incidence from the surface normal (degrees, in (-90, 90)); default the
      scene's. Positive: the tangential velocity is along the positive spin's rolling sense.
    - `omega0`: initial spin (rad/s), signed so that ``v_t == r*omega`` is rolling.
    - `method`: override ``scene.solver.method``.
    - `adjoint`: how ``diffrax`` differentiates the solve; default
      ``RecursiveCheckpointAdjoint()`` (reverse mode, ``jax.grad``). Pass
      ``diffrax.ForwardMode()`` for forward mode (``jax.jacfwd``, ``jax.jvp``).
    - `program`: what the compiled program is made for (Tsit5, the default method; other
      methods ignore it): ``"throughput"`` (default: the fastest to run) or ``"compact"``
      (one-off work that compiling dominates, such as a fit or a few impacts: half the
      compile time, about 2x the run time). Each is batch-independent; they agree with each
      other to the solver's tolerance, not bit for bit (BENCHMARKS.md, "Throughput").

    Scalars or arrays (broadcast together; batched internally with ``vmap``).

    **Returns:** an `ImpactResult` with the broadcast shape; check ``status`` (a failed impact
    has NaN outputs, never silently wrong ones).

    **Raises:** `SceneError` (a `ValueError`) for invalid concrete inputs, naming the field.

    Works under ``jax.jit``, ``jax.vmap`` and ``jax.grad``; changing values does not recompile.
    """
    return _simulate(
        scene, speed, angle_deg, omega0, method=method, adjoint=adjoint, program=program
    )


def _simulate(
    scene,
    speed=None,
    angle_deg=None,
    omega0=None,
    *,
    method=None,
    adjoint=None,
    chunk=None,
    loop=None,
    program="throughput",
):
    """``simulate`` with the batch path's private settings: ``chunk``, lanes per device in one
    vmapped solve (default ``_default_chunk``; 0: the whole batch in one); ``loop``: the step
    loop, ``"lean"`` (``step_loop``, chunked), ``"pool"`` (the lean loop with lanes refilled
    as impacts finish) or ``"diffrax"`` (``diffeqsolve``, differentiated with ``adjoint``);
    default (None): :func:`default_loop`. Values and derivatives come
    from the chosen loop (``_simulate_flat``). The lean loop gives diffeqsolve's bits; the pool
    runs 9-12x faster on slow float32 impacts near capture, not bit for bit
    (tests/test_throughput_paths.py).

    Traced inputs cannot raise: a lane with an input outside its range (``_ranges.RANGES``)
    is solved with the scene's nominal inputs in its place and reported with status
    ``invalid_input`` and NaN outputs."""
    speed = scene.impact.speed if speed is None else speed
    angle_deg = scene.impact.angle_deg if angle_deg is None else angle_deg
    omega0 = scene.impact.omega0 if omega0 is None else omega0
    dtype = jnp.result_type(float)
    speed, angle_deg, omega0 = (jnp.asarray(x, dtype) for x in (speed, angle_deg, omega0))
    check_impact(speed, angle_deg, omega0)
    params = {k: jnp.asarray(v, dtype) for k, v in scene_parameters(scene).items()}
    shape = jnp.broadcast_shapes(
        speed.shape, angle_deg.shape, omega0.shape, *(v.shape for v in params.values())
    )
    size = int(np.prod(shape))
    flat = lambda x: jnp.broadcast_to(x, shape).reshape(size)  # noqa: E731
    params = {k: flat(v) for k, v in params.items()}
    speed, angle_deg, omega0 = flat(speed), flat(angle_deg), flat(omega0)
    valid = None
    if not all(map(_is_concrete, (speed, angle_deg, omega0, *params.values()))):
        (params, speed, angle_deg, omega0), valid = _replace_invalid(
            (params, speed, angle_deg, omega0)
        )

    terms = required_terms(scene, params, angle_deg, omega0)
    cfg = integration_settings(scene, params, speed, angle_deg, dtype, method)
    if program not in PROGRAMS:
        raise SceneError(f"program must be one of {', '.join(PROGRAMS)}, got {program!r}")
    cfg = dataclasses.replace(cfg, stages=PROGRAMS[program])
    inputs = (params, speed, angle_deg, omega0)
    # A batch of one is simplified differently by XLA (measured: the last bit of the Hertz
    # damping force), which an adaptive solve can amplify: at least 2 lanes; and in the
    # per_state form every lane on the vectorized path: a multiple of `lane_group` lanes per
    # device (and per chunk, in `_simulate_flat`), padded with copies of the last impact.
    group = max(2, lane_group(dtype, cfg.stages))
    if valid is None and _lean_method(cfg) and size <= SHARED_PROGRAM_LANES[-1]:
        group = max(group, next(n for n in SHARED_PROGRAM_LANES if n >= size))
    loop = default_loop(dtype) if loop is None else loop
    inputs, shards = _shard_over_devices(inputs, size, group)
    parts = _thread_parts(inputs, size, shards)
    chunk = _default_chunk(max(shards, parts), dtype) if chunk is None else chunk
    settings = dict(chunk=chunk, shards=shards, loop=loop)
    if parts > 1:
        result = _solve_in_threads(terms, cfg, inputs, adjoint, parts, group, settings)
    else:
        result = _simulate_flat(terms, cfg, *inputs, adjoint, **settings)
    if shards > 1:  # (concrete inputs only) sharded results cut and reshaped on one device
        result = gathered(result)
    result = jax.tree_util.tree_map(lambda x: x[:size], result)
    if valid is not None:
        result = _mark_invalid(result, valid)
    return jax.tree_util.tree_map(lambda x: x.reshape(shape), result)


# A small concrete batch of an explicit method is padded (copies of its last impact) to the
# first of these lane counts that holds it, so that batches of 3, 10 and 50 impacts of a scene
# run one compiled program instead of three: compiling takes seconds, 64 lanes of a Table 1
# impact a few milliseconds more. (In the test suite the Table 1 scene's program was compiled
# for 8, 16, 24, 32, 80 and 152 lanes: 66 s of 243 s of `simulate` compilations.) Lanes do not
# depend on their batch, so the values are the same bits.
SHARED_PROGRAM_LANES = (64, 128, 256)

# Inputs that stand in for an invalid traced lane: a plain, quick Table 1 impact.
_NOMINAL = {
    "speed": 1.0,
    "angle_deg": 0.0,
    "omega0": 0.0,
    "radius": 21.7e-6,
    "density": 2500.0,
    "K": 5.3e10,
    "f0": 300.0,
    "C_A": 0.75,
    "C_H": 0.25,
    "friction": 0.3,
    "lambda": 0.0,
    "G_star": 2e10,
    "w": 0.1,
    "p_y": 1e9,
    "eta_n": 1e-12,  # every LAMMPS damping quick there (tsuji: alpha(0) = 1.27, scale-free)
    "radius2": 21.7e-6,
    "density2": 2500.0,
    "omega2": 0.0,
}


def _replace_invalid(inputs):
    """``(inputs, valid)``: each lane valid where every input is in its range
    (``_ranges.RANGES``); an invalid lane's inputs replaced by :data:`_NOMINAL`."""
    from .._model.ranges import RANGES

    params, speed, angle_deg, omega0 = inputs
    named = {**params, "speed": speed, "angle_deg": angle_deg, "omega0": omega0}
    valid = jnp.ones(speed.shape, bool)
    for name, x in named.items():
        rng = RANGES[name]
        above = x >= rng.lo if rng.lo_closed else x > rng.lo
        below = x <= rng.hi if rng.hi_closed else x < rng.hi
        valid = valid & jnp.isfinite(x) & above & below
    pick = lambda name, x: jnp.where(valid, x, jnp.asarray(_NOMINAL[name], x.dtype))  # noqa: E731
    params = {k: pick(k, v) for k, v in params.items()}
    return (
        params,
        pick("speed", speed),
        pick("angle_deg", angle_deg),
        pick("omega0", omega0),
    ), valid


def _mark_invalid(result: ImpactResult, valid) -> ImpactResult:
    """Status ``invalid_input`` and NaN outputs (0 steps) on the invalid lanes."""

    def mark(x):
        if jnp.issubdtype(x.dtype, jnp.floating):
            return jnp.where(valid, x, jnp.nan)
        return x

    marked = jax.tree_util.tree_map(mark, result)
    return dataclasses.replace(
        marked,
        status=jnp.where(valid, result.status, Status.INVALID_INPUT).astype(result.status.dtype),
        steps=jnp.where(valid, result.steps, 0).astype(result.steps.dtype),
    )


def _shard_over_devices(inputs, size, group=1):
    """Pad a batch with copies of its last impact to a multiple of ``group`` lanes per device
    and, if it is concrete and large enough, split it over all local devices (GPUs, or host
    devices on a CPU with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``), sharded
    along the batch. Returns the inputs and the number of devices they are split over."""
    devices = jax.local_devices()
    leaves = jax.tree_util.tree_leaves(inputs)
    if len(devices) == 1 or size < 2 * len(devices) or not all(map(_is_concrete, leaves)):
        pad = -size % group
        return jax.tree_util.tree_map(lambda x: jnp.pad(x, (0, pad), mode="edge"), inputs), 1
    pad = -size % (len(devices) * group)
    sharding = jax.sharding.NamedSharding(_batch_mesh(), jax.sharding.PartitionSpec("batch"))
    inputs = jax.tree_util.tree_map(
        lambda x: jax.device_put(jnp.pad(x, (0, pad), mode="edge"), sharding), inputs
    )
    return inputs, len(devices)


# On a CPU with one XLA device (JAX's default), a concrete batch of more than this many impacts
# is split into one part per core, each solved by the compiled program of its part from a
# thread of its own: XLA runs one device's program on one core, and releases Python's lock
# while it runs, so the parts run side by side. ``JAXIMPACT_CPU_THREADS=1`` turns it off
# (``=N``: at most N parts). With ``use_all_cpu_cores()`` (a device per core) the batch is
# sharded over the devices instead. BENCHMARKS.md, "Throughput".
THREADED_LANES = SHARED_PROGRAM_LANES[-1]
THREADS_ENV = "JAXIMPACT_CPU_THREADS"
_THREAD_POOL: list = []  # the pool, made on first use
_THREADED_PROGRAMS: set = set()  # the part programs that have run once (compiled)


def cpu_threads() -> int:
    """The threads a batch on one CPU device is split over: the usable cores, at most
    ``$JAXIMPACT_CPU_THREADS``."""
    import os

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    limit = os.environ.get(THREADS_ENV, "").strip()
    return max(1, min(cores or 1, int(limit))) if limit.isdigit() else max(1, cores or 1)


def _thread_parts(inputs, size, shards) -> int:
    """Parts of the batch solved side by side in threads: one per core where the batch is
    concrete, larger than :data:`THREADED_LANES` and on a single CPU device; else 1."""
    if shards > 1 or size <= THREADED_LANES or jax.default_backend() != "cpu":
        return 1
    if len(jax.local_devices()) > 1 or not compiled_alone(inputs):
        return 1
    return min(cpu_threads(), size // (THREADED_LANES // 2))


def _solve_in_threads(terms, cfg, inputs, adjoint, parts, group, settings):
    """``_simulate_flat`` on ``parts`` contiguous equal parts of the (concrete) batch, each a
    whole number of lane groups (the last padded with copies of the batch's last impact), run
    side by side from a thread pool; the results concatenated in order. A lane's arithmetic
    does not depend on its batch, so these are the bits of the batch solved in one program
    (tests/test_threads.py). The first call of a part program runs its first part alone, so
    that it is compiled once, not in every thread."""
    from concurrent.futures import ThreadPoolExecutor

    size = inputs[1].shape[0]
    pad = -size % (parts * group)
    host = jax.tree_util.tree_map(lambda x: np.pad(np.asarray(x), (0, pad), mode="edge"), inputs)
    width = (size + pad) // parts
    pieces = [
        jax.tree_util.tree_map(lambda x, i=i: jax.device_put(x[i * width : (i + 1) * width]), host)
        for i in range(parts)
    ]

    def solve(piece):
        return jax.device_get(_simulate_flat(terms, cfg, *piece, adjoint, **settings))

    if not _THREAD_POOL:
        _THREAD_POOL.append(ThreadPoolExecutor(cpu_threads(), thread_name_prefix="jaximpact"))
    pool = _THREAD_POOL[0]
    key = repr((terms, cfg, adjoint, sorted(settings.items()), width, str(inputs[1].dtype)))
    key += repr(sorted(inputs[0]))
    first = []
    if key not in _THREADED_PROGRAMS:
        first = [solve(pieces[0])]
        _THREADED_PROGRAMS.add(key)
    futures = [pool.submit(solve, piece) for piece in pieces[len(first) :]]
    results = first + [f.result() for f in futures]
    joined = jax.tree_util.tree_map(lambda *xs: np.concatenate(xs)[:size], *results)
    return jax.device_put(joined)
