"""``simulate(compact=True)``: Tsit5's stages in a loop (compiled once), for compile-bound work.

The compact program is a different XLA program, so its bits differ from the default's; what
must hold is the same method (Tsit5, to rounding), the same answers to the solver's tolerance,
the same batch independence, and derivatives that agree with the default's.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaximpact as ji
from jaximpact._tsit5 import LaneTsit5

from test_derivatives import BATCH, seed

OUTPUTS = ("cor_n", "vt_out", "omega_out", "contact_time")


def test_stage_loop_is_tsit5():
    """One step with the stages in a loop: Tsit5's step, error estimate and dense output."""
    term = diffrax.ODETerm(lambda t, y, args: {"a": -y["a"] * y["b"], "b": jnp.sin(t) + y["a"]})
    y0 = {"a": jnp.asarray(1.3), "b": jnp.asarray(-0.4)}
    t0, t1 = 0.2, 0.5
    loop, ref = LaneTsit5(stage_loop=True), diffrax.Tsit5()
    y1, err1, dense1, k1, _ = loop.step(
        term, t0, t1, y0, None, loop.init(term, t0, t1, y0, None), False
    )
    y2, err2, dense2, _, _ = ref.step(term, t0, t1, y0, None, ref.init(term, t0, t1, y0, None), False)
    interp1 = loop.interpolation_cls(t0=t0, t1=t1, **dense1)
    interp2 = ref.interpolation_cls(t0=t0, t1=t1, **dense2)
    for k in y0:
        assert float(y1[k]) == pytest.approx(float(y2[k]), rel=1e-14, abs=1e-15)
        assert float(err1[k]) == pytest.approx(float(err2[k]), rel=1e-9, abs=1e-17)
        for t in np.linspace(t0, t1, 5):
            assert float(interp1.evaluate(t)[k]) == pytest.approx(
                float(interp2.evaluate(t)[k]), rel=1e-13, abs=1e-13
            )
    # FSAL: the last stage is the vector field at y1
    f1 = jax.flatten_util.ravel_pytree(term.vf(t1, y1, None))[0]
    np.testing.assert_allclose(np.asarray(k1), np.asarray(f1), rtol=1e-14)


def test_compact_batch_does_not_change_a_lane(table1):
    """Outputs and step counts bitwise: alone, in a batch, in a shuffled batch; and within the
    solver's tolerance of the default program."""
    speed, angle, omega0 = BATCH
    batch = ji.simulate(table1, speed, angle, omega0, compact=True)
    perm = np.random.default_rng(seed("shuffle-compact")).permutation(len(speed))
    shuffled = ji.simulate(table1, speed[perm], angle[perm], omega0[perm], compact=True)
    default = ji.simulate(table1, speed, angle, omega0)
    for i in (0, 3, 6):
        alone = ji.simulate(table1, speed[i], angle[i], omega0[i], compact=True)
        j = int(np.flatnonzero(perm == i)[0])
        for k in (*OUTPUTS, "steps"):
            a, b, c = (np.asarray(getattr(x, k)) for x in (alone, batch, shuffled))
            np.testing.assert_array_equal(a, b[i], err_msg=f"{k}, impact {i}")
            np.testing.assert_array_equal(c[j], b[i], err_msg=f"{k}, impact {i} shuffled")
    np.testing.assert_array_equal(np.asarray(batch.status), np.asarray(default.status))
    scale = {"cor_n": 1.0, "vt_out": speed, "omega_out": speed / table1.particle.radius}
    for k in OUTPUTS:
        got, want = np.asarray(getattr(batch, k)), np.asarray(getattr(default, k))
        s = scale.get(k, np.abs(want))
        assert np.all(np.abs(got - want) <= 1e-7 * s), (k, got, want)


@pytest.mark.slow  # two forward-mode programs: CI's second step
def test_compact_derivatives_match_default(table1):
    """Forward-mode derivatives of the compact program against the default program's, which
    tests/test_derivatives.py checks against the exact reference."""
    speed, angle, omega0 = np.array([1.2, 0.8, 3.0]), np.array([25.0, -40.0, 0.0]), np.array(
        [0.0, 8000.0, -2e4]
    )

    def outputs(x, compact):
        scene = table1.replace(contact={"f0": x[0], "C_H": x[1], "friction": x[2]})
        r = ji.simulate(
            scene, speed, angle, omega0, adjoint=diffrax.ForwardMode(), compact=compact
        )
        return jnp.stack([r.cor_n, r.vt_out / speed, r.omega_out * table1.particle.radius / speed])

    c = table1.contact
    x0 = jnp.asarray([c.f0, c.C_H, c.friction], dtype=float)
    jac = {k: jax.jacfwd(lambda x, k=k: outputs(x, k))(x0) * x0 for k in (False, True)}
    typical = np.abs(np.asarray(jac[False])).max(axis=(1, 2), keepdims=True)
    err = np.abs(np.asarray(jac[True]) - np.asarray(jac[False])) / typical
    assert err.max() < 1e-5, err
