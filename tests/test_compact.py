"""``simulate(program=...)``: two forms of Tsit5's stage sums, each batch-independent.

``"throughput"`` (per state variable, batches padded to whole SIMD lane groups) and
``"compact"`` (the state flattened, the stages in a loop) are different XLA programs, so their
bits differ; what must hold for each is the same method (Tsit5, to rounding), the same answers
to the solver's tolerance, the same independence of the batch, and the same derivatives.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_derivatives import BATCH, seed

import jaximpact as ji
from jaximpact._engine.simulate import PROGRAMS
from jaximpact._engine.tsit5 import STAGE_FORMS, LaneTsit5

OUTPUTS = ("cor_n", "vt_out", "omega_out", "contact_time")


@pytest.mark.parametrize("stages", STAGE_FORMS)
def test_each_stage_form_is_tsit5(stages):
    """One step: Tsit5's step, error estimate, dense output and FSAL stage, to rounding."""
    term = diffrax.ODETerm(lambda t, y, args: {"a": -y["a"] * y["b"], "b": jnp.sin(t) + y["a"]})
    y0 = {"a": jnp.asarray(1.3), "b": jnp.asarray(-0.4)}
    t0, t1 = 0.2, 0.5
    mine, ref = LaneTsit5(stages=stages), diffrax.Tsit5()
    y1, err1, dense1, k1, _ = mine.step(
        term, t0, t1, y0, None, mine.init(term, t0, t1, y0, None), False
    )
    y2, err2, dense2, _, _ = ref.step(
        term, t0, t1, y0, None, ref.init(term, t0, t1, y0, None), False
    )
    interp1 = mine.interpolation_cls(t0=t0, t1=t1, **dense1)
    interp2 = ref.interpolation_cls(t0=t0, t1=t1, **dense2)
    for k in y0:
        assert float(y1[k]) == pytest.approx(float(y2[k]), rel=1e-14, abs=1e-15)
        assert float(err1[k]) == pytest.approx(float(err2[k]), rel=1e-9, abs=1e-17)
        for t in np.linspace(t0, t1, 5):
            assert float(interp1.evaluate(t)[k]) == pytest.approx(
                float(interp2.evaluate(t)[k]), rel=1e-13, abs=1e-13
            )
    f1 = jax.flatten_util.ravel_pytree(term.vf(t1, y1, None))[0]
    k1 = jax.flatten_util.ravel_pytree(k1)[0]
    np.testing.assert_allclose(np.asarray(k1), np.asarray(f1), rtol=1e-14)


def test_unknown_program_is_refused(table1):
    with pytest.raises(ValueError, match="program must be one of"):
        ji.simulate(table1, 1.0, 0.0, 0.0, program="fastest")
    with pytest.raises(ValueError, match="stages must be one of"):
        LaneTsit5(stages="unrolled")


@pytest.mark.parametrize("program", ["throughput", "compact"])
def test_each_program_is_batch_independent(table1, program):
    """Outputs and step counts bitwise: alone, in a batch, and in shuffled sub-batches of odd
    sizes (5 and 13 lanes moved a lane of the per-state form before lane-group padding); and
    within the solver's tolerance of the default program. The default program is checked the
    same way in tests/test_derivatives.py."""
    speed, angle, omega0 = (np.concatenate([x, x[::-1]]) for x in BATCH)  # 14 impacts
    speed = speed * np.linspace(1.0, 1.1, speed.size)  # all distinct
    batch = ji.simulate(table1, speed, angle, omega0, program=program)
    default = ji.simulate(table1, speed, angle, omega0)
    rng = np.random.default_rng(seed(f"sub-batches-{program}"))
    for n in (5, 13):
        pick = rng.choice(speed.size, n, replace=False)
        sub = ji.simulate(table1, speed[pick], angle[pick], omega0[pick], program=program)
        for k in (*OUTPUTS, "steps"):
            np.testing.assert_array_equal(
                np.asarray(getattr(sub, k)), np.asarray(getattr(batch, k))[pick], err_msg=k
            )
    alone = ji.simulate(table1, speed[3], angle[3], omega0[3], program=program)
    for k in (*OUTPUTS, "steps"):
        np.testing.assert_array_equal(
            np.asarray(getattr(alone, k)), np.asarray(getattr(batch, k))[3]
        )
    np.testing.assert_array_equal(np.asarray(batch.status), np.asarray(default.status))
    scale = {"cor_n": 1.0, "vt_out": speed, "omega_out": speed / table1.particle.radius}
    for k in OUTPUTS:
        got, want = np.asarray(getattr(batch, k)), np.asarray(getattr(default, k))
        s = scale.get(k, np.abs(want))
        assert np.all(np.abs(got - want) <= 1e-7 * s), (k, got, want)


@pytest.mark.slow  # three forward-mode programs: CI's second step
def test_programs_give_the_same_derivatives(table1):
    """Forward-mode derivatives of every program against the default program's, which
    tests/test_derivatives.py checks against the exact reference."""
    speed, angle = np.array([1.2, 0.8, 3.0]), np.array([25.0, -40.0, 0.0])
    omega0 = np.array([0.0, 8000.0, -2e4])

    def outputs(x, program):
        scene = table1.replace(contact={"f0": x[0], "C_H": x[1], "friction": x[2]})
        r = ji.simulate(scene, speed, angle, omega0, adjoint=diffrax.ForwardMode(), program=program)
        radius = table1.particle.radius
        return jnp.stack([r.cor_n, r.vt_out / speed, r.omega_out * radius / speed])

    c = table1.contact
    x0 = jnp.asarray([c.f0, c.C_H, c.friction], dtype=float)
    jac = {p: np.asarray(jax.jacfwd(lambda x, p=p: outputs(x, p))(x0) * x0) for p in PROGRAMS}
    typical = np.abs(jac["throughput"]).max(axis=(1, 2), keepdims=True)
    for p in ("compact",):
        err = np.abs(jac[p] - jac["throughput"]) / typical
        assert err.max() < 1e-5, (p, err)


@pytest.mark.parametrize("stages", STAGE_FORMS)
def test_kept_dense_output_locates_the_event_as_the_repeated_step_does(stages):
    """The loop form keeps the last step's dense output in the lane state instead of taking
    that step again to locate the event: the same crossing and state, to the root finder's
    tolerance (1e-12: the step compiled twice may round differently, which moves Newton's
    iterates), with the same derivatives; the empty dense output has the step's structure,
    shapes and dtypes."""
    import optimistix as optx

    from jaximpact._engine import step_loop

    term = diffrax.ODETerm(lambda t, y, args: {"x": y["v"], "v": -args * y["x"] - 0.1 * y["v"]})
    solver = LaneTsit5(stages=stages)
    y0 = {"x": jnp.asarray(1.0), "v": jnp.asarray(0.3)}
    step = solver.step(term, 0.0, 0.1, y0, 2.0, solver.init(term, 0.0, 0.1, y0, 2.0), False)
    want = jax.tree_util.tree_map(lambda a: (a.shape, a.dtype), step[2])
    got = jax.tree_util.tree_map(lambda a: (a.shape, a.dtype), solver.empty_dense_info(y0))
    assert got == want

    def crossing(omega2, keep_dense):  # the first time x falls through 0
        options = dict(
            event=diffrax.Event(
                lambda t, y, args, **kw: y["x"], root_finder=optx.Newton(rtol=1e-12, atol=1e-12)
            ),
            stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10),
            max_steps=1000,
            keep_dense=keep_dense,
        )
        init, running, step, finish = step_loop.lane_functions(
            term, solver, 0.0, 100.0, 0.01, y0, **options
        )
        s = jax.lax.while_loop(running, lambda s: step(s, omega2), init(y0, omega2))
        sol = finish(s, omega2)
        return sol.ts[0], sol.ys["v"][0]

    for omega2 in (2.0, 7.5):
        kept, repeated = crossing(omega2, True), crossing(omega2, False)
        assert 0.0 < float(kept[0]) < 100.0
        np.testing.assert_allclose(np.asarray(kept), np.asarray(repeated), rtol=1e-10)
        d_kept = jax.jacfwd(lambda w: crossing(w, True))(omega2)
        d_repeated = jax.jacfwd(lambda w: crossing(w, False))(omega2)
        np.testing.assert_allclose(np.asarray(d_kept), np.asarray(d_repeated), rtol=1e-9)
