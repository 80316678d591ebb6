"""The batch paths of issue 12: a large batch in chunks, bitwise the unchunked batch.

Small chunks (2-8 lanes) stand in for ``CHUNK``: the code path is the same, and the programs
stay small. Checked by hand (not here: it needs a process with two host devices): a sharded
chunked batch gives the bits of one device, and its program has the unchunked one's
collectives only (the loops' all-reduces).
"""

import diffrax
import jax
import numpy as np
import pytest

import jaximpact as ji
from jaximpact._engine import simulate as sim

FIELDS = ("status", "steps", "cor_n", "vt_out", "omega_out", "contact_time", "max_overlap")
FIELDS += ("loss_friction", "energy_out")


def impacts(n, seed=12):
    rng = np.random.default_rng(seed)
    speed = rng.uniform(0.5, 5.0, n)
    angle = rng.uniform(-60.0, 60.0, n)
    omega0 = rng.uniform(-2e4, 2e4, n)
    speed[1] = 0.02  # a capture among the rebounds
    return speed, angle, omega0


@pytest.mark.parametrize("n, chunk", [(17, 4), pytest.param(16, 8, marks=pytest.mark.slow)])
def test_chunked_batch_is_bitwise_the_unchunked_batch(table1, n, chunk):
    """Outputs and step counts: same bits, for a multiple of the chunk and not."""
    speed, angle, omega0 = impacts(n)
    whole = sim._simulate(table1, speed, angle, omega0, chunk=0)
    chunked = sim._simulate(table1, speed, angle, omega0, chunk=chunk)
    assert np.asarray(whole.status)[1] == ji.Status.CAPTURED
    for k in FIELDS:
        a, b = np.asarray(getattr(whole, k)), np.asarray(getattr(chunked, k))
        assert a.shape == b.shape == (n,)
        np.testing.assert_array_equal(a, b, err_msg=k)


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_default_chunk_used_by_simulate(table1, monkeypatch):
    """``simulate`` chunks a batch larger than the default chunk and keeps each lane's bits."""
    speed, angle, omega0 = impacts(11)
    whole = sim._simulate(table1, speed, angle, omega0, chunk=0)
    # the tests run on a CPU, with the loop kernels that ``import jaximpact`` sets
    default = sim.CHUNK_LOOP_KERNEL if sim.loop_kernels() else sim.CHUNK_ONE_DEVICE
    assert sim._default_chunk(1) == default
    monkeypatch.setattr(sim, "CHUNK_ONE_DEVICE", 4)
    monkeypatch.setattr(sim, "CHUNK_LOOP_KERNEL", 4)
    res = ji.simulate(table1, speed.reshape(11, 1), angle.reshape(11, 1), omega0.reshape(11, 1))
    assert res.cor_n.shape == (11, 1)
    for k in FIELDS:
        np.testing.assert_array_equal(
            np.asarray(getattr(res, k))[:, 0], np.asarray(getattr(whole, k)), err_msg=k
        )


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_chunked_forward_derivatives_match_unchunked(table1):
    """``jax.jacfwd`` through a chunked batch: the unchunked derivatives to 1e-12."""
    speed, angle, omega0 = impacts(9, seed=3)

    def outputs(x, chunk):
        scene = table1.replace(contact={"C_H": x[0], "f0": x[1]})
        r = sim._simulate(scene, speed, angle, omega0, adjoint=diffrax.ForwardMode(), chunk=chunk)
        return jax.numpy.stack([r.cor_n, r.vt_out, r.omega_out])

    x = jax.numpy.asarray([table1.contact.C_H, table1.contact.f0])
    whole = np.asarray(jax.jacfwd(lambda x: outputs(x, 0))(x))
    chunked = np.asarray(jax.jacfwd(lambda x: outputs(x, 4))(x))
    assert np.all(np.isfinite(whole[:, [0, 2, 3, 4, 5, 6, 7, 8]]))
    scale = np.nanmax(np.abs(whole), axis=1, keepdims=True)
    np.testing.assert_allclose(chunked, whole, rtol=1e-12, atol=1e-12 * scale.max())


@pytest.mark.slow  # reverse mode through lax.map compiles for minutes: CI's second step
def test_chunked_reverse_gradient_matches_unchunked(table1):
    """``jax.grad`` through a chunked batch (reverse mode through ``lax.map``)."""
    speed, angle, omega0 = impacts(5, seed=4)
    speed[1] = 1.0

    def loss(c_h, chunk):
        scene = table1.replace(contact={"C_H": c_h})
        return sim._simulate(scene, speed, angle, omega0, chunk=chunk).cor_n.sum()

    c_h = jax.numpy.asarray(table1.contact.C_H)
    whole = float(jax.grad(lambda c: loss(c, 0))(c_h))
    chunked = float(jax.grad(lambda c: loss(c, 2))(c_h))
    assert np.isfinite(whole)
    assert chunked == pytest.approx(whole, rel=1e-12)


def _assert_same(a, b):
    for k in FIELDS:
        np.testing.assert_array_equal(np.asarray(getattr(a, k)), np.asarray(getattr(b, k)), k)


@pytest.mark.slow  # compiles diffeqsolve's program: CI's second step
def test_default_loop_is_bitwise_diffeqsolve(table1):
    """The default step loop for concrete inputs (``_fast_loop``'s lean loop): diffrax's
    arithmetic without its bookkeeping, the same bits (rebounds and a capture), chunked."""
    speed, angle, omega0 = impacts(7, seed=5)
    ref = sim._simulate(table1, speed, angle, omega0, chunk=0, loop="diffrax")
    default = sim._simulate(table1, speed, angle, omega0, chunk=4)
    assert np.asarray(ref.status)[1] == ji.Status.CAPTURED
    _assert_same(default, ref)


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_lean_loop_is_bitwise_diffeqsolve_compact_program(table1):
    """The same for the fit's compact program."""
    speed, angle, omega0 = impacts(9, seed=7)
    kw = dict(chunk=0, program="compact")
    ref = sim._simulate(table1, speed, angle, omega0, loop="diffrax", **kw)
    lean = sim._simulate(table1, speed, angle, omega0, loop="lean", **kw)
    assert np.asarray(ref.status)[1] == ji.Status.CAPTURED
    _assert_same(lean, ref)


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_lean_loop_float32_agrees_with_diffeqsolve_to_the_event_tolerance(table1):
    """float32: the lean loop's event locator (Newton in a bracket) and diffeqsolve's bisection
    stop at different points inside the event tolerance (1000 ulp of time, 1.2e-4), so the
    outputs agree to that tolerance, not bitwise; the steps before the event are the same."""
    speed, angle, omega0 = impacts(9, seed=7)
    with jax.enable_x64(False):
        kw = dict(chunk=0, program="throughput")
        ref = sim._simulate(table1, speed, angle, omega0, loop="diffrax", **kw)
        lean = sim._simulate(table1, speed, angle, omega0, loop="lean", **kw)
    assert np.asarray(ref.status)[1] == ji.Status.CAPTURED
    for k in ("status", "steps"):
        np.testing.assert_array_equal(np.asarray(getattr(lean, k)), np.asarray(getattr(ref, k)))
    for k in ("cor_n", "vt_out", "omega_out", "contact_time", "energy_out"):
        a, b = np.asarray(getattr(lean, k), float), np.asarray(getattr(ref, k), float)
        scale = np.max(np.abs(b))
        np.testing.assert_allclose(a, b, rtol=2e-4, atol=2e-4 * scale, err_msg=k)


@pytest.mark.slow  # compiles diffeqsolve's program: CI's second step
def test_lean_loop_reports_the_step_limit_as_diffeqsolve(table1):
    """Failures too: impacts that run out of steps end ``max_steps`` with NaN outputs in both
    loops (same step counts), the others as before."""
    speed, angle, omega0 = impacts(5, seed=8)
    scene = table1.replace(solver={"max_steps": 200})
    ref = sim._simulate(scene, speed, angle, omega0, chunk=0, loop="diffrax")
    lean = sim._simulate(scene, speed, angle, omega0, chunk=0)
    status = np.asarray(ref.status)
    assert (status == ji.Status.MAX_STEPS).any() and (status != ji.Status.MAX_STEPS).any()
    assert np.isnan(np.asarray(lean.cor_n)[status == ji.Status.MAX_STEPS]).all()
    _assert_same(lean, ref)


@pytest.mark.slow  # compiles programs of its own: CI's second step
def test_lean_loop_derivatives_match_diffeqsolve(table1):
    """Traced inputs (here ``jax.jacfwd``) run the lean loop with tangents (the locator's
    implicit-function derivative at the event); diffeqsolve differentiates through its own
    root find. The two are derivatives of the same discrete solution: equal to 1e-12."""
    speed, angle, omega0 = impacts(3, seed=6)

    def cor(c_h, loop):
        scene = table1.replace(contact={"C_H": c_h})
        r = sim._simulate(scene, speed, angle, omega0, adjoint=diffrax.ForwardMode(), loop=loop)
        return r.cor_n

    c_h = jax.numpy.asarray(table1.contact.C_H)
    lean = np.asarray(jax.jacfwd(lambda c: cor(c, "lean"))(c_h))
    ref = np.asarray(jax.jacfwd(lambda c: cor(c, "diffrax"))(c_h))
    assert np.all(lean[[0, 2]] != 0)
    np.testing.assert_allclose(lean, ref, rtol=1e-12, atol=1e-14)


def slow_impacts(n, seed=2026):
    """Slow impacts near capture, where a few grazing ones take many times the median steps."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.02, 0.3, n), rng.uniform(-89.9, 89.9, n), rng.uniform(-2e4, 2e4, n)


@pytest.mark.slow  # compiles four programs (~80 s on 2 cores): CI's second step
def test_float32_pool_is_batch_independent(table1):
    """float32 runs its lanes as a pool (refilled as impacts finish, the last ones gathered in
    fewer lanes): an impact's bits do not depend on its batch, its place or the chunk size,
    and they agree with ``diffeqsolve``'s to float32 rounding."""
    speed, angle, omega0 = slow_impacts(40)
    with jax.enable_x64(False):
        whole = sim._simulate(table1, speed, angle, omega0, chunk=8)  # 16 lanes, refilled
        perm = np.random.default_rng(0).permutation(40)
        shuffled = sim._simulate(table1, speed[perm], angle[perm], omega0[perm], chunk=24)
        few = sim._simulate(table1, speed[:5], angle[:5], omega0[:5], chunk=8)
        ref = sim._simulate(table1, speed, angle, omega0, chunk=0, loop="diffrax")
    steps = np.asarray(whole.steps)
    assert steps.max() > 4 * steps.min()  # uneven lanes: 40 impacts in 16 lanes, refilled
    inverse = np.argsort(perm)
    for k in FIELDS:
        a = np.asarray(getattr(whole, k))
        np.testing.assert_array_equal(np.asarray(getattr(shuffled, k))[inverse], a, k)
        np.testing.assert_array_equal(np.asarray(getattr(few, k)), a[:5], k)
    np.testing.assert_array_equal(np.asarray(whole.status), np.asarray(ref.status))
    for k in ("cor_n", "vt_out", "contact_time"):
        np.testing.assert_allclose(
            np.asarray(getattr(whole, k)),
            np.asarray(getattr(ref, k)),
            rtol=2e-3,
            atol=1e-6,
            err_msg=k,
        )


@pytest.mark.slow  # compiles two programs (~30 s on 2 cores): CI's second step
def test_float64_pool_matches_the_chunked_loop(table1, monkeypatch):
    """float64 with ``loop="pool"`` (the posterior sampler's evaluations): an impact's bits do
    not depend on its batch or place, and the values are those of the chunked lean loop (the
    default) to a small multiple of rounding: same status, same step count."""
    traced = []
    pool = sim.step_loop.solve_pool
    monkeypatch.setattr(
        sim.step_loop, "solve_pool", lambda *a, **k: traced.append(1) or pool(*a, **k)
    )
    speed, angle, omega0 = slow_impacts(40, seed=7)
    whole = sim._simulate(table1, speed, angle, omega0, chunk=8, loop="pool")
    assert traced  # the pool ran (float64 no longer falls back to the chunked loop)
    perm = np.random.default_rng(1).permutation(40)
    shuffled = sim._simulate(table1, speed[perm], angle[perm], omega0[perm], chunk=8, loop="pool")
    lean = sim._simulate(table1, speed, angle, omega0, chunk=8)
    steps = np.asarray(whole.steps)
    assert steps.max() > 3 * steps.min()  # uneven lanes: the pool refills them
    inverse = np.argsort(perm)
    for k in FIELDS:
        a = np.asarray(getattr(whole, k))
        np.testing.assert_array_equal(np.asarray(getattr(shuffled, k))[inverse], a, k)
    for k in ("status", "steps"):
        np.testing.assert_array_equal(np.asarray(getattr(whole, k)), np.asarray(getattr(lean, k)))
    for k in ("cor_n", "vt_out", "omega_out", "contact_time"):
        np.testing.assert_allclose(
            np.asarray(getattr(whole, k)), np.asarray(getattr(lean, k)), rtol=1e-9, atol=1e-12,
            err_msg=k,
        )  # fmt: skip
