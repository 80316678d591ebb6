"""Settings of XLA's CPU backend that must be made before JAX starts: one device per core, and
step loops compiled as single kernels."""

import functools
import os
import re

# XLA's CPU backend compiles a while loop whose body accesses fewer bytes per iteration than
# this into one kernel (its "small while loop" pass; JAX's default is 1 KB). A step loop of a
# few hundred lanes then runs without a dispatch per operation: the fit's forward-mode program
# (26 lanes, 3 tangents) 2.5x faster, a chunk of 64-128 lanes 1.3x per core (BENCHMARKS.md,
# "Loop kernels"). Such a kernel runs on one core, so it pays only where there is a device
# per core (and small chunks per device, ``_engine.simulate._default_chunk``). 8 MiB covers
# the step loop of about 2,000 float64 lanes and leaves larger loops to the multi-threaded
# runtime. LLVM's loop unrolling is turned off with it: a kernel of the unfused throughput
# program (:func:`compiler_options`) compiled in 9 s instead of 25 s and ran
# 1.8x faster without it.
LOOP_KERNEL_BYTES = 8 << 20
_LOOP_OPTION = "xla_cpu_small_while_loop_byte_threshold"
_UNROLL_OPTION = "xla_cpu_disable_loop_unrolling"


#: ``import jaximpact`` adds the loop-kernel options to ``XLA_FLAGS`` where JAX's backends have
#: not started (:func:`loop_kernels_at_import`); this environment variable set to ``off``
#: leaves XLA's settings as they are.
XLA_OPTIONS_ENV = "JAXIMPACT_XLA_OPTIONS"
_OFF = ("off", "0", "false", "no", "none")
_SET = "set-by-import"  # its value where an import set the options (read by child processes)
_BY_IMPORT: list = []  # [XLA_FLAGS before] where import set the options
_ALL_CORES: list = []  # [True] after use_all_cpu_cores(loop_kernels=True)


def loop_kernels_at_import() -> bool:
    """Loop kernels (:func:`_with_loop_kernels`) for the process, where JAX's backends have not
    started, ``XLA_FLAGS`` names neither option (the user's choice is kept) and
    ``$JAXIMPACT_XLA_OPTIONS`` is not ``off``: called by ``import jaximpact``. A notebook's
    ``simulate`` then runs its threads' step loops as single kernels (about 1.6x the rate on
    2 cores; BENCHMARKS.md, "As a notebook runs it and as the command line runs it", which
    also measures other JAX code with and without them). The options apply to every while
    loop of the process whose iteration touches less than 8 MiB (it then runs on one core)
    and turn LLVM's loop unrolling off; the device count is left alone. Said once, at INFO
    level of the ``jaximpact`` logger. **Returns:** whether it set them."""
    if os.environ.get(XLA_OPTIONS_ENV, "").strip().lower() in _OFF:
        return False
    flags = os.environ.get("XLA_FLAGS", "")
    if _LOOP_OPTION in flags or _UNROLL_OPTION in flags:
        return False
    from jax._src import xla_bridge

    if getattr(xla_bridge, "_backends", None):
        return False
    os.environ["XLA_FLAGS"] = _with_loop_kernels(flags).strip()
    # (child processes inherit XLA_FLAGS: this tells them the options are the import's, so
    # that they compile the programs this one does)
    os.environ[XLA_OPTIONS_ENV] = _SET
    _BY_IMPORT.append(flags)
    import logging

    logging.getLogger("jaximpact").info(
        "jaximpact added %s to XLA_FLAGS (while loops under 8 MiB per iteration compiled as "
        "single kernels); %s=off before the import leaves XLA's settings alone",
        _LOOP_OPTION,
        XLA_OPTIONS_ENV,
    )
    return True


def use_all_cpu_cores(count: int | None = None, *, loop_kernels: bool = True) -> int:
    """Ask XLA for one CPU device per core, so batches are split over all cores.

    XLA runs a vmapped batch on one core per device; ``simulate`` and ``jaximpact sweep`` shard
    a batch over all local devices, so on a CPU this is what uses the other cores (1.5-2x on 2
    cores, measured in BENCHMARKS.md). It must run before JAX starts its backend (before the
    first array is made); it does nothing on a GPU machine's GPU devices.

    **Arguments:**
    - `count`: number of host devices (default: the number of usable cores).
    - `loop_kernels`: also let XLA compile each device's step loop into one kernel
      (:data:`LOOP_KERNEL_BYTES`): fits, posteriors and batches run 1.3-2.5x faster. It
      applies to every while loop of the process whose iteration touches less than 8 MiB
      (such a loop then runs on one core), and turns LLVM's loop unrolling off for the
      process's CPU programs.

    **Returns:** the device count requested.

    **Raises:** `RuntimeError` if JAX's backend has already started.
    """
    from jax._src import xla_bridge

    if getattr(xla_bridge, "_backends", None):
        raise RuntimeError(
            "use_all_cpu_cores() must be called before JAX creates its first array "
            "(set XLA_FLAGS=--xla_force_host_platform_device_count=N in the environment instead)"
        )
    count = count or len(os.sched_getaffinity(0))
    flags = os.environ.get("XLA_FLAGS", "")
    if os.environ.get(XLA_OPTIONS_ENV) == _SET:
        # the options are now the caller's (child processes compile as this one), and
        # without loop kernels the flags from before the import's options
        del os.environ[XLA_OPTIONS_ENV]
        if _BY_IMPORT and not loop_kernels:
            flags = _BY_IMPORT[0]
    flags = re.sub(r"--xla_force_host_platform_device_count=\d+", "", flags)
    flags = f"{flags} --xla_force_host_platform_device_count={count}"
    if loop_kernels:
        flags = _with_loop_kernels(flags)
        _ALL_CORES.append(True)
    os.environ["XLA_FLAGS"] = flags.strip()
    return count


def _with_loop_kernels(flags: str) -> str:
    """``flags`` with the loop-kernel threshold added to XLA's backend options (a value the
    user gave is kept)."""
    options = [f"{_LOOP_OPTION}={LOOP_KERNEL_BYTES}", f"{_UNROLL_OPTION}=true"]
    option = ",".join(o for o in options if o.split("=")[0] not in flags)
    if not option:
        return flags
    match = re.search(r"--xla_backend_extra_options=(\S*)", flags)
    if match is None:
        return f"{flags} --xla_backend_extra_options={option}"
    merged = ",".join(filter(None, [match.group(1), option]))
    return flags[: match.start(1)] + merged + flags[match.end(1) :]


def loop_kernels() -> bool:
    """Whether XLA was asked (in ``XLA_FLAGS``) to compile step loops as single kernels."""
    match = re.search(_LOOP_OPTION + r"=(\d+)", os.environ.get("XLA_FLAGS", ""))
    return match is not None and int(match.group(1)) >= LOOP_KERNEL_BYTES // 4


# XLA's operation fusion off: the throughput program's setting where step loops are single
# kernels. XLA:CPU makes one fusion per output and copies cheap operations into every fusion
# that uses them (the float64 step: 136 fusions holding 6,000 operations against 1,150
# unfused); inside one kernel, reading an unfused operation's result back from the cache costs
# less than computing it again: 20,000 float64 impacts on 2 cores ran 31,500/s against
# 23,600/s fused (chunks of 128 lanes; compiling 9 s against 6 s).
UNFUSED = {"xla_disable_hlo_passes": "fusion"}
# XLA:CPU prefers 256-bit vectors where the CPU has 512-bit ones (against the clock slowdown
# of early AVX-512 parts); a step loop is arithmetic on whole vectors of lanes (``lane_group``
# pads every chunk to 512 bits), and 512-bit vectors ran 20,000 float64 impacts on 2 cores
# about 1.4-2.2x faster (BENCHMARKS.md, "Loop kernels"). A CPU without them keeps its width.
WIDE_VECTORS = {"xla_cpu_prefer_vector_width": 512}


def compiler_options(throughput: bool = False) -> dict:
    """XLA options for the engine's compiled programs in this process: 512-bit vectors on a
    CPU; with loop kernels that the user asked for (:func:`unfused_programs`), a
    ``throughput`` program (unrolled stages, values only) also without fusion. Call it where
    the program is built (it starts JAX's backend)."""
    import jax

    if jax.default_backend() != "cpu":
        return {}
    options = dict(WIDE_VECTORS)
    if throughput and unfused_programs():
        options.update(UNFUSED)
    return options


def unfused_programs() -> bool:
    """Whether the throughput program is compiled without fusion: with loop kernels that the
    user asked for (``use_all_cpu_cores()``, ``XLA_FLAGS``), not those that ``import
    jaximpact`` set: fused, a notebook's first ``simulate`` of 3 impacts compiled in 7.0 s
    against 10.0-10.6 s unfused (8.0-9.4 s without loop kernels), for 0.8-0.9x the unfused
    rate on 20,000 impacts (BENCHMARKS.md, "As a notebook runs it and as the command line runs
    it")."""
    by_import = _BY_IMPORT or os.environ.get(XLA_OPTIONS_ENV) == _SET
    return loop_kernels() and (not by_import or bool(_ALL_CORES))


def engine_jit(fn, **kwargs):
    """``jax.jit`` with :func:`compiler_options` where the program is compiled on its own: for
    programs that run the engine inside (a sampler's steps and log density). Called while
    another program is traced (a tracer among its arguments, or under ``jax.jit``) it is a
    plain ``jax.jit``, whose program the caller's compiles (JAX refuses options there)."""
    import jax

    plain = jax.jit(fn, **kwargs)
    tuned = []  # made on first use: compiler_options() starts JAX's backend

    @functools.wraps(fn)
    def call(*args, **kw):
        if not compiled_alone((args, kw)):
            return plain(*args, **kw)
        if not tuned:
            tuned.append(jax.jit(fn, compiler_options=compiler_options() or None, **kwargs))
        return tuned[0](*args, **kw)

    return call


def compiled_alone(args) -> bool:
    """Whether a jitted call with these arguments is a program of its own, which may take XLA
    options: not while a ``jax.jit`` is traced, and no tracer among ``args`` (under ``grad`` or
    ``vmap`` the jit may end up inside another program)."""
    import jax

    leaves = jax.tree_util.tree_leaves(args)
    return not under_trace() and not any(isinstance(x, jax.core.Tracer) for x in leaves)


def under_trace() -> bool:
    """Whether a ``jax.jit`` is being traced (JAX's own test, private; without it: no)."""
    import jax

    test = getattr(jax._src.core, "unsafe_am_i_under_a_jit", None)
    return bool(test()) if test is not None else False


def gathered(tree):
    """The results of a program sharded over several devices, waited for and put on the default
    device by way of the host: no collective operation. Slicing or reshaping the sharded arrays
    would run a partitioned program whose all-gather each device enters when its own queue gets
    there; a device that finished its share early then waits for the others, and XLA's CPU
    runtime aborts the process when that wait passes 40 s (it did, in a wall law's build, with
    the other core busy)."""
    import jax

    return jax.device_put(jax.device_get(tree))
