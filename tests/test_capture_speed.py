"""capture_speed against the exact reference's threshold (bisection) and its derivatives
against central differences of that threshold."""

import dataclasses

import jax
import numpy as np
import pytest

import jaximpact as ji
from jaximpact import reference
from jaximpact.wall_law import CaptureStatus
from jaximpact.wall_law._capture import classify, next_capture, scene_with

NAMES = ("radius", "density", "K", "f0", "C_A", "C_H", "friction")


def random_parameters(n: int, seed: int) -> dict:
    """Adhesive microsphere scenes, moderate damping (an explicit solver suits them all)."""
    rng = np.random.default_rng(seed)
    return {
        "radius": np.exp(rng.uniform(np.log(5e-6), np.log(50e-6), n)),
        "density": rng.uniform(2000.0, 9000.0, n),
        "K": np.exp(rng.uniform(np.log(2e10), np.log(2e11), n)),
        "f0": rng.uniform(50.0, 500.0, n),
        "C_A": rng.uniform(0.2, 2.0, n),
        "C_H": rng.uniform(0.05, 0.5, n),
        "friction": rng.uniform(0.1, 0.5, n),
    }


def reference_params(values: dict, i=None) -> reference.Params:
    pick = (lambda v: float(v)) if i is None else (lambda v: float(np.asarray(v)[i]))
    return reference.Params(
        radius=pick(values["radius"]),
        density=pick(values["density"]),
        K=pick(values["K"]),
        f0=pick(values["f0"]),
        C_A=pick(values["C_A"]),
        C_H=pick(values["C_H"]),
        friction=pick(values["friction"]),
    )


def reference_threshold(p, angle, omega0=0.0, guess=None, rel_tol=1e-10, width=0.1):
    """The reference's capture speed by bisection in ``guess (1 -+ width)`` (raises
    ``ValueError`` if that does not straddle it)."""
    lo, hi = (1 - width) * guess, (1 + width) * guess
    return reference.capture_speed(p, angle, omega0, lo=lo, hi=hi, rel_tol=rel_tol)


@pytest.fixture(scope="module")
def scenes():
    """Table 1 and a random adhesive scene, as one scene with arrays of shape (2, 1) (with two
    angles: four lanes, as the wall-law tests use, so that both share one compiled program)."""
    table1 = {k: float(v) for k, v in ji.scene_parameters(ji.table1_scene()).items()}
    rand = random_parameters(1, seed=23)
    values = {k: np.concatenate([[table1[k]], rand[k]])[:, None] for k in NAMES}
    return values, scene_with(ji.table1_scene(), values)


def test_capture_speed_matches_reference_bisection(scenes):
    values, scene = scenes
    angles = np.array([0.0, 45.0])
    got = ji.capture_speed(scene, angles, 0.0)
    assert got.speed.shape == (2, 2)
    assert np.all(np.asarray(got.status) == CaptureStatus.THRESHOLD)
    lo, hi = (np.asarray(b) for b in got.bracket)
    speed = np.asarray(got.speed)
    assert np.all((lo <= speed) & (speed <= hi))
    for i in range(2):
        p = reference_params(values, (i, 0))
        for j, angle in enumerate(angles):
            # a bracket of 1e-5 around our value: the reference must find its threshold there
            want = reference_threshold(p, angle, guess=speed[i, j], rel_tol=1e-9, width=1e-5)
            assert abs(speed[i, j] / want - 1) < 1e-6, (i, angle, speed[i, j], want)
    # the simulator itself: captured just below, rebound just above
    below = ji.simulate(scene, speed * (1 - 1e-5), angles, 0.0)
    above = ji.simulate(scene, speed * (1 + 1e-5), angles, 0.0)
    assert np.all(np.asarray(below.status) == ji.Status.CAPTURED)
    assert np.all(np.asarray(above.status) == ji.Status.REBOUND)


def test_no_adhesion_is_zero_with_zero_derivatives():
    scene = ji.table1_scene().replace(contact={"f0": 0.0})
    got = ji.capture_speed(scene, [0.0, 30.0])
    assert np.all(np.asarray(got.speed) == 0.0)
    assert list(got.status_names) == ["no_adhesion", "no_adhesion"]
    off = ji.table1_scene().replace(model={"adhesion": False})
    assert float(ji.capture_speed(off).speed) == 0.0
    grad = jax.grad(
        lambda c: ji.capture_speed(ji.table1_scene().replace(contact={"C_A": c, "f0": 0.0})).speed
    )(0.5)
    assert float(grad) == 0.0


def test_rule_for_scans_that_are_not_one_threshold():
    # speeds increase along each row: 0 rebound, 1 captured, 2+ failed
    scan = np.array(
        [
            [1, 1, 1, 0, 0, 0],  # one threshold
            [1, 0, 1, 0, 0, 0],  # captured again above the lowest step
            [0, 0, 1, 1, 0, 0],  # rebounds below the only captured band
            [1, 1, 0, 0, 1, 1],  # captured again at high speed (overdamped)
            [0, 0, 0, 0, 0, 0],  # nothing captured in the scan
            [1, 1, 1, 1, 1, 1],  # everything captured
            [0, 0, 1, 1, 1, 1],  # captured from some speed up: no captured-to-rebound step
            [1, 2, 0, 0, 0, 0],  # a failure
        ]
    )
    status, top = classify(scan)
    assert list(status) == [
        CaptureStatus.THRESHOLD,
        CaptureStatus.MULTIPLE,
        CaptureStatus.MULTIPLE,
        CaptureStatus.MULTIPLE,
        CaptureStatus.NONE_IN_RANGE,
        CaptureStatus.ALL_CAPTURED,
        CaptureStatus.ALL_CAPTURED,
        CaptureStatus.FAILED,
    ]
    # the speed is the lowest captured-to-rebound step; above it, where capture comes back
    assert list(top[:4]) == [2, 0, 3, 1]
    grid = np.broadcast_to(np.arange(6.0), scan.shape)
    assert list(next_capture(scan, grid, top)[:4]) == [np.inf, 2.0, np.inf, 4.0]


def test_traced_values_and_bad_inputs_are_refused():
    scene = ji.table1_scene()
    with pytest.raises(ji.SceneError, match="concrete"):
        jax.jit(lambda f0: ji.capture_speed(scene.replace(contact={"f0": f0})).speed)(325.0)
    with pytest.raises(ji.SceneError, match="angle_deg"):
        ji.capture_speed(scene, 90.0)
    with pytest.raises(ji.SceneError, match="speed_range"):
        ji.capture_speed(scene, 0.0, speed_range=(1.0, 0.5))


def central_difference(p, name, angle, omega0, guess, rel_step=1e-3):
    h = rel_step * getattr(p, name)
    up = reference_threshold(dataclasses.replace(p, **{name: getattr(p, name) + h}), angle,
                             omega0, guess)  # fmt: skip
    down = reference_threshold(dataclasses.replace(p, **{name: getattr(p, name) - h}), angle,
                               omega0, guess)  # fmt: skip
    return (up - down) / (2 * h)


@pytest.mark.slow  # compiles the tangent program (about a minute), then 40 bisections
@pytest.mark.parametrize("angle,omega0", [(0.0, 0.0), (45.0, 0.0), (30.0, 2e4)])
def test_derivatives_match_central_differences_of_the_reference(angle, omega0):
    values = {k: float(v[1]) for k, v in random_parameters(2, seed=7).items()}
    scene = scene_with(ji.table1_scene(), values)

    def speed(vals):
        return ji.capture_speed(scene_with(scene, vals), angle, omega0).speed

    jac = jax.jacfwd(speed)(values)
    v0 = float(speed(values))
    p = reference_params(values)
    assert abs(reference_threshold(p, angle, omega0, v0) / v0 - 1) < 1e-6
    names = ("radius", "density", "K", "f0", "C_A", "C_H") + (("friction",) if omega0 else ())
    for name in names:
        want = central_difference(p, name, angle, omega0, v0)
        got = float(jac[name])
        # the oracle's resolution: the bisection's error (1e-10 of the speed at each end)
        # over the step; it matters only for derivatives that are zero in all but name
        # (friction with spin: d ln v_c / d ln friction ~ 3e-7)
        noise = 1e-10 * v0 / (1e-3 * getattr(p, name))
        assert abs(got - want) <= 1e-3 * abs(want) + noise, (name, got, want, noise)


@pytest.mark.slow  # compiles the tangent program (30-60 s)
def test_gradients_in_one_parameter_then_another_compile_once(caplog):
    """``jax.grad`` (reverse mode, through the implicit derivative) in f0, then in C_H: equal
    to central differences of the reference's threshold, and the second compiles nothing
    (every partial derivative comes from one program, whichever parameter is asked for)."""
    import logging

    base = ji.table1_scene()

    def vc(f0, c_h):
        return ji.capture_speed(base.replace(contact={"f0": f0, "C_H": c_h}), 30.0).speed

    d_f0 = float(jax.grad(vc, 0)(300.0, 0.25))
    with caplog.at_level(logging.WARNING), jax.log_compiles(True):
        d_ch = float(jax.grad(vc, 1)(300.0, 0.25))
    compiled = [r for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    assert compiled == []
    values = {k: float(v) for k, v in ji.scene_parameters(base).items()}
    p = reference_params({**values, "f0": 300.0, "C_H": 0.25})
    v0 = float(vc(300.0, 0.25))
    for name, got in (("f0", d_f0), ("C_H", d_ch)):
        want = central_difference(p, name, 30.0, 0.0, v0)
        assert abs(got - want) <= 1e-4 * abs(want), (name, got, want)


# Two random scenes (default-prior ranges): the first is stiff at the top of its scan (the
# engine's rule picks Kvaerno5 there), the second is not.
STIFF = {"radius": 1.4633717925197185e-07, "density": 4927.0221866638485,
         "K": 781374782.2287899, "f0": 67630.07261299966, "C_A": 0.08033553615080243,
         "C_H": 0.44270460360479985, "friction": 0.41637495242467326}  # fmt: skip
PLAIN = {"radius": 7.429998260135524e-06, "density": 1828.4499515873742,
         "K": 1341031770765.7307, "f0": 1.6574836937352073, "C_A": 0.010139487487600329,
         "C_H": 0.01804421074975731, "friction": 0.6261826861091994}  # fmt: skip


def test_each_lane_keeps_its_solver_whatever_its_batch():
    """A lane's search runs on one solver, chosen for it alone: beside a stiff scene the plain
    scene's capture speed is the one it has alone (bit for bit). Before, the engine chose the
    solver per call for the whole batch, so the plain lane ran some impacts on Kvaerno5 and its
    search ended ``failed`` (Newton's event location on Kvaerno5's dense output, 1e-9 from the
    capture speed: ``solver_error``)."""
    pair = {k: np.array([STIFF[k], PLAIN[k]]) for k in NAMES}
    got = ji.capture_speed(scene_with(ji.table1_scene(), pair), 0.0)
    assert list(got.status_names) == ["all_captured", "threshold"]
    assert got.implicit == 1
    alone = ji.capture_speed(scene_with(ji.table1_scene(), PLAIN), 0.0)
    assert float(np.asarray(got.speed)[1]) == float(alone.speed)
    # The implicit solver locates the capture near the threshold too (it raised solver_error
    # at this speed).
    v = 2.5720573632796436e-06
    res = ji.simulate(scene_with(ji.table1_scene(), PLAIN), [v, v * (1 - 1e-9)], 0.0, 0.0,
                      method="kvaerno5")  # fmt: skip
    assert set(res.status_names) <= {"rebound", "captured"}, res.status_names
