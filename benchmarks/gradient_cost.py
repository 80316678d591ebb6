"""Gradient cost of a fitting-like objective: value, reverse mode and forward mode.

Objective: 25 oblique spinning Table 1 impacts, parameters (C_A, C_H, f0), sum of squared
``cor_n`` residuals against targets made with the Table 1 values. Reverse mode is ``jax.grad``
with diffrax's default ``RecursiveCheckpointAdjoint``; forward mode is ``jax.jacfwd`` with
``simulate(..., adjoint=diffrax.ForwardMode())`` (the default adjoint supports reverse mode
only). Everything under ``jax.jit``; medians of repeated calls after compilation.
"""

import time

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from _common import median_time, table

import jaximpact as ji


def objective(adjoint=None):
    scene = ji.table1_scene()
    rng = np.random.default_rng(11)
    speed = rng.uniform(0.3, 5.0, 25)
    angle = rng.uniform(-60.0, 60.0, 25)
    omega0 = rng.uniform(-2e4, 2e4, 25)
    target = np.asarray(ji.simulate(scene, speed, angle, omega0).cor_n)

    def loss(x):
        s = scene.replace(contact={"C_A": x[0], "C_H": x[1], "f0": x[2]})
        res = ji.simulate(s, speed, angle, omega0, adjoint=adjoint)
        return jnp.sum((res.cor_n - target) ** 2)

    x0 = jnp.array([float(scene.contact.C_A) * 1.2, float(scene.contact.C_H) * 0.8, 300.0])
    return loss, x0


def run(quick=False):
    loss, x0 = objective()
    loss_fwd, _ = objective(diffrax.ForwardMode())
    fns = {
        "value": jax.jit(loss),
        "value + gradient, reverse (jax.value_and_grad)": jax.jit(jax.value_and_grad(loss)),
        "gradient, forward (jax.jacfwd, ForwardMode)": jax.jit(jax.jacfwd(loss_fwd)),
        "value, ForwardMode adjoint": jax.jit(loss_fwd),
    }
    rows, out = [], {}
    for name, f in fns.items():
        t = time.perf_counter()
        val = jax.block_until_ready(f(x0))
        first = time.perf_counter() - t
        run_t = median_time(lambda f=f: jax.block_until_ready(f(x0)), 3 if quick else 7)
        out[name] = dict(first=first, run=run_t, value=val)
    base = out["value"]["run"]
    g_rev = np.asarray(out["value + gradient, reverse (jax.value_and_grad)"]["value"][1])
    g_fwd = np.asarray(out["gradient, forward (jax.jacfwd, ForwardMode)"]["value"])
    for name, r in out.items():
        rows.append(
            [
                name,
                f"{r['run'] * 1e3:.1f}",
                f"{r['run'] / base:.1f}",
                f"{r['first'] - r['run']:.1f}",
            ]
        )
    agree = float(np.max(np.abs(g_rev - g_fwd) / (np.abs(g_rev) + 1e-300)))
    md = [
        "## Gradient cost\n",
        "Fitting-like objective: 25 oblique spinning Table 1 impacts (0.3-5 m/s, -60..60 deg, "
        "|omega0| <= 2e4 rad/s), parameters (C_A, C_H, f0), sum of squared cor_n residuals, "
        "float64, default settings, under `jax.jit`.\n",
        table(["computation", "run (ms)", "x value", "compile (s)"], rows),
        f"\nReverse and forward gradients agree to {agree:.1e} (relative, largest component). "
        "diffrax's default `RecursiveCheckpointAdjoint` supports reverse mode only; forward "
        "mode needs `simulate(..., adjoint=diffrax.ForwardMode())`.\n",
    ]
    return "\n".join(md) + "\n", out
