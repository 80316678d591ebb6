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
