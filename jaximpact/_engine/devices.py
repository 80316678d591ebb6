"""Using every CPU core: one XLA host device per core, over which ``simulate`` shards batches."""

import os
import re


def use_all_cpu_cores(count: int | None = None) -> int:
    """Ask XLA for one CPU device per core, so batches are split over all cores.

    XLA runs a vmapped batch on one core per device; ``simulate`` and ``jaximpact sweep`` shard
    a batch over all local devices, so on a CPU this is what uses the other cores (1.5-2x on 2
    cores, measured in BENCHMARKS.md). It must run before JAX starts its backend (before the
    first array is made); it does nothing on a GPU machine's GPU devices.

    **Arguments:** `count`: number of host devices (default: the number of usable cores).

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
    flags = re.sub(
        r"--xla_force_host_platform_device_count=\d+", "", os.environ.get("XLA_FLAGS", "")
    )
    os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={count}".strip()
    return count
