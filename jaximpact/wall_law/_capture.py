"""The capture speed: the impact speed below which the sphere sticks, for each incidence angle
and spin, found on the simulator and differentiated by the implicit-function theorem.

The capture margin
------------------
``g(v) = (vn_out / v)^2``, the normal kinetic energy after a rebound over the impact's kinetic
energy. It is smooth in ``v`` and every parameter on the rebound side, and falls to 0 at the
capture speed ``v_c``, where the sphere leaves the surface with no normal speed left (the
normal energy at separation goes to zero linearly in ``v - v_c``, so ``vn_out`` goes like
``sqrt(v - v_c)`` but ``g`` does not). Below ``v_c`` the simulator reports a capture, for
which ``g`` has no value: the root is found from the rebound side, with the captured speeds as
the other end of a bracket.

Search
------
1. Scan: ``SCAN_POINTS`` speeds, geometric, from ``1e-3`` to ``1e3`` times the adhesion speed
   ``v_a = sqrt(2 |V_min| / m)`` (``V_min = -(8/15) pi f0 sqrt(r) (2 pi f0 / K)^1.5``, the
   depth of the adhesive well of the normal potential), cut at the speed range's top
   (1000 m/s).
2. Rule: the capture speed is the lowest speed at which the scan goes from captured to
   rebound (the upper end of the lowest captured band that has a rebound right above it).
   Captured at every scanned speed below it and rebound at every one above: status
   ``threshold``. Any other pattern is ``multiple``: a rebound below it (a captured band
   above rebounds at lower speeds) or a capture above it (a band of rebounds between speeds
   that stick); ``next_capture`` is then the lowest scanned speed above it that sticks. (On
   the scenes tried, strong damping gave one threshold or a capture at every scanned speed,
   ``all_captured``: Table 1 with ``C_H`` up to 2.5 s/m has one threshold, with 3 s/m none.)
3. Root: secant steps on ``g`` through the two lowest rebound speeds of the bracket, kept inside
   it; a step that lands on a capture moves the captured end and the next step is taken just
   above it; bisection where the secant leaves the bracket. Converged when the bracket or the
   secant step is below ``rtol`` of the speed.

Solver: with ``solver.method = "auto"`` each lane runs its whole search on one solver, chosen
for it alone by the engine's rule at its scan's lowest and highest speed; a lane whose impact
still reaches ``max_steps`` on its solver moves to the other one (:class:`_Lanes`).

Derivatives (implicit-function theorem): ``dv_c = -(dg/dp . dp) / (dg/dv)``, with the partial
derivatives of the simulator (forward mode) taken at ``v_c (1 + eps)`` and ``v_c (1 + 2 eps)``
and extrapolated to ``v_c`` (Richardson: the partials at ``v_c`` itself would read a capture).
"""

from __future__ import annotations

import collections
import functools
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._engine.simulate import scene_parameters
from ..parameters import with_parameters
from ._checks import SPEED_MAX as SPEED_MAX
from ._checks import _checked_concrete, _checked_options, _is_concrete
from ._lanes import IMPLICIT_METHOD, _Lanes

__all__ = ["CaptureSpeed", "CaptureStatus", "adhesion_speed", "capture_speed", "scene_with"]

SCAN_POINTS = 19  # three per decade over six decades of v / v_a
SCAN_RANGE = (1e-3, 1e3)  # in units of the adhesion speed v_a
RTOL = 1e-9  # relative tolerance of the root
MAX_ITERATIONS = 40
EPS = 1e-4  # relative offset above v_c of the derivative points (Richardson to v_c)
COMPACT_LANES = 64  # searches of at most this many lanes run the compact program


class CaptureStatus:
    """Status codes of :func:`capture_speed` (``CaptureSpeed.status``).

    - ``THRESHOLD`` (0): captured below the speed, rebound above it, over the whole scan.
    - ``NO_ADHESION`` (1): the scene has no adhesion (``f0 = 0`` or ``model.adhesion =
      false``): nothing sticks, the speed is 0 (exactly, with zero derivatives).
    - ``MULTIPLE`` (2): capture is not one threshold in speed. The speed is the lowest at which
      the scan goes from captured to rebound; a scanned speed below it rebounds, or one above
      it (``CaptureSpeed.next_capture``, the lowest) is captured again.
    - ``NONE_IN_RANGE`` (3): every scanned speed rebounds: the capture speed, if any, lies
      below the scan (``speed`` is then the lowest scanned speed, an upper bound).
    - ``ALL_CAPTURED`` (4): no captured speed of the scan has a rebound right above it (the
      sphere sticks up to the top of the scan; ``speed`` is ``inf``).
    - ``FAILED`` (5): an impact of the scan or the root find failed (``speed`` is NaN).
    - ``NOT_CONVERGED`` (6): the root find used its iterations without reaching the tolerance
      (``speed`` is the best estimate).
    """

    THRESHOLD = 0
    NO_ADHESION = 1
    MULTIPLE = 2
    NONE_IN_RANGE = 3
    ALL_CAPTURED = 4
    FAILED = 5
    NOT_CONVERGED = 6
    NAMES = {
        0: "threshold",
        1: "no_adhesion",
        2: "multiple",
        3: "none_in_range",
        4: "all_captured",
        5: "failed",
        6: "not_converged",
    }


class CaptureSpeed(eqx.Module):
    """Result of :func:`capture_speed` (arrays of the broadcast shape of its inputs).

    - `speed`: capture speed, m/s (see `status` for what it means where it is not one
      threshold).
    - `status`: :class:`CaptureStatus` codes (int).
    - `bracket`: ``(lo, hi)``, m/s: the fastest speed found captured and the slowest found
      rebounding below and above `speed` (for a lane without a root: the scan's ends).
    - `next_capture`: m/s, the lowest scanned speed above `speed` at which the sphere sticks
      again (status ``multiple``), else ``inf`` (resolution: the scan's step, a factor 2.15).
    - `evaluations`: impacts simulated per value (scan and root find).
    - `implicit`: how many values ended their search on the implicit solver (``solver.method =
      "auto"``: each value's solver is chosen once for its whole search, by the engine's
      stiffness rule at the scan's lowest and highest speed).
    - `retried`: how many values changed solver (explicit to implicit or back) because an
      impact reached ``max_steps`` on the first one (that impact was run again).
    """

    speed: jax.Array
    status: jax.Array
    bracket: tuple
    next_capture: jax.Array
    evaluations: int = eqx.field(static=True, default=0)
    implicit: int = eqx.field(static=True, default=0)
    retried: int = eqx.field(static=True, default=0)

    @property
    def status_names(self) -> np.ndarray:
        codes = np.asarray(self.status)
        return np.vectorize(lambda c: CaptureStatus.NAMES[int(c)], otypes=[object])(codes)


def scene_with(scene, params: dict):
    """``scene`` with its float parameters replaced by ``params`` (impacts-CSV names: those of
    ``jaximpact.parameters.PARAMETERS``)."""
    return with_parameters(scene, params)


def adhesion_speed(radius, density, K, f0, w=None, law="brach_dunn"):
    """``v_a = sqrt(2 |V_min| / m)`` (m/s): the speed whose kinetic energy fills the adhesive
    well of the normal potential ``V(n) = (2/5) K sqrt(r) n^2.5 - (4/3) pi f0 sqrt(r) n^1.5``
    (minimum at ``n = 2 pi f0 / K``). 0 without adhesion. The other normal laws take the work
    of adhesion ``w``: DMT's well ``(3/5) 2 pi w r n_e`` (``n_e = (2 pi w sqrt(r) /
    K)^(2/3)``), JKR's snap-off loss ``c_W (w^5 r^4 / E^2)^(1/3)`` (``E = 3 K / 4``; also
    for Thornton-Ning, whose yield only raises the capture speed above it)."""
    xp = jnp if any(isinstance(x, jax.Array) for x in (radius, density, K, f0, w)) else np
    mass = density * 4.0 / 3.0 * math.pi * radius**3
    if law == "dmt":
        n_e = (2.0 * math.pi * w * xp.sqrt(radius) / K) ** (2.0 / 3.0)
        depth = 0.6 * 2.0 * math.pi * w * radius * n_e
    elif law in ("jkr", "thornton_ning"):  # (Thornton-Ning: its elastic JKR part's)
        from ..reference.jkr import C_W

        depth = C_W * (w**5 * radius**4 / (0.75 * K) ** 2) ** (1.0 / 3.0)
    else:
        n_e = 2.0 * math.pi * f0 / K
        depth = (8.0 / 15.0) * math.pi * f0 * xp.sqrt(radius) * n_e**1.5
    return xp.sqrt(2.0 * depth / mass)


def _margin(scene, params, speed, angle_deg, omega0):
    """``g = (vn_out / speed)^2`` and the simulator's status."""
    from .._engine.api import simulate

    res = simulate(scene_with(scene, params), speed, angle_deg, omega0)
    return (res.vn_out / speed) ** 2, res.status


def capture_speed(
    scene, angle_deg=0.0, omega0=0.0, *, rtol: float = RTOL, speed_range=None
) -> CaptureSpeed:
    """The impact speed below which the sphere is captured (sticks), per angle and spin.

    **Arguments:**
    - `scene`: a `Scene`; its float parameters may be arrays (one value per entry), broadcast
      with `angle_deg` and `omega0`.
    - `angle_deg`: incidence from the surface normal (degrees, in (-90, 90)).
    - `omega0`: initial spin (rad/s, signed as in `simulate`).
    - `rtol`: relative tolerance of the root (default 1e-9).
    - `speed_range`: ``(lo, hi)`` in m/s to scan instead of ``1e-3 .. 1e3`` times the adhesion
      speed (:func:`adhesion_speed`).

    **Returns:** a :class:`CaptureSpeed`: `speed` (m/s) and `status` (:class:`CaptureStatus`;
    check it: where capture is not one threshold the speed follows the documented rule).

    Differentiable (``jax.grad``, ``jax.jacfwd``, ``jax.jvp``) with respect to every scene
    parameter and `angle_deg`, `omega0`, by the implicit-function theorem on the capture margin
    (module docstring). The search runs on concrete values: not under ``jax.jit`` or
    ``jax.vmap`` (pass arrays instead: the values are batched).

    **Raises:** `SceneError` (a `ValueError`) for inputs outside their ranges, traced primal
    values (under ``jit``/``vmap``), or a scene with a ``[target]`` sphere.
    """
    speed_range = _checked_options(scene, rtol, speed_range)
    params = scene_parameters(scene)
    adhesive = bool(scene.model.adhesion)
    names = tuple(params)
    evaluations, solvers = [], []

    def search(values, angle, omega):
        a, w = _checked_concrete(values, angle, omega)
        out = _remembered_search(scene, names, values, a, w, adhesive, rtol, speed_range)
        evaluations.append(out["evaluations"])
        solvers.append((int(out["implicit"].sum()), int(out["retried"].sum())))
        dtype = jnp.result_type(float)
        fields = (out["speed"], out["status"].astype(float), out["lo"], out["hi"], out["next"])
        return tuple(jnp.asarray(x, dtype) for x in fields)

    @jax.custom_jvp
    def solve(values, angle, omega):
        return search(values, angle, omega)

    @solve.defjvp
    def solve_jvp(primals, tangents):
        values, angle, omega = primals
        dvalues, dangle, domega = tangents
        out = search(values, angle, omega)
        v_c, status = np.asarray(out[0]), np.asarray(out[1]).astype(int)
        dv = _implicit_tangent(
            scene, names, values, angle, omega, v_c, status, dvalues, dangle, domega
        )
        zero = jnp.zeros_like(out[0])
        return out, (dv, zero, zero, zero, zero)

    dtype = jnp.result_type(float)
    values = tuple(jnp.asarray(params[k], dtype) for k in names)
    speed, status, lo, hi, again = solve(
        values, jnp.asarray(angle_deg, dtype), jnp.asarray(omega0, dtype)
    )
    return CaptureSpeed(
        speed=speed,
        status=jax.lax.stop_gradient(status).astype(int),
        bracket=(jax.lax.stop_gradient(lo), jax.lax.stop_gradient(hi)),
        next_capture=jax.lax.stop_gradient(again),
        evaluations=int(evaluations[-1]) if evaluations else 0,
        implicit=solvers[-1][0] if solvers else 0,
        retried=solvers[-1][1] if solvers else 0,
    )


def _remembered_search(scene, names, values, a, w, adhesive, rtol, speed_range) -> dict:
    """:func:`_search`, or its result for the same inputs kept from a recent call."""
    memo = (
        _structure_key(scene, names),
        tuple(np.asarray(v, dtype=float).tobytes() for v in (*values, a, w)),
        tuple(np.shape(v) for v in (*values, a, w)),
        rtol,
        speed_range,
    )
    if memo in _SEARCHES:  # e.g. the value, then its gradient: one search
        return _SEARCHES[memo]
    out = _search(scene, names, values, a, w, adhesive, rtol, speed_range)
    _SEARCHES[memo] = out
    while len(_SEARCHES) > _SEARCHES_KEPT:
        _SEARCHES.popitem(last=False)
    return out


# The last few searches of this process, by scene structure and input values: `jax.grad`
# calls the function again, and its derivative rule needs the root that the value found.
_SEARCHES: collections.OrderedDict = collections.OrderedDict()
_SEARCHES_KEPT = 4


def _flat_inputs(names, values, angle, omega):
    arrays = [np.asarray(v, dtype=float) for v in values]
    angle, omega = np.asarray(angle, dtype=float), np.asarray(omega, dtype=float)
    shape = np.broadcast_shapes(angle.shape, omega.shape, *(a.shape for a in arrays))
    size = int(np.prod(shape))
    flat = lambda x: np.broadcast_to(x, shape).reshape(size).copy()  # noqa: E731
    params = {k: flat(a) for k, a in zip(names, arrays, strict=True)}
    return params, flat(angle), flat(omega), shape


def _search(scene, names, values, angle, omega, adhesive, rtol, speed_range, program=None) -> dict:
    """The search of the module docstring on concrete values; numpy arrays of ``shape``.
    ``program``: the simulator's (default: by the number of lanes, below)."""
    from .._engine.api import simulate

    params, angle, omega, shape = _flat_inputs(names, values, angle, omega)
    size = angle.size
    speed = np.zeros(size)
    status = np.full(size, CaptureStatus.NO_ADHESION)
    lo_out, hi_out, again = np.zeros(size), np.zeros(size), np.full(size, np.inf)
    strength = params["f0"] if scene.model.normal == "brach_dunn" else params["w"]
    lanes = np.flatnonzero(strength > 0) if adhesive else np.array([], int)
    evaluations = 0
    implicit, retried = np.zeros(size, bool), np.zeros(size, bool)
    if lanes.size:
        sub = {k: v[lanes] for k, v in params.items()}
        # A search of a few lanes is compile-bound: the compact program compiles in half the
        # time (cold capture_speed at one angle: 6.1 against 8.6 s) and runs 2x slower
        # (warm 1.6 against 1.2 s); larger batches keep the throughput program.
        if program is None:
            program = "compact" if lanes.size <= COMPACT_LANES else "throughput"
        run = functools.partial(simulate, program=program)
        res = _root(run, scene, sub, angle[lanes], omega[lanes], rtol, speed_range)
        speed[lanes], status[lanes] = res["speed"], res["status"]
        lo_out[lanes], hi_out[lanes] = res["lo"], res["hi"]
        again[lanes] = res["next"]
        implicit[lanes], retried[lanes] = res["implicit"], res["retried"]
        evaluations = res["evaluations"]
    reshape = lambda x: x.reshape(shape)  # noqa: E731
    return {
        "speed": reshape(speed),
        "status": reshape(status),
        "lo": reshape(lo_out),
        "hi": reshape(hi_out),
        "next": reshape(again),
        "evaluations": evaluations,
        "implicit": reshape(implicit),
        "retried": reshape(retried),
    }


def scan_speeds(
    params: dict, speed_range=None, points: int = SCAN_POINTS, law: str = "brach_dunn"
) -> np.ndarray:
    """The scanned speeds, ``(lanes, points)`` m/s (module docstring)."""
    if speed_range is not None:
        grid = np.geomspace(speed_range[0], speed_range[1], points)
        return np.broadcast_to(grid, (np.size(params["f0"]), points)).copy()
    v_a = adhesion_speed(
        params["radius"], params["density"], params["K"], params["f0"], params.get("w"), law
    )
    grid = np.asarray(v_a)[:, None] * np.geomspace(*SCAN_RANGE, points)
    return np.minimum(grid, SPEED_MAX)


def _root(simulate, scene, params, angle, omega, rtol, speed_range, grid=None) -> dict:
    """Scan, rule and root find (module docstring) for lanes with adhesion; ``grid``: the
    speeds to scan, ``(lanes, points)``, instead of :func:`scan_speeds`."""
    n = angle.size
    if grid is None:
        grid = scan_speeds(params, speed_range, law=scene.model.normal)
    lanes = _Lanes(simulate, scene, params, angle, omega, grid)
    run = lanes.run
    points = grid.shape[1]
    st_scan = np.empty((n, points), int)
    g_scan = np.empty((n, points))
    for k in range(points):  # one batch shape throughout: one compiled program
        st_scan[:, k], g_scan[:, k] = run(grid[:, k])

    speed = np.full(n, np.nan)
    lo, hi = np.full(n, np.nan), np.full(n, np.nan)
    status, top = classify(st_scan)
    again = next_capture(st_scan, grid, top)
    none = status == CaptureStatus.NONE_IN_RANGE
    all_cap = status == CaptureStatus.ALL_CAPTURED
    speed[none], speed[all_cap] = grid[none, 0], np.inf
    active = np.isin(status, (CaptureStatus.THRESHOLD, CaptureStatus.MULTIPLE))
    a, b, estimate, done, steps = _secant_search(run, grid, g_scan, top, active, status, rtol)
    still = ~done
    status[still & active] = CaptureStatus.NOT_CONVERGED
    ok = active & (status != CaptureStatus.FAILED)
    speed[ok] = estimate[ok]
    lo[active], hi[active] = a[active], b[active]
    for mask, value in ((none, grid[:, 0]), (all_cap, grid[:, -1])):
        lo[mask] = np.where(none[mask], 0.0, value[mask])
        hi[mask] = np.where(none[mask], value[mask], np.inf)
    return {
        "speed": speed,
        "status": status,
        "lo": lo,
        "hi": hi,
        "next": again,
        "evaluations": points + steps,
        "implicit": lanes.method == IMPLICIT_METHOD,
        "retried": lanes.retried,
    }


def _secant_search(run, grid, g_scan, top, active, status, rtol) -> tuple:
    """The root find of the module docstring from the scan's bracket, for the ``active``
    lanes (every lane is simulated at each step: one batch shape); a lane whose impact fails
    gets status ``FAILED`` (``status`` is updated in place). Returns ``(a, b, estimate, done,
    steps)``: each lane's captured and rebound ends of the bracket, its estimate, whether it
    stopped (converged or failed), and the number of steps run."""
    n, points = grid.shape
    idx = np.arange(n)
    # bracket: a captured, b < c the next rebounds (c may be missing: NaN)
    t = np.clip(top, 0, points - 1)
    a = grid[idx, t]
    b = grid[idx, np.minimum(t + 1, points - 1)]
    gb = g_scan[idx, np.minimum(t + 1, points - 1)]
    c = np.where(t + 2 < points, grid[idx, np.minimum(t + 2, points - 1)], np.nan)
    gc = np.where(t + 2 < points, g_scan[idx, np.minimum(t + 2, points - 1)], np.nan)
    lefts = np.zeros(n, int)  # consecutive steps that landed on a capture
    done = ~active
    estimate = np.where(active, b, grid[:, 0])  # finite: every lane is simulated each step
    steps = 0
    for _ in range(MAX_ITERATIONS):
        if done.all():
            break
        secant = _secant(b, gb, c, gc)
        ok = np.isfinite(secant) & (secant > a) & (secant < b)
        bisect = np.sqrt(a * b)
        x = np.where(ok, secant, bisect)
        # after a step landed on a capture, aim just above the captured end: the secant's
        # error is second order, so the root is within about (b - a)^2 / b of it
        near = a + np.minimum(0.5 * (b - a), 4.0 * (b - a) ** 2 / b)
        x = np.where(lefts == 1, near, x)
        x = np.where(lefts >= 2, 0.5 * (a + b), x)
        x = np.where(done, estimate, x)
        st, g = run(x)
        steps += 1
        bad = ~done & (st >= 2)
        status[bad] = CaptureStatus.FAILED
        done |= bad
        cap = ~done & (st == 1)
        reb = ~done & (st == 0)
        a = np.where(cap, x, a)
        lefts = np.where(cap, lefts + 1, np.where(reb, 0, lefts))
        step = np.abs(b - x)
        c, gc = np.where(reb, b, c), np.where(reb, gb, gc)
        b, gb = np.where(reb, x, b), np.where(reb, g, gb)
        secant = _secant(b, gb, c, gc)
        good = np.isfinite(secant) & (secant >= a) & (secant <= b)
        estimate = np.where(~done, np.where(good, secant, b), estimate)
        # converged: the bracket, or a secant step, below the tolerance (at the noise level of
        # the margin the next secant would be meaningless)
        converged = ~done & (((b - a) <= rtol * b) | (reb & (step <= rtol * b)))
        done |= converged
    return a, b, estimate, done, steps


def classify(scan_status) -> tuple[np.ndarray, np.ndarray]:
    """The rule of the module docstring on the simulator's statuses of the scan (lanes, points;
    speeds increasing): ``(status, top)``, ``top`` the index of the captured speed of the
    lowest captured-to-rebound step (-1 if none)."""
    st = np.asarray(scan_status)
    n, points = st.shape
    failed = np.any(st >= 2, axis=1)
    captured, rebound = st == 1, st == 0
    step = captured[:, :-1] & rebound[:, 1:]
    top = np.where(step.any(axis=1), np.argmax(step, axis=1), -1)
    index = np.arange(points)[None, :]
    below = index < top[:, None]
    above = index > top[:, None] + 1
    status = np.full(n, CaptureStatus.THRESHOLD)
    other = np.any(rebound & below, axis=1) | np.any(captured & above, axis=1)
    status[other] = CaptureStatus.MULTIPLE
    status[(top == -1) & captured.any(axis=1)] = CaptureStatus.ALL_CAPTURED
    status[~captured.any(axis=1)] = CaptureStatus.NONE_IN_RANGE
    status[failed] = CaptureStatus.FAILED
    return status, top


def next_capture(scan_status, grid, top) -> np.ndarray:
    """The lowest scanned speed above the step ``top`` that is captured (inf if none)."""
    st = np.asarray(scan_status)
    index = np.arange(st.shape[1])[None, :]
    again = (st == 1) & (index > np.asarray(top)[:, None] + 1) & (np.asarray(top)[:, None] >= 0)
    first = np.argmax(again, axis=1)
    return np.where(again.any(axis=1), grid[np.arange(st.shape[0]), first], np.inf)


def _secant(b, qb, c, qc):
    """Root in ``v`` of the line through ``(b^2, qb)`` and ``(c^2, qc)`` (NaN if none)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        s = b**2 - qb * (c**2 - b**2) / (qc - qb)
        return np.where(s > 0, np.sqrt(np.abs(s)), np.nan)


def _implicit_tangent(scene, names, values, angle, omega, v_c, status, dvalues, dangle, domega):
    """``dv_c`` by the implicit-function theorem (module docstring).

    The partial derivatives of the margin with respect to every input (each scene parameter,
    the angle, the spin and the speed) are computed at once, as concrete numbers, by one
    forward-mode program with a tangent per input; ``dv_c`` is then their combination with
    the caller's tangents. So the compiled program is the same whichever parameters the
    caller differentiates (``jax.grad`` in f0, then in C_H, compile nothing new), and a
    gradient in every parameter costs one program run."""
    dtype = jnp.result_type(float)
    shape = np.shape(v_c)
    usable = np.isin(status, (CaptureStatus.THRESHOLD, CaptureStatus.MULTIPLE)) & np.isfinite(v_c)
    fill = jnp.asarray(np.where(status == CaptureStatus.NO_ADHESION, 0.0, np.nan), dtype)
    if not usable.any():
        return jnp.zeros(shape, dtype) * fill
    factors = np.array([1.0 + EPS, 1.0 + 2.0 * EPS])
    safe_vc = np.where(usable, v_c, 1.0)
    speeds = jnp.asarray(safe_vc[..., None] * factors, dtype)  # (*shape, 2)
    inputs = jnp.stack(
        [jnp.broadcast_to(jnp.asarray(x, dtype), shape) for x in (*values, angle, omega)]
    )  # (inputs, *shape): the primals, concrete
    partials = _margin_partials(scene, names, inputs, speeds)  # (inputs + 1, *shape, 2)
    dg_dv = partials[-1]
    tangents = [*dvalues, dangle, domega]
    dg_dp = sum(
        partials[k] * jnp.broadcast_to(jnp.asarray(t, dtype), shape)[..., None]
        for k, t in enumerate(tangents)
    )
    ratio = -dg_dp / jnp.where(dg_dv == 0, jnp.nan, dg_dv)
    dv = 2.0 * ratio[..., 0] - ratio[..., 1]
    return jnp.where(jnp.asarray(usable), dv, fill)


# The partials' compiled programs of this process, by scene structure and shapes (the most
# recently used few).
_PARTIALS_PROGRAMS: collections.OrderedDict = collections.OrderedDict()
_PARTIALS_PROGRAMS_KEPT = 8


def _margin_partials(scene, names, inputs, speeds):
    """``dg/dx`` for every row ``x`` of ``inputs`` (the scene parameters ``names``, the angle,
    the spin), then ``dg/dv``, at the points ``speeds`` (*shape, 2): ``(len(inputs) + 1,
    *shape, 2)``, by forward mode with one tangent per input.

    One compiled program, through the traced-program cache (``_io.cache.compiled_program``):
    run op by op, the transformations of the simulator were traced again by every process
    (about 4 s) and some 75 small operations compiled one by one (about 2 s cold, loaded one
    by one warm)."""
    from .._io.cache import compiled_program, runtime_checks_as_nan

    dtype = jnp.result_type(float)
    inputs, speeds = jnp.asarray(inputs, dtype), jnp.asarray(speeds, dtype)
    key = _structure_key(scene, names)
    example = (
        jax.ShapeDtypeStruct(inputs.shape, dtype),
        jax.ShapeDtypeStruct(speeds.shape, dtype),
    )
    memo = (key, repr(example))
    if memo not in _PARTIALS_PROGRAMS:

        def partials(inputs, speeds):
            return (_margin_partials_traced(scene, names, inputs, speeds),)

        # Equinox's run-time checks as NaN (a raising check is a host callback, which keeps a
        # program out of the caches): a NaN partial gives a NaN derivative, never a wrong one.
        with runtime_checks_as_nan():
            program, _ = compiled_program("capture_partials", partials, example, key)
        _PARTIALS_PROGRAMS[memo] = program
        while len(_PARTIALS_PROGRAMS) > _PARTIALS_PROGRAMS_KEPT:
            _PARTIALS_PROGRAMS.popitem(last=False)
    _PARTIALS_PROGRAMS.move_to_end(memo)
    return _PARTIALS_PROGRAMS[memo](inputs, speeds)[0]


def _structure_key(scene, names) -> str:
    """What the partials' program depends on besides its inputs: the scene's structure and
    switches, and its values other than ``names`` (those are the program's inputs)."""
    from .._engine.simulate import _NOMINAL

    neutral = scene_with(scene, {n: _NOMINAL[n] for n in names})
    leaves, treedef = jax.tree_util.tree_flatten(neutral)
    values = [repr(x.aval) if not _is_concrete(x) else np.asarray(x).tolist() for x in leaves]
    return repr((str(treedef), tuple(names), values))


def _margin_partials_traced(scene, names, inputs, speeds):
    """:func:`_margin_partials`' computation (traced once per program)."""
    k = inputs.shape[0]
    expand = lambda x: jnp.broadcast_to(x[..., None], speeds.shape)  # noqa: E731

    def g_of(inputs, v):
        params = {n: expand(inputs[i]) for i, n in enumerate(names)}
        g, _ = _margin(scene, params, v, expand(inputs[k - 2]), expand(inputs[k - 1]))
        return g

    basis = jnp.eye(k + 1, dtype=inputs.dtype)

    def along(e):
        tangent = (e[:k].reshape((k,) + (1,) * (inputs.ndim - 1)) * jnp.ones_like(inputs),
                   e[k] * jnp.ones_like(speeds))  # fmt: skip
        return jax.jvp(g_of, (inputs, speeds), tangent)[1]

    return jax.vmap(along)(basis)
