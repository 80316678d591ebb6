"""Derivatives of the smooth model against the exact reference, and their batch independence.

Every derivative is compared with central finite differences of ``jaximpact.reference``
(rtol 1e-12, Richardson-checked), relative to the column's typical magnitude: the derivative
of an output scaled to order one (cor_n, vt/speed, omega r/speed, angle in rad, contact time in
units of the reference's own) with respect to an input scaled likewise (``x d/dx``; per radian
for the angle, per speed/radius for the spin). Entries whose finite difference is itself
uncertain (a regime switch inside the step) are not compared, and counted.
"""

import math
import os
import subprocess
import sys
import zlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaximpact as ji
from jaximpact import reference as ref
from jaximpact._engine.sensitivity import INPUTS, OUTPUTS

TOL = 1e-3  # the target, relative to the column's typical magnitude


def seed(name: str) -> int:
    return zlib.crc32(name.encode())


def random_scene(rng, moments):
    """A scene with every parameter drawn at random (radius 9-45 um), and its reference twin."""
    radius = rng.uniform(9e-6, 45e-6)
    values = dict(
        radius=radius,
        density=rng.uniform(2000.0, 9000.0),
        K=10 ** rng.uniform(10.3, 11.2),
        f0=rng.uniform(20.0, 300.0) if moments != "none" else 0.0,
        C_A=rng.uniform(0.2, 1.5),
        C_H=rng.uniform(0.05, 0.5),
        friction=rng.uniform(0.1, 0.6),
        lam=rng.uniform(0.5e-9, 2e-9) if moments == "lambda" else 0.0,
    )
    adhesion = values["f0"] > 0
    scene = ji.Scene(
        particle=ji.Particle(radius=radius, density=values["density"]),
        contact=ji.Contact(
            K=values["K"],
            f0=values["f0"],
            C_A=values["C_A"],
            C_H=values["C_H"],
            friction=values["friction"],
        ),  # fmt: skip
        model=ji.Model(adhesion=adhesion, rolling_moments=moments, lambda_=values["lam"]),
    )
    return scene, ref.Params(**values, adhesion=adhesion, rolling_moments=moments)


def random_impacts(rng, params, n):
    """Rebounding impacts, 0.3-5 m/s, -70..70 deg, with and without spin."""
    speed = 10 ** rng.uniform(math.log10(0.5), math.log10(5.0), n)
    angle = rng.uniform(-70.0, 70.0, n)
    omega0 = rng.uniform(-0.5, 0.5, n) * speed / params.radius
    omega0[1::2] = 0.0
    return speed, angle, omega0


def scaled_errors(jac, params, speed, angle, omega0, inputs):
    """(worst scaled error, number of entries compared, number skipped) for one impact."""
    exact, fd_error = ref.output_derivatives(params, speed, angle, omega0, inputs=inputs)
    scale_in = {"angle_deg": 180.0 / math.pi, "omega0": speed / params.radius, "speed": speed}
    scale_out = {"cor_n": 1.0, "vt_out": speed, "omega_out": speed / params.radius,
                 "rebound_angle_deg": 180.0 / math.pi}  # fmt: skip
    worst, compared, skipped = 0.0, 0, 0
    for out in OUTPUTS:
        cols = [c for c in inputs if c in exact[out]]
        if out == "contact_time":
            s_out = abs(exact["contact_time"]["K"] * params.K) if "K" in cols else None
        s_out = s_out if out == "contact_time" and s_out else scale_out.get(out, 1.0)

        def x(c):
            if c in scale_in:
                return scale_in[c]
            return abs(params.lam if c == "lambda" else getattr(params, c))

        want = {c: exact[out][c] * x(c) / s_out for c in cols}
        typical = max(abs(v) for v in want.values())
        for c in cols:
            scale = max(abs(want[c]), 1e-2 * typical, 1e-12)
            if fd_error[out][c] * x(c) / s_out > 0.1 * TOL * scale:
                skipped += 1
                continue
            got = jac[out][inputs.index(c)] * x(c) / s_out
            worst = max(worst, abs(got - want[c]) / scale)
            compared += 1
    return worst, compared, skipped


def check_against_reference(moments, n_impacts, inputs, name, fast=False):
    rng = np.random.default_rng(seed(name))
    for _ in range(10):  # redraw scenes whose impacts mostly capture (derivatives of rebounds)
        scene, params = random_scene(rng, moments)
        speed, angle, omega0 = random_impacts(rng, params, n_impacts)
        status = np.asarray(ji.simulate(scene, speed, angle, omega0).status)
        keep = status == ji.Status.REBOUND
        if keep.sum() >= max(1, n_impacts // 2):
            break
    if fast:
        keep[1:] = False
    assert keep.sum() >= (1 if fast else n_impacts // 2), "the random impacts should rebound"
    jac = ji.output_jacobian(scene, speed[keep], angle[keep], omega0[keep], inputs=inputs)
    report = []
    for i, (v, a, w) in enumerate(zip(speed[keep], angle[keep], omega0[keep], strict=True)):
        row = {k: np.asarray(jac[k][i]) for k in OUTPUTS}
        worst, compared, skipped = scaled_errors(row, params, v, a, w, inputs)
        report.append((worst, v, a, w))
        assert compared > skipped
    assert max(r[0] for r in report) < TOL, report


@pytest.mark.parametrize("moments", ["analytical", "none"])
def test_derivatives_match_exact_reference_fast(moments):
    """A fast subset: one spinning oblique impact, the parameters a fit identifies and the
    impact inputs."""
    inputs = ("f0", "C_A", "C_H", "friction", "speed", "omega0")
    if moments == "none":
        inputs = ("C_H", "friction", "K", "angle_deg", "omega0")
    check_against_reference(moments, 2, inputs, f"fast-{moments}", fast=True)


@pytest.mark.slow
@pytest.mark.parametrize("moments", ["analytical", "lambda", "none"])
def test_derivatives_match_exact_reference_all_inputs(moments):
    inputs = tuple(c for c in INPUTS if not (c == "lambda" and moments != "lambda"))
    if moments == "none":
        inputs = tuple(c for c in inputs if c not in ("f0", "C_A"))
    check_against_reference(moments, 4, inputs, f"slow-{moments}")


@pytest.mark.slow  # about 25 s (a lambda program of its own and its forward-mode program)
def test_strong_lambda_moment_values_and_derivatives_match_reference():
    """A constant-lambda scene whose moment stops the spin within the contact (lambda 6e-7
    N m on a 20 um sphere): at normal incidence without spin (the sphere rolls from the first
    touch; a slip left to the ODE's pull lagged behind the moment and put d/d angle 3 % off)
    and oblique spinning impacts that pass from sliding to rolling mid-contact (the slip
    width's error: 1.6e-3 at width 1e-3). Values within 1e-5 of the speed, derivatives 1e-3."""
    values = dict(radius=20e-6, density=4600.0, K=5.3e10, f0=170.0, C_A=2.0, C_H=0.08,
                  friction=0.38, lam=6e-7)  # fmt: skip
    scene = ji.Scene(
        particle=ji.Particle(radius=values["radius"], density=values["density"]),
        contact=ji.Contact(**{k: values[k] for k in ("K", "f0", "C_A", "C_H", "friction")}),
        model=ji.Model(rolling_moments="lambda", lambda_=values["lam"]),
    )
    params = ref.Params(**values, adhesion=True, rolling_moments="lambda")
    speed, angle, omega0 = (
        np.array([1.5, 1.8, 1.6]),
        np.array([0.0, -5.0, -15.0]),
        np.array([0.0, -5000.0, -12000.0]),
    )
    got = ji.simulate(scene, speed, angle, omega0)
    inputs = ("f0", "C_A", "lambda", "friction", "speed", "angle_deg", "omega0")
    jac = ji.output_jacobian(scene, speed, angle, omega0, inputs=inputs, program="compact")
    for i in range(3):
        exact = ref.simulate_impact(params, speed[i], angle[i], omega0[i], rtol=1e-12)
        assert exact.status == "rebound" and exact.roll_time < exact.contact_time  # it rolls
        v_n = speed[i] * math.cos(math.radians(angle[i]))
        assert abs(float(got.cor_n[i]) - exact.vn_out / v_n) < 1e-5
        assert abs(float(got.vt_out[i]) - exact.vt_out) / speed[i] < 1e-5
        r = values["radius"]
        assert abs(float(got.omega_out[i]) - exact.omega_out) * r / speed[i] < 1e-5
        row = {k: np.asarray(jac[k][i]) for k in OUTPUTS}
        worst, compared, skipped = scaled_errors(row, params, speed[i], angle[i], omega0[i], inputs)
        assert compared > skipped and worst < TOL, (i, worst)


def test_normal_incidence_spin_derivative_is_exact():
    """Normal impact without spin or rolling moments: the sphere rolls at once, so the exact
    d omega_out / d omega0 is 2/7 (angular momentum about the contact point), d(vt_out)/d angle
    is (5/7) speed pi/180 and d(omega_out)/d angle is (5/7) (speed/r) pi/180."""
    r, speed = 20e-6, 1.0
    scene = ji.Scene(
        particle=ji.Particle(radius=r, density=2500.0),
        contact=ji.Contact(K=5e10, f0=0.0, C_A=0.0, C_H=0.2, friction=0.4),
        model=ji.Model(adhesion=False, rolling_moments="none"),
    )
    jac = ji.output_jacobian(scene, speed, 0.0, 0.0, inputs=("angle_deg", "omega0"))
    d_angle = math.pi / 180.0
    assert float(jac["omega_out"][0, 1]) == pytest.approx(2 / 7, rel=TOL)
    assert float(jac["vt_out"][0, 0]) == pytest.approx(5 / 7 * speed * d_angle, rel=TOL)
    assert float(jac["omega_out"][0, 0]) == pytest.approx(5 / 7 * speed / r * d_angle, rel=TOL)


BATCH = (
    np.array([1.5, 1.0, 0.3, 5.0, 0.05, 2.0, 0.7]),
    np.array([0.0, 30.0, -50.0, 70.0, 10.0, 0.0, -20.0]),
    np.array([12000.0, 0.0, 3000.0, -20000.0, 0.0, 0.0, 5e4]),
)


def test_batch_does_not_change_a_lane(table1):
    """Outputs bitwise: alone, in a batch, in a shuffled batch."""
    speed, angle, omega0 = BATCH
    batch = ji.simulate(table1, speed, angle, omega0)
    perm = np.random.default_rng(seed("shuffle")).permutation(len(speed))
    shuffled = ji.simulate(table1, speed[perm], angle[perm], omega0[perm])
    for i in range(len(speed)):
        alone = ji.simulate(table1, speed[i], angle[i], omega0[i])
        j = int(np.flatnonzero(perm == i)[0])
        for k in ("cor_n", "vt_out", "omega_out", "contact_time", "steps"):
            a, b, c = (np.asarray(getattr(x, k)) for x in (alone, batch, shuffled))
            np.testing.assert_array_equal(a, b[i], err_msg=f"{k}, impact {i}")
            np.testing.assert_array_equal(c[j], b[i], err_msg=f"{k}, impact {i} shuffled")


@pytest.mark.slow  # two forward-mode programs: CI's second step
def test_batch_does_not_change_a_lanes_derivatives(table1):
    """Derivatives to 1e-12: alone and in a batch."""
    speed, angle, omega0 = BATCH
    inputs = ("C_H", "speed")
    jac = ji.output_jacobian(table1, speed, angle, omega0, inputs=inputs)
    jac_alone = ji.output_jacobian(table1, speed[0], angle[0], omega0[0], inputs=inputs)
    for k in OUTPUTS:
        np.testing.assert_allclose(jac_alone[k][0], jac[k][0], rtol=1e-12, atol=0, err_msg=k)


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_sharded_batch_equals_single_device(tmp_path):
    """Split over two host devices, each lane gives the same bits as on one device."""
    script = tmp_path / "shard.py"
    script.write_text(
        "import jax, numpy as np\n"
        "jax.config.update('jax_enable_x64', True)\n"
        "import jaximpact as ji\n"
        "assert len(jax.local_devices()) == 2\n"
        "s = ji.table1_scene()\n"
        "v = np.linspace(0.3, 4.0, 6); a = np.linspace(-60, 60, 6); w = np.linspace(-1e4, 1e4, 6)\n"
        "r = ji.simulate(s, v, a, w)\n"
        f"np.save({str(tmp_path / 'out.npy')!r}, "
        "np.stack([np.asarray(r.cor_n), np.asarray(r.omega_out)]))\n"
    )
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    subprocess.run([sys.executable, str(script)], check=True, env=env, timeout=600)
    sharded = np.load(tmp_path / "out.npy")
    s = ji.table1_scene()
    v, a, w = np.linspace(0.3, 4.0, 6), np.linspace(-60, 60, 6), np.linspace(-1e4, 1e4, 6)
    one = ji.simulate(s, v, a, w)
    np.testing.assert_array_equal(
        sharded, np.stack([np.asarray(one.cor_n), np.asarray(one.omega_out)])
    )


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_grad_jacfwd_jacrev_agree(table1):
    speed, angle, omega0 = np.array([1.2, 0.8]), np.array([25.0, -40.0]), np.array([0.0, 8000.0])
    inputs = ("f0", "C_H", "friction", "angle_deg")
    fwd = ji.output_jacobian(table1, speed, angle, omega0, inputs=inputs, mode="fwd")
    rev = ji.output_jacobian(table1, speed, angle, omega0, inputs=inputs, mode="rev")

    def cor_of_f0(f0):
        scene = table1.replace(contact={"f0": f0})
        return ji.simulate(scene, speed[0], angle[0], omega0[0]).cor_n

    g = jax.grad(cor_of_f0)(jnp.asarray(float(table1.contact.f0)))
    for k in OUTPUTS:
        np.testing.assert_allclose(
            fwd[k], rev[k], rtol=1e-9, atol=1e-12 * float(np.abs(fwd[k]).max()), err_msg=k
        )
    assert float(g) == pytest.approx(float(fwd["cor_n"][0, 0]), rel=1e-9)


def test_eager_gradient_loads_its_program_and_matches_central_differences(table1):
    """``jax.grad`` called outside ``jit`` (concrete primals) takes the tangent program through
    the traced-program cache; it is the derivative of the values ``simulate`` returns
    (central differences of them, step 1e-4 of f0, to TOL: the adaptive steps change with
    f0, measured 4.4e-4)."""
    from jaximpact._engine import simulate as engine

    speed, angle = np.array([0.9, 2.0]), np.array([20.0, -35.0])

    def loss(f0):
        return jnp.sum(ji.simulate(table1.replace(contact={"f0": f0}), speed, angle).vt_out)

    before = {k for k in engine._CACHED_PROGRAMS if k[0] == "tangents"}
    grad = float(jax.grad(loss)(300.0))
    assert {k for k in engine._CACHED_PROGRAMS if k[0] == "tangents"} - before
    h = 0.03
    central = (float(loss(300.0 + h)) - float(loss(300.0 - h))) / (2 * h)
    assert grad != 0.0 and grad == pytest.approx(central, rel=TOL)


@pytest.mark.slow  # three derivative programs: CI's second step
def test_eager_derivatives_match_the_jit_and_vmap_paths(table1):
    """The eager path's derivatives (the tangent program from the traced-program cache)
    equal those traced inside ``jax.jit`` and ``jax.vmap`` (the other path) to the last bits
    of the final sums, with several perturbed inputs (scene parameters and the angle)."""
    speed, angle = np.array([0.9, 2.0]), np.array([20.0, -35.0])

    def loss(x):
        scene = table1.replace(contact={"f0": x[0], "friction": x[1]})
        return jnp.sum(ji.simulate(scene, speed, angle + 0.0 * x[0]).vt_out)

    x = jnp.array([300.0, 0.3])
    eager = np.asarray(jax.grad(loss)(x))
    traced = np.asarray(jax.jit(jax.grad(loss))(x))
    mapped = np.asarray(jax.vmap(jax.grad(loss))(x[None]))[0]
    assert np.all(np.isfinite(eager)) and np.all(eager != 0.0)
    np.testing.assert_allclose(eager, traced, rtol=1e-12, atol=0)
    np.testing.assert_allclose(eager, mapped, rtol=1e-12, atol=0)


def test_ledger_closes_without_rotation(table1):
    """With rotation off the initial spin is ignored, and so is its energy (issue 10)."""
    scene = table1.replace(model={"rotation": False})
    res = ji.simulate(scene, np.array([1.0, 2.0]), np.array([30.0, 0.0]), np.array([2e4, -5e4]))
    losses = sum(
        np.asarray(getattr(res, k))
        for k in ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling")
    )
    gap = (np.asarray(res.energy_in) - np.asarray(res.energy_out) - losses) / np.asarray(
        res.energy_in
    )
    assert np.all(np.abs(gap) < 1e-6), gap


def _shared_parameter_case():
    """The scene, a batch mixing normal, oblique and spinning impacts, and a function of a
    shared speed offset and f0 (the call pattern of a fit)."""
    scene = ji.table1_scene().replace(
        particle={"radius": 45e-6, "density": 1200.0},
        contact={"K": 4e9, "f0": 65.0, "C_A": 0.22, "C_H": 0.06, "friction": 0.12},
        model={"rolling_moments": "analytical"},
    )
    v = np.array([0.7, 2.2, 1.1, 4.5, 3.0, 0.9, 6.0, 1.6])
    a = np.array([0.0, 0.0, 15.0, -40.0, 60.0, 30.0, -20.0, 45.0])
    w = np.array([0.0, 2e4, 0.0, -1.2e4, 5e3, 0.0, 3e4, -8e3])

    def outputs(d, v0, a0, w0):
        r = ji.simulate(scene.replace(contact={"f0": 65.0 + d[1]}), v0 + d[0], a0, w0)
        return jnp.stack([r.cor_n, r.vt_out / v0, r.omega_out * 45e-6 / v0])

    return scene, v, a, w, outputs


def test_shared_parameter_derivatives_are_batch_exact():
    """The call pattern of a fit: ``jit(jacfwd)`` and ``grad`` of a batch's outputs with
    respect to parameters shared by the whole batch (a speed offset and f0), on a scene with
    rolling moments and a batch that mixes normal, oblique and spinning impacts. Each impact's
    derivatives are the same alone, in the batch and in a shuffled batch (to 1e-12; the
    engine gives them bitwise)."""
    scene, v, a, w, outputs = _shared_parameter_case()
    jac = jax.jit(jax.jacfwd(outputs))
    zero = jnp.zeros(2)
    batch = np.asarray(jac(zero, v, a, w))  # (3, 8, 2)
    perm = np.random.default_rng(seed("perm")).permutation(8)
    shuffled = np.asarray(jac(zero, v[perm], a[perm], w[perm]))
    alone = np.stack(
        [np.asarray(jac(zero, v[i : i + 1], a[i : i + 1], w[i : i + 1]))[:, 0] for i in range(8)],
        axis=1,
    )
    assert np.all(np.isfinite(batch)) and np.any(np.abs(batch) > 1e-3)
    np.testing.assert_allclose(batch, alone, rtol=1e-12, atol=0)
    np.testing.assert_allclose(shuffled, batch[:, perm], rtol=1e-12, atol=0)


@pytest.mark.slow  # two reverse-mode programs (~25 s): CI's second step
def test_shared_parameter_gradient_is_batch_exact():
    """``jit(grad)`` of the sum of a batch's ``cor_n`` with respect to the shared parameters:
    the column sums of ``jacfwd`` and the sum of the impacts' gradients taken alone (1e-12)."""
    scene, v, a, w, outputs = _shared_parameter_case()
    zero = jnp.zeros(2)
    batch = np.asarray(jax.jit(jax.jacfwd(outputs))(zero, v, a, w))
    grad = jax.jit(jax.grad(lambda d, v0, a0, w0: jnp.sum(outputs(d, v0, a0, w0)[0])))
    g_batch = np.asarray(grad(zero, v, a, w))
    np.testing.assert_allclose(g_batch, batch[0].sum(axis=0), rtol=1e-12)
    one = [(v[i : i + 1], a[i : i + 1], w[i : i + 1]) for i in range(8)]
    g_alone = sum(np.asarray(grad(zero, *x)) for x in one)
    np.testing.assert_allclose(g_batch, g_alone, rtol=1e-12)
