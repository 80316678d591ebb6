"""Batches split over several (host) devices give the same results as one device."""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import jaximpact as ji

SCRIPT = """
import json, jax, numpy as np
import jaximpact as ji
jax.config.update("jax_enable_x64", True)
rng = np.random.default_rng(3)
speed, angle = rng.uniform(0.05, 5, 11), rng.uniform(-60, 60, 11)
omega0 = rng.uniform(-2e4, 2e4, 11)
res = ji.simulate(ji.table1_scene(), speed, angle, omega0)
out = {"devices": len(jax.devices()), "status": np.asarray(res.status).tolist()}
out.update({k: np.asarray(getattr(res, k)).tolist() for k in ("cor_n", "omega_out")})
print(json.dumps(out))
"""


def run(devices):
    env = {**os.environ, "XLA_FLAGS": f"--xla_force_host_platform_device_count={devices}"}
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT],
        env=env,
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_sharded_batch_equals_single_device():
    one, three = run(1), run(3)
    assert one["devices"] == 1 and three["devices"] == 3
    assert three["status"] == one["status"]
    # Same per-lane model; XLA vectorizes the shorter per-device arrays differently, and the
    # adaptive step choice can amplify that rounding up to the solver tolerance (~1e-7 here).
    np.testing.assert_allclose(three["cor_n"], one["cor_n"], rtol=1e-5)
    np.testing.assert_allclose(three["omega_out"], one["omega_out"], rtol=1e-5)


def test_use_all_cpu_cores_refuses_after_jax_started():
    import jax.numpy as jnp

    jnp.zeros(1)  # the backend is running in this process
    with pytest.raises(RuntimeError, match="before JAX"):
        ji.use_all_cpu_cores()


def test_loop_kernel_option_is_added_merged_or_kept():
    from jaximpact._engine.devices import LOOP_KERNEL_BYTES, _with_loop_kernels

    threshold = f"xla_cpu_small_while_loop_byte_threshold={LOOP_KERNEL_BYTES}"
    option = f"{threshold},xla_cpu_disable_loop_unrolling=true"
    assert _with_loop_kernels("") == f" --xla_backend_extra_options={option}"
    merged = _with_loop_kernels("--a=1 --xla_backend_extra_options=k=v --b=2")
    assert merged == f"--a=1 --xla_backend_extra_options=k=v,{option} --b=2"
    mine = "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5"
    assert _with_loop_kernels(mine) == mine + ",xla_cpu_disable_loop_unrolling=true"
    both = mine + ",xla_cpu_disable_loop_unrolling=false"
    assert _with_loop_kernels(both) == both


LOOP_KERNEL_SCRIPT = """
import json, math, jax, numpy as np
import jaximpact as ji
ji.use_all_cpu_cores(2)  # one device per core, step loops compiled as single kernels
jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp
from jaximpact import reference as ref
from jaximpact._engine.devices import loop_kernels
out = {"devices": len(jax.devices()), "loop_kernels": loop_kernels()}
rng = np.random.default_rng(11)
n = 150  # 75 lanes per device: two chunks each
speed, angle = rng.uniform(0.3, 6, n), rng.uniform(-60, 60, n)
omega0 = rng.uniform(-2e4, 2e4, n)
scene = ji.table1_scene()
batch = ji.simulate(scene, speed, angle, omega0)
perm = rng.permutation(n)
shuffled = ji.simulate(scene, speed[perm], angle[perm], omega0[perm])
alone = [ji.simulate(scene, speed[i], angle[i], omega0[i]) for i in range(6)]
columns = lambda r: np.stack([np.asarray(r.cor_n), np.asarray(r.omega_out)])
out["shuffled"] = float(np.max(np.abs(columns(shuffled) - columns(batch)[:, perm])))
out["alone"] = max(
    float(np.max(np.abs(columns(r) - columns(batch)[:, i]))) for i, r in enumerate(alone)
)
params = ref.table1_params()
err = 0.0
for i in range(8):
    exact = ref.simulate_impact(params, speed[i], angle[i], omega0[i])
    assert exact.status == "rebound"
    v_n = speed[i] * math.cos(math.radians(angle[i]))
    err = max(err, abs(float(batch.cor_n[i]) - exact.vn_out / v_n))
out["reference"] = err
# the call pattern of a fit: jit(jacfwd) in parameters shared by the batch
def outputs(d, v0, a0, w0):
    f0 = scene.contact.f0 + d[1]
    r = ji.simulate(scene.replace(contact={"f0": f0}), v0 + d[0], a0, w0)
    return jnp.stack([r.cor_n, r.vt_out / v0])
jac = jax.jit(jax.jacfwd(outputs))
zero = jnp.zeros(2)
v, a, w = speed[:8], angle[:8], omega0[:8]
jb = np.asarray(jac(zero, v, a, w))
ja = np.stack([np.asarray(jac(zero, v[i:i+1], a[i:i+1], w[i:i+1]))[:, 0] for i in range(8)], 1)
out["jacobian"] = float(np.max(np.abs(jb - ja) / np.maximum(np.abs(jb), 1e-300)))
out["jacobian_finite"] = bool(np.all(np.isfinite(jb)))
# d cor_n / d (speed, f0) against central differences of the exact reference
exact = np.array([
    [d["cor_n"][k] for k in ("speed", "f0")]
    for d in (ref.output_derivatives(params, v[i], a[i], w[i], inputs=("speed", "f0"))[0]
              for i in range(3))
])
scale = np.max(np.abs(exact), axis=0)
out["jacobian_vs_reference"] = float(np.max(np.abs(jb[0, :3] - exact) / scale))
print(json.dumps(out))
"""


@pytest.mark.slow  # a process of its own compiling five programs (60 s): CI's second step
def test_loop_kernels_keep_results_batch_exact_and_accurate():
    """With ``use_all_cpu_cores()`` (as the CLI runs: two devices, step loops compiled as
    single kernels, small chunks per device), an impact's values are bitwise the same alone,
    in a batch split over devices and chunks, and shuffled; ``jit(jacfwd)`` in parameters
    shared by the batch gives each impact the derivatives it has alone (1e-12); ``cor_n``
    agrees with the exact reference to 1e-6 and its derivatives with the reference's central
    differences to 1e-3 of each column's scale."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    proc = subprocess.run(
        [sys.executable, "-c", LOOP_KERNEL_SCRIPT],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2 and out["loop_kernels"]
    assert out["shuffled"] == 0.0 and out["alone"] == 0.0
    assert out["reference"] < 1e-6
    assert out["jacobian_finite"] and out["jacobian"] <= 1e-12
    assert out["jacobian_vs_reference"] < 1e-3


LAGGING_DEVICE_SCRIPT = """
import jax, jax.numpy as jnp, numpy as np
import jaximpact as ji
from fitting._bayesian.programs import over_devices
jax.config.update("jax_enable_x64", True)
scene = ji.table1_scene()
speed = np.linspace(0.5, 3, 31)  # 31 impacts: padded to 32, cut back to 31 after the solve
ji.simulate(scene, speed)  # compiled before the other device is kept busy
log_density = over_devices(lambda X, d: jnp.sum(X * d, axis=1), "lagging-device-test", np.ones(2))
rows = np.arange(14.0).reshape(7, 2)  # 7 rows: padded to 8 and cut back
log_density(rows)
busy = jax.jit(lambda a: jax.lax.fori_loop(0, 600, lambda i, x: jnp.tanh(x @ x), a))
lagging = jax.device_put(jnp.eye(600) * 0.5, jax.local_devices()[1])
for _ in range(2):  # the second device's queue holds about 2 s of work when each call starts
    busy(lagging)
    result = ji.simulate(scene, speed)
    busy(lagging)
    values = log_density(rows)
print(result.cor_n.shape, float(result.cor_n[0]), values.tolist())
"""


def test_results_of_a_sharded_batch_need_no_collective():
    """With two devices, one of them seconds behind the other (another computation in its
    queue), ``simulate`` and the posterior's sharded log density finish: their sharded results
    are cut to the batch on one device without a collective operation, which XLA's CPU runtime
    aborts when one device waits for the other longer than its timeout (40 s by default, 1 s
    here). Measured before the fix: the process aborted in ``simulate``."""
    flags = (
        "--xla_force_host_platform_device_count=2"
        " --xla_cpu_collective_call_terminate_timeout_seconds=1"
        " --xla_cpu_collective_call_warn_stuck_timeout_seconds=1"
    )
    env = {**os.environ, "XLA_FLAGS": flags}
    proc = subprocess.run(
        [sys.executable, "-c", LAGGING_DEVICE_SCRIPT],
        env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split()[0] == "(31,)"
    assert proc.stdout.strip().endswith("[1.0, 5.0, 9.0, 13.0, 17.0, 21.0, 25.0]")
