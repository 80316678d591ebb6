"""A batch on one CPU device is split over the cores in threads (``_engine.simulate``), with
the bits of the batch solved in one program; ``import jaximpact`` imports names on first use."""

import json
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaximpact as ji
from jaximpact._engine import simulate as sim

FIELDS = ("status", "steps", "cor_n", "vt_out", "omega_out", "contact_time", "loss_friction")


def columns(result):
    return np.stack([np.asarray(getattr(result, k), float) for k in FIELDS])


def test_thread_parts_only_for_large_concrete_batches_on_one_cpu_device(monkeypatch):
    """One part per core (at most ``$JAXIMPACT_CPU_THREADS``) for a concrete batch above
    ``THREADED_LANES`` on one CPU device; one part for a small batch, a batch sharded over
    devices and traced inputs (under ``jit``, ``grad``, ``vmap``: the derivative paths)."""
    monkeypatch.setattr(sim, "cpu_threads", lambda: 2)
    big = sim.THREADED_LANES + 8
    x = jnp.ones(big)
    assert len(jax.local_devices()) == 1  # the tests run on one CPU device
    assert sim._thread_parts((x,), big, 1) == 2
    assert sim._thread_parts((x,), sim.THREADED_LANES, 1) == 1
    assert sim._thread_parts((x,), big, 2) == 1
    parts = []
    jax.jit(lambda y: parts.append(sim._thread_parts((y,), big, 1)) or y)(x)
    jax.grad(lambda y: parts.append(sim._thread_parts((y,), big, 1)) or y.sum())(x)
    assert parts == [1, 1]
    monkeypatch.undo()
    monkeypatch.setenv(sim.THREADS_ENV, "1")
    assert sim.cpu_threads() == 1 and sim._thread_parts((x,), big, 1) == 1


@pytest.mark.slow  # compiles two programs of its own (about 15 s on 2 cores): CI's second step
def test_threaded_batch_is_bitwise_the_batch_in_one_program_and_alone(table1, monkeypatch):
    """A batch of 300 impacts (a capture among them) split over 2 threads: every output and
    step count bitwise those of the same batch in one program and of each impact alone, at the
    parts' boundary too."""
    rng = np.random.default_rng(56)
    n = 300
    speed, angle = rng.uniform(0.5, 5.0, n), rng.uniform(-60.0, 60.0, n)
    omega0 = rng.uniform(-2e4, 2e4, n)
    speed[150] = 0.02
    monkeypatch.setattr(sim, "cpu_threads", lambda: 2)
    calls = []
    threaded = sim._solve_in_threads
    monkeypatch.setattr(sim, "_solve_in_threads", lambda *a: calls.append(a[4]) or threaded(*a))
    batch = columns(ji.simulate(table1, speed, angle, omega0))
    assert calls == [2]
    assert batch[0, 150] == ji.Status.CAPTURED
    monkeypatch.setattr(sim, "cpu_threads", lambda: 1)
    one = columns(ji.simulate(table1, speed, angle, omega0))
    assert calls == [2]
    np.testing.assert_array_equal(batch, one)
    for i in (0, 149, 150, 151, n - 1):
        alone = columns(ji.simulate(table1, speed[i], angle[i], omega0[i]))
        np.testing.assert_array_equal(alone, batch[:, i], err_msg=str(i))


IMPORT_SCRIPT = """
import json, sys
import jaximpact as ji
loaded = [m for m in ("diffrax", "equinox", "jaximpact.wall_law", "jaximpact._engine.simulate")
          if m in sys.modules]
import jaximpact.wall_law as wl
out = {"loaded": loaded, "wall_law_is_function": callable(ji.wall_law) and wl is ji.wall_law}
out["names"] = all(getattr(ji, name) is not None for name in ji.__all__)
out["subpackage"] = ji.reference.__name__
out["dir"] = set(ji.__all__) <= set(dir(ji))
print(json.dumps(out))
"""


def test_import_leaves_the_solver_libraries_for_first_use():
    """``import jaximpact`` imports neither diffrax, equinox, the engine nor the wall law; every
    public name resolves on first use; ``jaximpact.wall_law`` stays the function after the
    subpackage is imported; subpackages are attributes as before."""
    proc = subprocess.run(
        [sys.executable, "-c", IMPORT_SCRIPT],
        capture_output=True, text=True, timeout=120, env={**os.environ},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out == {
        "loaded": [],
        "wall_law_is_function": True,
        "names": True,
        "subpackage": "jaximpact.reference",
        "dir": True,
    }


XLA_SCRIPT = """
import json, os, sys
import jax
if sys.argv[1] == "started":
    jax.numpy.zeros(1)  # the backend is running before jaximpact is imported
import jaximpact as ji
if sys.argv[1].startswith("all cores"):
    ji.use_all_cpu_cores(2, loop_kernels=sys.argv[1] == "all cores")
from jaximpact._engine import devices
out = {"flags": os.environ.get("XLA_FLAGS", ""), "loop_kernels": devices.loop_kernels()}
out["unfused"] = "xla_disable_hlo_passes" in devices.compiler_options(throughput=True)
out["devices"] = len(jax.devices())
out["marker"] = os.environ.get("JAXIMPACT_XLA_OPTIONS")
print(json.dumps(out))
"""


@pytest.mark.parametrize(
    "case, env",
    [
        ("plain", {}),
        ("off", {"JAXIMPACT_XLA_OPTIONS": "off"}),
        ("user", {"XLA_FLAGS": "--xla_backend_extra_options=xla_cpu_disable_loop_unrolling=false"}),
        ("started", {}),
        ("all cores", {}),
        ("all cores without loop kernels", {}),
        (
            "child",
            {
                "XLA_FLAGS": "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold"
                "=8388608,xla_cpu_disable_loop_unrolling=true",
                "JAXIMPACT_XLA_OPTIONS": "set-by-import",
            },
        ),
    ],
)
def test_import_sets_loop_kernels_only_where_nobody_chose(case, env):
    """``import jaximpact`` adds the loop-kernel options to ``XLA_FLAGS`` (one device, fused
    programs) where JAX's backend has not started, the user set neither option and
    ``JAXIMPACT_XLA_OPTIONS`` is not ``off``; ``use_all_cpu_cores()`` after it gives the
    command line's settings (a device per core, unfused throughput programs)."""
    base = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAXIMPACT_XLA_OPTIONS")}
    proc = subprocess.run(
        [sys.executable, "-c", XLA_SCRIPT, case],
        capture_output=True, text=True, timeout=120, env={**base, **env},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    threshold = "xla_cpu_small_while_loop_byte_threshold=8388608"
    if case == "plain":
        assert threshold in out["flags"] and out["loop_kernels"]
        assert not out["unfused"] and out["devices"] == 1 and out["marker"] == "set-by-import"
    elif case == "child":  # the parent's import set the options: the same programs
        assert out["flags"] == env["XLA_FLAGS"] and out["loop_kernels"] and not out["unfused"]
    elif case in ("off", "started"):
        assert out["flags"] == "" and not out["loop_kernels"] and not out["unfused"]
    elif case == "user":
        assert out["flags"] == env["XLA_FLAGS"] and not out["loop_kernels"]
    elif case == "all cores":  # child processes then compile as this one: unfused
        assert threshold in out["flags"] and out["unfused"] and out["devices"] == 2
        assert out["marker"] is None
    else:
        assert out["flags"] == "--xla_force_host_platform_device_count=2"
        assert not out["loop_kernels"] and out["devices"] == 2 and out["marker"] is None
