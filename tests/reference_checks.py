"""Checks shared by the tests of the contact laws and of sphere-sphere impacts: the engine
against the exact reference, and a batch against its lanes alone."""

import math

import numpy as np
import pytest

import jaximpact as ji
from jaximpact import reference as ref

LOSSES = ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling")


def random_impacts(seed, speeds, radius):
    """Angles in -70..70 deg (the first normal) and spins of up to 0.3 speed/radius."""
    rng = np.random.default_rng(seed)
    angles = rng.uniform(-70, 70, speeds.size)
    angles[0] = 0.0
    omega0 = rng.uniform(-0.3, 0.3, speeds.size) * speeds / radius
    return angles, omega0


def check_impacts(scene, params, speeds, angles, omega0, tol=1e-7, exchanged=None) -> set:
    """Every impact of ``scene`` against ``ref.simulate_impact(params, ...)``: the same status,
    ``vn_out`` (rebounds), ``vt_out`` and ``omega_out r`` within ``tol`` of the speed, the
    engine's ledger closed to ``tol`` of the energy in (or of ``exchanged(res, i)``, the
    energy the impact exchanges). Returns the statuses seen."""
    r = params.radius
    res = ji.simulate(scene, speeds, angles, omega0)
    statuses = {"rebound": ji.Status.REBOUND, "captured": ji.Status.CAPTURED}
    seen = set()
    for i, v in enumerate(speeds):
        q = ref.simulate_impact(params, v, angles[i], omega0[i])
        assert int(res.status[i]) == statuses[q.status], (v, angles[i])
        seen.add(q.status)
        if q.status == "rebound":
            assert float(res.vn_out[i]) == pytest.approx(q.vn_out, abs=tol * v)
        assert float(res.vt_out[i]) == pytest.approx(q.vt_out, abs=tol * v)
        assert float(res.omega_out[i]) * r == pytest.approx(q.omega_out * r, abs=tol * v)
        losses = sum(float(getattr(res, k)[i]) for k in LOSSES)
        e_in, e_out = float(res.energy_in[i]), float(res.energy_out[i])
        scale = exchanged(res, i) if exchanged else e_in
        assert abs(e_in - e_out - losses) < tol * scale, (v, angles[i])
    return seen


def check_derivatives(scene, params, speed, angle, omega0, inputs, tol=1e-4):
    """``output_jacobian`` of one impact against the reference's Richardson-checked central
    differences, each scaled to order one (``x d/dx`` of cor_n, vt/speed, omega r/speed; per
    radian for the angle)."""
    r = params.radius
    # the compact program: half the compile time of the default one (these are a few impacts)
    jac = ji.output_jacobian(scene, speed, angle, omega0, inputs=inputs, program="compact")
    exact, err = ref.output_derivatives(params, speed, angle, omega0, inputs=inputs)
    x = {"speed": speed, "angle_deg": 180 / math.pi, "omega0": speed / r}
    if params.target:
        x["omega2"] = speed / params.radius2
    for name in inputs:
        if name not in x:
            x[name] = getattr(params, "lam" if name == "lambda" else name)
    for out, s_out in {"cor_n": 1.0, "vt_out": speed, "omega_out": speed / r}.items():
        for j, name in enumerate(inputs):
            want = exact[out][name] * x[name] / s_out
            assert err[out][name] * x[name] / s_out < 0.1 * tol, (out, name)
            got = float(jac[out][0, j]) * x[name] / s_out
            assert got == pytest.approx(want, abs=tol), (out, name)


def check_batch_exact(scene, speeds, angles, omega0, lanes=(0, 2), keys=("cor_n", "vt_out",
                      "omega_out", "contact_time")):  # fmt: skip
    """Each of ``lanes`` gives bitwise the same ``keys`` alone as inside the batch."""
    batch = ji.simulate(scene, speeds, angles, omega0)
    for i in lanes:
        alone = ji.simulate(scene, speeds[i : i + 1], angles[i : i + 1], omega0[i : i + 1])
        for k in keys:
            a, b = np.asarray(getattr(alone, k))[0], np.asarray(getattr(batch, k))[i]
            assert a == b or (np.isnan(a) and np.isnan(b)), (k, i)
