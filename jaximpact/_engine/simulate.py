"""``simulate``: the one public driver, and the only caller of ``diffrax.diffeqsolve``."""

import collections
import dataclasses
import functools

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.custom_derivatives import SymbolicZero

from .._model import dynamics as dyn
from .._model import laws
from .._model.scene import (
    INERTIA_FACTOR,
    Scene,
    SceneError,
    _is_concrete,
    check_impact,
    check_range,
)
from .._model.units import ScaledParameters, hertz_units
from . import step_loop
from .devices import compiled_alone, compiler_options, gathered, loop_kernels, under_trace
from .results import ImpactResult, Status
from .solvers import (
    CAP_WIDTH,
    CONTACT_FLOOR,
    SLIP_RELAXATION,
    default_slip_width,
    default_tolerances,
    make_controller,
    make_solver,
)
from .tsit5 import lane_group

PARAMETERS = ("radius", "density", "K", "f0", "C_A", "C_H", "friction", "lambda")
T_MAX = 1e5  # in Hertz times; the step limit, not this, bounds a slow impact


def scene_parameters(scene: Scene) -> dict:
    """The scene's float parameters by their impacts-CSV column names (and ``G_star`` when the
    scene uses the Mindlin tangential spring, ``w`` with the DMT or JKR normal law,
    ``radius2``, ``density2`` and ``omega2`` with a second sphere)."""
    params = {
        "radius": scene.particle.radius,
        "density": scene.particle.density,
        "K": scene.contact.K,
        "f0": scene.contact.f0,
        "C_A": scene.contact.C_A,
        "C_H": scene.contact.C_H,
        "friction": scene.contact.friction,
        "lambda": scene.model.lambda_,
    }
    if scene.model.tangential == "mindlin":
        params["G_star"] = scene.contact.G_star
    if scene.model.normal in ("dmt", "jkr", "thornton_ning"):
        params["w"] = scene.contact.w
    if scene.model.normal == "thornton_ning":
        params["p_y"] = scene.contact.p_y
    if scene.target is not None:
        params.update(
            radius2=scene.target.radius, density2=scene.target.density, omega2=scene.target.omega0
        )
    return params


class Integration(eqx.Module):
    """Resolved numerical settings (static)."""

    method: str = eqx.field(static=True)
    rtol: float = eqx.field(static=True)
    atol: float = eqx.field(static=True)
    dt: float = eqx.field(static=True)
    max_steps: int = eqx.field(static=True)
    # The form of Tsit5's stage sums (``LaneTsit5.stages``; ``simulate(program=...)``).
    stages: str = eqx.field(static=True, default="per_state")


def _all(values, predicate) -> bool:
    """``predicate`` holds for every element of every value, known without tracing."""
    return all(_is_concrete(v) and bool(np.all(predicate(np.asarray(v)))) for v in values)


def required_terms(scene: Scene, params: dict, angle_deg, omega0) -> dyn.Terms:
    """The terms an impact batch needs, from the switches and, where concrete, the values.

    A normal impact without spin needs no tangential or rotational state; zero ``f0`` needs no
    adhesion terms; zero ``lambda`` (or zero ``C_A`` and ``C_H``) needs no rolling moments.
    Under ``jit``/``grad`` the values are traced and only the switches decide.
    """
    m, s = scene.model, scene.solver
    if m.tangential == "mindlin":
        check_range(
            "contact.G_star (model.tangential = 'mindlin')", params["G_star"], positive=True
        )
    spins = [omega0] + ([params["omega2"]] if "omega2" in params else [])
    tangential = not _all([angle_deg, *spins], lambda v: v == 0)
    strength = params["f0"] if m.normal == "brach_dunn" else params["w"]
    adhesion = m.adhesion and not _all([strength], lambda v: v == 0)
    moments = m.rolling_moments
    if moments == "lambda" and _all([params["lambda"]], lambda v: v == 0):
        moments = "none"
    if moments == "analytical" and _all([params["C_A"], params["C_H"]], lambda v: v == 0):
        moments = "none"
    rotation = m.rotation and tangential
    return dyn.Terms(
        tangential=tangential,
        rotation=rotation,
        adhesion=adhesion,
        rolling_moments=moments if rotation else "none",
        friction_load=m.friction_load,
        slip_width=default_slip_width(jnp.result_type(float), s.slip_width, s.rtol),
        ring_width=s.ring_width,
        ledger=s.outputs == "full",
        contact_floor=CONTACT_FLOOR,
        slip_relaxation=SLIP_RELAXATION,
        mindlin=tangential and m.tangential == "mindlin",
        cap_width=CAP_WIDTH if m.tangential == "mindlin" else 0.0,
        normal=m.normal,
        target=scene.target is not None,
    )


def stiffness_estimate(params: dict, speed, angle_deg):
    """Fastest relaxation rate of the damping and rolling-moment terms, in Hertz units.

    An explicit solver needs of the order of this many steps per impact; ``method="auto"``
    switches to the implicit Kvaerno5 above ``solver.stiffness_limit``.
    """
    p, _ = _scaled(params, speed, angle_deg, 0.0)
    a = jnp.sqrt(p.radius)  # contact radius at unit overlap
    rates = [
        1.25 * p.C_H,  # Hertz damping
        2 * jnp.pi * p.f0 * p.C_A * a,  # adhesion damping
        p.lam * p.C_A * a / p.inertia,  # constant-lambda moment
        jnp.pi * p.f0 * p.C_A * a**3 / p.inertia,  # peeling moment M_A
        p.K / 5 * p.C_H * p.radius**1.5 / p.inertia,  # Hertzian rolling moment M_H
    ]
    if p.inertia2 is not None:  # the moments turn a second sphere too
        rates += [r * p.inertia / p.inertia2 for r in rates[2:]]
    return jnp.max(jnp.stack([jnp.max(r) for r in rates]))


# One compiled program instead of a dozen dispatched operations (about 0.1 s of a warm
# command-line run); values are concrete where it is called (``integration_settings``).
_stiffness_estimate_jit = jax.jit(stiffness_estimate)


def _scaled(params, speed, angle_deg, omega0):
    theta = jnp.deg2rad(angle_deg)
    v_n = speed * jnp.cos(theta)
    mass = params["density"] * (4.0 / 3.0) * jnp.pi * params["radius"] ** 3
    radius, target = params["radius"], None
    if "radius2" in params:  # a sphere-sphere impact: reduced radius and mass
        mass2 = params["density2"] * (4.0 / 3.0) * jnp.pi * params["radius2"] ** 3
        target = (radius, mass, params["radius2"], mass2)
        radius = radius * params["radius2"] / (radius + params["radius2"])
        mass = mass * mass2 / (mass + mass2)
    units = hertz_units(mass, radius, params["K"], v_n)
    p = ScaledParameters.from_si(
        units,
        radius=radius,
        K=params["K"],
        f0=params["f0"],
        C_A=params["C_A"],
        C_H=params["C_H"],
        friction=params["friction"],
        lam=params["lambda"],
        inertia_factor=INERTIA_FACTOR,
        G_star=params.get("G_star"),
        w_adhesion=params.get("w"),
        target=target,
        p_yield=params.get("p_y"),
    )
    return p, units


# Only the motion and the peak overlap drive the step size: the ledger integrals follow it
# (their kinks, e.g. max(ndot, 0) at the turning point, would only cost rejected steps), and
# slide_time (a latch that jumps once, when rolling starts) must not drive it at all.
CONTROLLED_STATES = ("n", "ndot", "vt", "w", "w2", "xi", "peak")


def _error_norm(error):
    """Largest scaled error of the controlled states.

    The maximum (not diffrax's default RMS) is unchanged by states that stay exactly zero, so a
    normal impact takes the same steps whether or not its batch carries tangential states.
    """
    errors = [jnp.abs(v) for k, v in error.items() if k in CONTROLLED_STATES]
    norm = errors[0]
    for e in errors[1:]:
        norm = jnp.maximum(norm, e)
    return norm


def _shell_adhesion(terms: dyn.Terms, p: ScaledParameters):
    """The work of the adhesion force across the shell ``0 <= n <= floor`` (``-V(floor)``) and
    the damping constant of that force while the contact separates (the ring's ``C_A``; the
    DMT force is not damped)."""
    work = -dyn.adhesion_potential(terms, p, terms.contact_floor)
    return work, (p.C_A if terms.ring else 0.0)


def _shell_entry(terms: dyn.Terms, p: ScaledParameters, dtype) -> dict:
    """The approach through the shell ``0 <= n <= floor``, in closed form.

    Energy balance over the shell with the normal speed ~1 there (its change across the shell
    is of order ``floor``): the work of the Hertz force, the Hertz damping and the adhesion
    (the spin-free ring does not damp an approach). The speed at the floor starts the solve.
    """
    eps = terms.contact_floor
    sr = jnp.sqrt(p.radius)
    hertz = 0.4 * p.K * sr * eps**2.5
    work = -hertz * (1.0 + p.C_H)
    if terms.adhesion:
        work = work + _shell_adhesion(terms, p)[0]
    ndot = jnp.sqrt(jnp.asarray(1.0 + 2.0 * work, dtype))
    shell = {"ndot": ndot, "time": 2.0 * eps / (1.0 + ndot), "peak": eps}
    shell["loss_hertz_damping"] = hertz * p.C_H
    shell["loss_adhesion_damping"] = jnp.zeros_like(ndot)
    return shell


# Hertz times after first touch at which an impact below the JKR sticking speed is declared
# captured (the state is then the state at first touch to ~1e-10).
JKR_STUCK_TIME = 1e-10


def _jkr_stuck(terms: dyn.Terms, p: ScaledParameters):
    """Captured at first touch: the JKR barrier ``V(n_c)`` exceeds the normal energy ``1/2``."""
    return dyn.jkr_barrier(terms, p, 0.0 if terms.plastic else None) > 0.5


def _jkr_exit(terms: dyn.Terms, p: ScaledParameters, ndot, xi=None, peak=None) -> dict:
    """The last stretch of a JKR contact, from the separation level ``mu (d_c + floor)`` down
    to the snap-off overlap ``n_c``, in closed form: the potential's change there is exact
    (``V`` is closed-form), the Hertzian damping's work is taken at the mean of the Hertzian
    force at the two ends and the crossing speed. At the snap-off the sphere leaves the
    contact, and the barrier ``V(n_c)`` (the elastic JKR loss, ``c_W (w^5 R^4/E^2)^(1/3)``) is
    the ledger's ``loss_adhesion_damping``.

    ``xi``: the Mindlin spring's displacement at the separation level (held across the
    stretch). Its normal force returns ``(k_t(n_sep) - k_t(n_c)) xi^2 / 2`` to the normal
    motion (exact: the force is minus the gradient of the spring's energy); the contact's
    radius does not vanish at the snap-off, so the spring still holds ``k_t(n_c) xi^2 / 2``
    when the contact breaks: that energy is lost (``spring_lost``, in the ledger's
    ``loss_friction``), as DEM codes drop the tangential history when a contact ends.

    ``peak``: Thornton-Ning's peak overlap, which selects the curve of the stretch."""
    r = dyn.jkr_curve(terms, p, peak)[0]
    n_sep = dyn.separation(terms, p, peak)
    n_c, a_c = dyn.jkr_snap_off(terms, p, peak)
    a_sep = dyn.jkr_contact_radius(terms, p, jnp.full_like(ndot, n_sep), peak)
    barrier = dyn.jkr_barrier(terms, p, peak)
    climb = barrier - laws.jkr_potential(a_sep, r, p.K, p.w_adhesion)
    width = n_sep - n_c
    speed = jnp.abs(ndot)
    hertz = -0.5 * (laws.jkr_hertz_force(a_sep, r, p.K) + laws.jkr_hertz_force(a_c, r, p.K))
    damping = hertz * p.C_H * speed * width
    energy = ndot**2 - 2.0 * (climb + damping)
    spring_lost = None
    if xi is not None:
        half_xi2 = 0.5 * xi * xi
        energy = energy + 2.0 * half_xi2 * 8.0 * p.G_star * (a_sep - a_c)
        spring_lost = half_xi2 * 8.0 * p.G_star * a_c
    shell = {"loss_hertz_damping": damping, "loss_adhesion_damping": barrier}
    shell["peak"] = jnp.zeros_like(ndot)
    shell["ok"] = energy > 0
    out_speed = jnp.sqrt(jnp.where(shell["ok"], energy, 1.0))
    shell["ndot"] = -out_speed
    shell["time"] = 2.0 * width / (speed + out_speed)
    # |integral of the friction load over n| across the stretch (for its tangential impulse)
    adhesive = 0.5 * (
        laws.jkr_adhesion_force(a_sep, p.K, p.w_adhesion)
        + laws.jkr_adhesion_force(a_c, p.K, p.w_adhesion)
    )
    net = jnp.abs(adhesive - hertz * (1.0 + p.C_H * ndot)) * width
    shell["load_work"] = net if terms.friction_load == "net" else hertz * width
    shell["width"] = width
    if spring_lost is not None:  # with the spring's tangential impulse across the stretch
        shell["spring_lost"] = spring_lost
        k_mean = 4.0 * p.G_star * (a_sep + a_c)
        shell["spring_impulse"] = -k_mean * xi * shell["time"]
    return shell


def _shell_exit(
    terms: dyn.Terms, p: ScaledParameters, ndot, spring=None, xi=None, peak=None
) -> dict:
    """The separation through the shell below the floor, in closed form (see ``_shell_entry``).

    ``ndot`` (< 0) is the normal velocity at the floor; returns the velocity at ``n = 0`` and
    ``ok = False`` where the normal energy runs out inside the shell (then a capture).
    ``spring``: the Mindlin spring's energy at the floor, which its normal force returns to the
    normal motion in the shell (its tangential impulse there, ``O(floor^2.5)``, is left out);
    ``xi``: the spring's displacement, for JKR's stretch (:func:`_jkr_exit`); ``peak``:
    Thornton-Ning's peak overlap.
    """
    if terms.jkr:
        return _jkr_exit(terms, p, ndot, xi, peak)
    eps = terms.contact_floor
    sr = jnp.sqrt(p.radius)
    speed = jnp.abs(ndot)
    hertz = 0.4 * p.K * sr * eps**2.5
    shell = {"loss_hertz_damping": hertz * p.C_H * speed, "peak": jnp.zeros_like(ndot)}
    work = hertz - shell["loss_hertz_damping"]
    shell["loss_adhesion_damping"] = jnp.zeros_like(ndot)
    if terms.adhesion:
        adhesion, damping = _shell_adhesion(terms, p)
        shell["loss_adhesion_damping"] = adhesion * damping * speed
        work = work - adhesion - shell["loss_adhesion_damping"]
    if spring is not None:
        work = work + spring
    energy = ndot**2 + 2.0 * work
    shell["ok"] = energy > 0
    out_speed = jnp.sqrt(jnp.where(shell["ok"], energy, 1.0))
    shell["ndot"] = -out_speed
    shell["time"] = 2.0 * eps / (speed + out_speed)
    return shell


def _shell_friction(terms: dyn.Terms, p: ScaledParameters, y: dict, shell: dict, ndot) -> dict:
    """Friction in a contact shell, in closed form: the tangential impulse there.

    The shell is crossed in ``shell["time"]`` at about constant normal speed, so the impulse of
    the friction load is ``f int N dt = f |int F_n dn| time / floor``, with the work integrals
    of the Hertz force, its damping, the ring adhesion and its (spin-free) damping. Near the
    capture speed adhesion dominates the load there and the sphere leaves slowly: ignoring this
    impulse left errors of up to ~5e-5 in ``vt_out/speed`` and ``omega_out r/speed`` (it grows
    like ``floor^1.5 / cor_n``). The impulse is exact Coulomb friction, not regularized: it
    opposes the slip and stops where the slip reaches zero, so a slip smaller than the shell's
    impulse can remove is removed (as in the exact model, where an infinitesimal slip is gone
    in an infinitesimal time). With the regularized sign instead, a slip inside the slip width
    entered the ODE and relaxed there at the pull's finite rate while a rolling moment acted
    on the lagging spin: at normal incidence without spin, derivatives with respect to the
    angle were off by the moment's rate over the pull's (0.2-3 % on lambda-law scenes).
    Rolling moments are left out (their share is ``O(floor^2.5)``, or ``O(lambda C_A w)``
    times the friction's).
    Returns ``vt``, ``w`` after the shell and the friction loss there (which closes the ledger
    exactly: minus the change of tangential and rotational kinetic energy).
    """
    eps = terms.contact_floor
    sr = jnp.sqrt(p.radius)
    hertz = 0.4 * p.K * sr * eps**2.5
    if terms.jkr:  # the exit stretch of a JKR contact (``_jkr_exit``)
        load, eps = shell["load_work"], shell["width"]
    elif terms.friction_load == "net":
        load = -hertz * (1.0 + p.C_H * ndot)
        if terms.adhesion:
            adhesion, damping = _shell_adhesion(terms, p)
            load = load + adhesion * (1.0 + damping * jnp.maximum(-ndot, 0.0))
        load = jnp.abs(load)
    else:
        load = hertz
    impulse = p.friction * load * shell["time"] / eps
    vt = y["vt"]
    w = y["w"] if terms.rotation else jnp.zeros_like(vt)
    m_eff = dyn.slip_mass(terms, p)
    slip = dyn.slip(terms, p, y, w)
    dv = jnp.clip(-m_eff * slip, -impulse, impulse)  # -m_eff slip brings the slip to zero
    out = {"vt": vt + dv, "loss_friction": -dv * slip - 0.5 * dv * dv / m_eff}
    if terms.rotation:
        out["w"] = w - dyn.moment_arm(p) * dv / p.inertia
        if terms.target:  # the second sphere takes the opposite impulse at its own arm
            out["w2"] = y["w2"] - p.arm2 * dv / p.inertia2
    return out


def _shell_spring(terms: dyn.Terms, p: ScaledParameters, y: dict, shell: dict):
    """The Mindlin spring's displacement at the floor, after the entry shell: the slip of the
    shell's crossing time, stuck (``xi = slip * time``), capped by Coulomb friction there.

    Near first contact the ratio ``k_t |xi| / (f N)`` of a sticking contact does not depend on
    the overlap (Hertz: ``k_t ~ n^0.5``, ``xi ~ n``, ``N ~ n^1.5``; adhesion only lowers it), so
    a contact below the cap at the floor stuck throughout the shell, and one at the cap slid
    there with ``xi`` at the cap. A spring started unloaded kept the offset ``slip * time``
    (about 1e-4 Hertz units) through the stick phase that follows: 2.9e-5 of the speed in the
    spin of a Kharaz rebound that sticks until late in the contact (docs/physics.md). The
    tangential impulse and the spring's energy in the shell, ``O(floor^2.5)``, are left out.
    """
    eps = terms.contact_floor
    n = jnp.full_like(y["ndot"], eps)
    w = y["w"] if terms.rotation else jnp.zeros_like(n)
    slip = dyn.slip(terms, p, y, w)
    k_t = laws.mindlin_stiffness(n, p.radius, p.G_star, eps)
    cap = dyn.friction_limit(terms, p, n, y["ndot"], dyn.spins(terms, y)[1]) / k_t
    return jnp.clip(slip * shell["time"], -cap, cap)


class _Problem(eqx.Module):
    """One impact set up for integration (Hertz units): what the solve and its outputs need."""

    term: diffrax.ODETerm
    solver: diffrax.AbstractSolver
    controller: diffrax.AbstractStepSizeController
    event: diffrax.Event
    dt0: object
    y0: dict
    p: ScaledParameters
    u: object  # the Hertz units (``_units``)
    v_n: jax.Array
    v_t: jax.Array
    entry: dict
    entry_friction: dict | None
    w2_0: object = None  # the second sphere's initial spin (Hertz units)


def _problem(terms: dyn.Terms, cfg: Integration, params: dict, speed, angle_deg, omega0):
    """Set up one impact: initial state at the contact floor, event, solver, controller."""
    dtype = jnp.result_type(speed)
    p, u = _scaled(params, speed, angle_deg, omega0)
    theta = jnp.deg2rad(angle_deg)
    v_n, v_t = speed * jnp.cos(theta), speed * jnp.sin(theta)
    w2 = params["omega2"] * u.time if "omega2" in params else 0.0
    y0 = dyn.initial_state(terms, v_t / v_n, omega0 * u.time, dtype, w2)
    floor = terms.contact_floor
    if terms.jkr:  # smooth at first touch: the solve starts there
        entry = {"ndot": y0["ndot"], "time": jnp.zeros((), dtype), "peak": jnp.zeros((), dtype)}
        entry["loss_hertz_damping"] = entry["loss_adhesion_damping"] = entry["time"]
        y0["n"] = jnp.zeros((), dtype)
    else:
        entry = _shell_entry(terms, p, dtype)
        y0["n"] = jnp.asarray(floor, dtype)
        y0["ndot"] = entry["ndot"]
    if terms.mindlin:  # (JKR: the solve starts at first touch, the spring unloaded)
        y0["xi"] = jnp.zeros((), dtype) if terms.jkr else _shell_spring(terms, p, y0, entry)
    entry_friction = None
    if terms.tangential and not terms.mindlin and terms.jkr:
        entry_friction = {"loss_friction": jnp.zeros((), dtype)}
    elif terms.tangential and not terms.mindlin:
        entry_friction = _shell_friction(terms, p, y0, entry, entry["ndot"])
        for k in ("vt", "w", "w2"):
            if k in y0:
                y0[k] = entry_friction[k]
    # One scalar event (diffrax's root find over several events solves a least-squares problem
    # whose rounding depends on the batch): the overlap reaches the contact floor
    # (separation), or, with adhesion, the normal energy reaches zero (capture; scaled to
    # order one by ``capture_margin`` so that the root finder's tolerance is meaningful).
    if terms.jkr:
        # Below the elastic sticking speed the sphere cannot climb the snap-off barrier even
        # without losses: captured at first touch (the event fires at JKR_STUCK_TIME).
        def cond(t, y, args, **kw):
            free = jnp.minimum(
                y["n"] - dyn.separation(terms, args, y.get("peak")),
                dyn.capture_margin(terms, args, y),
            )
            return jnp.where(_jkr_stuck(terms, args), JKR_STUCK_TIME - t, free)

    elif terms.adhesion:
        cond = lambda t, y, args, **kw: jnp.minimum(  # noqa: E731
            y["n"] - floor, dyn.capture_margin(terms, args, y)
        )
    else:  # without adhesion the normal energy cannot fall below zero
        cond = lambda t, y, args, **kw: y["n"] - floor  # noqa: E731
    # Event times to ~1e-10 Hertz times in float64: tighter chases rounding noise in E (a
    # difference of large terms when adhesion dominates a slow impact) and the root find would
    # not converge. float32: 1000 ulp (1.2e-4), where 100 ulp left Newton failing on 20 of
    # 30,000 slow impacts near capture (and 1000 ulp on 147 of 1e6: hence the bisection).
    tol = max(1e-10, 1000 * float(jnp.finfo(dtype).eps))
    if jnp.finfo(dtype).bits >= 64:
        root_finder = optx.Newton(rtol=tol, atol=tol)
    else:
        # float32: at a grazing capture the event function crosses zero with almost no slope,
        # and Newton did not converge there (147 of 1e6 slow impacts failed, issue 12).
        # Bisection inside the last step always does. flip=True: every lane's function
        # decreases across the step (the events are down-crossings; diffrax gives lanes
        # without an event `tnext - t`), so no sign detection, which raises on those lanes.
        root_finder = optx.Bisection(rtol=tol, atol=tol, flip=True)
    event = diffrax.Event(cond, root_finder=root_finder, direction=False)
    controller, dt0 = make_controller(cfg.method, cfg.rtol, cfg.atol, cfg.dt, _error_norm)
    solver = make_solver(cfg.method, dtype, cfg.stages)
    return _Problem(
        diffrax.ODETerm(dyn.ImpactField(terms)),
        solver,
        controller,
        event,
        dt0,
        y0,
        p,
        u,
        v_n,
        v_t,
        entry,
        entry_friction,
        w2 if terms.target else None,
    )


def _solve_one(
    terms: dyn.Terms,
    cfg: Integration,
    params: dict,
    speed,
    angle_deg,
    omega0,
    adjoint=None,
    loop="diffrax",
):
    """Integrate one impact in Hertz units and return its ``ImpactResult`` fields (SI).

    ``loop="lean"``: the step loop of ``step_loop`` where it supports the solver (forward
    only: explicit adaptive solvers), else ``diffrax.diffeqsolve``.
    """
    prob = _problem(terms, cfg, params, speed, angle_deg, omega0)
    if loop in ("lean", "pool") and _lean_supported(prob):
        integrate = step_loop.diffeqsolve_lean
    else:
        integrate = diffrax.diffeqsolve
    options = {}
    if integrate is diffrax.diffeqsolve:
        # Reverse mode keeps every step rather than recomputing steps from checkpoints: the
        # recomputed steps came out different enough (a different step sequence after a
        # one-ulp difference) to put jax.grad 1e-3..1e-2 away from jax.jacfwd (measured).
        options = dict(
            throw=False,
            adjoint=(
                diffrax.RecursiveCheckpointAdjoint(checkpoints=cfg.max_steps)
                if adjoint is None
                else adjoint
            ),
        )
    sol = integrate(
        prob.term,
        prob.solver,
        t0=0.0,
        t1=T_MAX,
        dt0=prob.dt0,
        y0=prob.y0,
        args=prob.p,
        event=prob.event,
        stepsize_controller=prob.controller,
        max_steps=cfg.max_steps,
        **options,
    )
    return _outputs(terms, prob, speed, omega0, sol)


def _lean_supported(prob: _Problem) -> bool:
    return step_loop.supported(prob.solver, prob.controller, prob.event)


def _outputs(terms: dyn.Terms, prob: _Problem, speed, omega0, sol):
    """The ``ImpactResult`` fields (SI) of one solved impact: the exit shell, status, energies."""
    dtype = jnp.result_type(speed)
    y, t_end, status = _final_state(terms, prob, sol)
    failed = status >= Status.MAX_STEPS
    rebound = status == Status.REBOUND

    out, losses = _output_fields(terms, prob, omega0, y, t_end, rebound, dtype)
    nan = jnp.asarray(jnp.nan, dtype)
    if not terms.ledger:
        ledger = ("energy_in", "energy_out", "energy_tangential", *losses)
        out.update({k: nan for k in ledger if k in out})
    out = {k: jnp.where(failed, nan, v).astype(dtype) for k, v in out.items()}
    return ImpactResult(status=status.astype(jnp.int32), steps=sol.stats["num_steps"], **out)


def _jkr_spring_exit(terms: dyn.Terms, p: ScaledParameters, y: dict, exit_: dict, separated):
    """The Mindlin spring across JKR's exit stretch (:func:`_jkr_exit`), in place: its
    tangential impulse there, ``-k_t xi`` times the crossing time (left out, it was 3e-6 of the
    speed off the reference in the spin), and what the snap-off drops, booked in
    ``loss_friction`` so that the ledger closes exactly: the spring's energy left at ``n_c``
    less the tangential kinetic energy its impulse gave."""
    if not terms.tangential:
        return
    dv = jnp.where(separated, exit_["spring_impulse"], 0.0)
    w = y["w"] if terms.rotation else jnp.zeros_like(dv)
    gained = dv * dyn.slip(terms, p, y, w) + 0.5 * dv * dv / dyn.slip_mass(terms, p)
    y["vt"] = y["vt"] + dv
    if terms.rotation:
        y["w"] = w - dyn.moment_arm(p) * dv / p.inertia
        if terms.target:
            y["w2"] = y["w2"] - p.arm2 * dv / p.inertia2
    if "loss_friction" in y:
        lost = exit_["spring_lost"] - gained
        y["loss_friction"] = y["loss_friction"] + jnp.where(separated, lost, 0.0)


def _final_state(terms: dyn.Terms, prob: _Problem, sol):
    """The state at the end of the impact (the exit shell crossed in closed form after a
    rebound, the entry shell's contributions added), its time and its status code."""
    p, entry = prob.p, prob.entry
    entry_friction = prob.entry_friction
    y = jax.tree_util.tree_map(lambda x: x[-1], sol.ys)
    t_end = sol.ts[-1]

    finite = jnp.all(jnp.stack([jnp.isfinite(v) for v in jax.tree_util.tree_leaves(y)]))
    event_hit = sol.result == diffrax.RESULTS.event_occurred
    spring = dyn.tangential_energy(terms, p, y) if terms.mindlin else None
    peak = y.get("peak")
    exit_ = _shell_exit(terms, p, y["ndot"], spring, y["xi"] if terms.mindlin else None, peak)
    if terms.adhesion:
        # At the event one of the two is ~0 and the other positive. A sphere whose normal
        # energy runs out inside the shell below the floor is captured too.
        separation = dyn.separation(terms, p, peak)
        captured = event_hit & (
            (y["n"] - separation > dyn.capture_margin(terms, p, y)) | ~exit_["ok"]
        )
    else:
        captured = False
    separated = event_hit & ~captured
    if terms.mindlin and terms.jkr:
        _jkr_spring_exit(terms, p, y, exit_, separated)
    if terms.mindlin:  # the spring's energy went into the normal motion in the shell
        y["xi"] = jnp.where(separated, 0.0, y["xi"])
    if terms.tangential and not terms.mindlin:
        exit_.update(_shell_friction(terms, p, y, exit_, y["ndot"]))
        for k in ("vt", "w", "w2"):
            if k in y:
                y[k] = jnp.where(separated, exit_[k], y[k])
        if "loss_friction" in y:
            entry["loss_friction"] = entry_friction["loss_friction"]
            y["loss_friction"] = y["loss_friction"] + entry["loss_friction"]
            y["loss_friction"] = y["loss_friction"] + jnp.where(
                separated, exit_["loss_friction"], 0.0
            )
    # Out of contact: at the touch point of the curve it left (0; Thornton-Ning: its shift),
    # where the normal potential is zero.
    y["n"] = jnp.where(separated, dyn.jkr_curve(terms, p, peak)[1], y["n"])
    y["ndot"] = jnp.where(separated, exit_["ndot"], y["ndot"])
    shell_time = entry["time"] + jnp.where(separated, exit_["time"], 0.0)
    if terms.ledger:
        for k in ("loss_hertz_damping", "loss_adhesion_damping", "peak"):
            if k in y:
                y[k] = y[k] + entry[k] + jnp.where(separated, exit_[k], 0.0)
    if "slide_time" in y:
        # The latch covers the integrated part of the contact only (the shells are crossed in
        # closed form): a sphere that slid to the end of it never rolled; the onset of rolling
        # counts from the first touch, the entry shell included.
        # One that never slid (no slip from the first touch: a normal impact without spin)
        # rolled from the start: 0, in any batch (the entry shell's time made it 1e-11 s in
        # a batch whose other impacts need the tangential terms).
        slid_through = y["slide_time"] >= t_end * (1 - 1e-4) - 1e-6
        y["slide_time"] = jnp.where(
            slid_through,
            t_end + shell_time,
            jnp.where(y["slide_time"] > 0, y["slide_time"] + entry["time"], 0.0),
        )
    t_end = t_end + shell_time
    status = jnp.where(
        ~finite,
        Status.NONFINITE,
        jnp.where(
            event_hit,
            jnp.where(captured, Status.CAPTURED, Status.REBOUND),
            jnp.where(
                sol.result == diffrax.RESULTS.max_steps_reached,
                Status.MAX_STEPS,
                Status.SOLVER_ERROR,
            ),
        ),
    )
    return y, t_end, status


def _output_fields(terms: dyn.Terms, prob: _Problem, omega0, y, t_end, rebound, dtype):
    """The output fields in SI from the final state (before failed impacts are masked), and
    the energy losses among them."""
    p, u, v_n, v_t = prob.p, prob.u, prob.v_n, prob.v_t
    nan = jnp.asarray(jnp.nan, dtype)
    vt = y["vt"] if terms.tangential else jnp.zeros((), dtype)
    w = y["w"] if terms.rotation else jnp.zeros((), dtype)
    vn_out = jnp.where(rebound, -y["ndot"], 0.0) * u.speed
    vt_out = vt * u.speed
    omega_out = w / u.time
    if not terms.ledger:
        roll_time = nan
    elif terms.tangential:
        never_rolled = y["slide_time"] >= t_end * (1 - 1e-4) - 1e-6
        roll_time = jnp.where(never_rolled, nan, y["slide_time"] * u.time)
    else:
        roll_time = jnp.zeros((), dtype)  # no slip at any time
    safe_vt = jnp.where(v_t == 0, 1.0, v_t)
    e_unit = u.energy
    energy_in = 0.5 * (1.0 + (v_t / v_n) ** 2)
    if terms.rotation:  # a scene without rotation ignores the initial spin, and its energy
        energy_in = energy_in + 0.5 * p.inertia * (omega0 * u.time) ** 2
        if terms.target:
            energy_in = energy_in + 0.5 * p.inertia2 * prob.w2_0**2
    losses = {
        k: (y[k] * e_unit if k in y else jnp.zeros((), dtype))
        for k in ("loss_hertz_damping", "loss_adhesion_damping", "loss_friction", "loss_rolling")
    }
    if terms.plastic:  # Thornton-Ning's yield: a field of ImpactResult only
        plastic = laws.thornton_ning_plastic_loss(
            y["peak"], p.radius, p.K, p.w_adhesion, p.a_yield, p.p_yield
        )
        losses["loss_plastic"] = plastic * e_unit if terms.ledger else nan
    out = dict(
        vn_out=vn_out,
        vt_out=vt_out,
        omega_out=omega_out,
        cor_n=vn_out / v_n,
        cor_t=jnp.where(v_t == 0, nan, vt_out / safe_vt),
        # Inputs masked too: arctan2(0, 0) of a capture has a NaN gradient ("double where").
        rebound_angle_deg=jnp.where(
            rebound,
            jnp.rad2deg(
                jnp.arctan2(jnp.where(rebound, vt_out, 0.0), jnp.where(rebound, vn_out, 1.0))
            ),
            nan,
        ),
        contact_time=t_end * u.time,
        roll_time=roll_time,
        max_overlap=y["peak"] * u.length if terms.ledger else nan,
        energy_in=energy_in * e_unit,
        energy_out=dyn.mechanical_energy(terms, p, y) * e_unit,
        **losses,
    )
    if terms.mindlin:  # the part of energy_out held by the spring (0 after a rebound)
        out["energy_tangential"] = dyn.tangential_energy(terms, p, y) * e_unit
    if "w2" in y:  # the second sphere's spin
        out["omega2_out"] = y["w2"] / u.time
    return out, losses


# ``simulate(program=...)``: what the program is made for -> the form of Tsit5's stage sums.
PROGRAMS = {"throughput": "per_state", "compact": "loop"}

# Lanes per device that one chunk of a large batch integrates at a time, on a CPU, in float64
# (float32: twice as many, the same bytes); issue 12, measured in BENCHMARKS.md, "Throughput
# (issue 12)". A vmapped solve walks its whole state once per step, which a chunk keeps in a
# core's caches; XLA also splits the operations of a large batch over all cores, which a small
# chunk forgoes, so one device gets large chunks, and the smaller ones are for a batch sharded
# over one device per core (``use_all_cpu_cores``). Retuned for the per-state stage sums
# (fourth session; 20,000 impacts, medians of 3): 2 devices, chunk 2048 float64 12,729/s
# against 10,839 at 512 and 9,508 whole; float32 chunk 4096 92,710/s against 46,814 at 512
# and 73,795 whole; 1 device float64 8192 10,770/s against 9,255 at 4096. No chunks on GPUs,
# where a larger batch is better.
CHUNK = 2048
CHUNK_ONE_DEVICE = 8192
# With step loops compiled as single kernels (``use_all_cpu_cores(loop_kernels=True)``, as
# the CLI does) a device's chunk runs on one core from its caches. Unfused (the throughput
# program, ``compiler_options``), 128 lanes ran 31,500 float64 impacts/s on 2 cores against
# 30,500 at 256 and 33,900 at 64 (which compiled in 24 s against 9 s); fused, 64 lanes ran
# 23,600, 16 21,300 and 256 19,200 (measured with 256-bit vectors).
CHUNK_LOOP_KERNEL = 128


def default_loop(dtype) -> str:
    """The step loop of a batch of ``dtype`` whose steps per impact nobody knows in advance:
    ``"pool"`` (lanes refilled as impacts finish) in float32, ``"lean"`` (chunks of lanes,
    each waiting for its slowest) in float64. Measured (issue 12): in float32 the pool ran
    9-12x the chunked loop on slow impacts near capture, where a few grazing ones take 40x
    the median steps, and 0.95-1.01x on the oblique benchmark; in float64 0.86-0.93x on that
    benchmark (1.31x near capture). Where the steps per impact spread widely (a posterior's
    points drawn from the prior: chunks of 128 lanes ran 7.9x the steps their impacts
    needed), the pool pays in float64 too: ``loop="pool"`` (3.8x the points per second)."""
    return "pool" if jnp.finfo(dtype).bits < 64 else "lean"


# The pooled lean loop's tail: once no impact is left to start and at most 1/TAIL_FRACTION of
# the lanes still run, they go on in that many lanes (``step_loop.solve_pool``).
TAIL_FRACTION = 16


def _default_chunk(shards: int, dtype=None) -> int:
    if jax.default_backend() != "cpu":
        return 0
    if loop_kernels():
        per_float64 = CHUNK_LOOP_KERNEL
    else:
        per_float64 = CHUNK if shards > 1 else CHUNK_ONE_DEVICE
    return per_float64 * 8 // jnp.dtype(dtype or jnp.result_type(float)).itemsize


def _simulate_flat(terms, cfg, *args, **kwargs):
    """:func:`_solve_flat`, compiled and cached; inlined where the caller is being traced
    under ``jax.jit`` already. A nested jit would make JAX trace the batch three times more
    than needed under ``jax.jacfwd``: the primal of :func:`_differentiable`'s custom JVP, and
    the whole tangent program again to batch it over the tangent directions, which act on
    the rule's last sums only (measured on the fit's program: tracing 3.4 against 6.1 s)."""
    if under_trace():
        return _solve_flat(terms, cfg, *args, **kwargs)
    # XLA options only on a program of its own (JAX refuses them on a nested jit)
    alone = compiled_alone(args)
    options = compiler_options(throughput=cfg.stages == "per_state") if alone else {}
    cached = bool(jax.config.jax_compilation_cache_dir)
    if alone and cached:
        return _from_program_cache(terms, cfg, options, *args, **kwargs)
    key = tuple(sorted(options.items()))
    if key not in _SOLVE_FLAT_JIT:
        _SOLVE_FLAT_JIT[key] = eqx.filter_jit(_solve_flat, compiler_options=options or None)
    jitted = functools.partial(_SOLVE_FLAT_JIT[key], terms, cfg)
    if cached and kwargs.get("loop") != "diffrax" and _lean_method(cfg):
        return _eagerly_differentiated(terms, cfg, jitted, *args, **kwargs)
    return jitted(*args, **kwargs)


def _eagerly_differentiated(
    terms, cfg, jitted, params, speed, angle_deg, omega0, adjoint=None, **settings
):
    """The batch under a transformation outside ``jax.jit`` (a user's ``jax.grad`` or
    ``jax.jacfwd`` of ``simulate``), with the derivatives of :func:`_differentiable` from
    programs of the traced-program cache where the primal inputs are concrete (they are under
    ``grad``, ``jacfwd`` and ``jacrev`` called eagerly): a warm process then loads the value
    and tangent programs instead of tracing the tangent program again (about 3 s). The same
    functions as the ``jitted`` path, so the same values and derivatives; other
    transformations (``vmap``, higher derivatives) take the ``jitted`` path."""

    def plain(inputs):
        return jitted(*inputs, adjoint, **settings)

    def concrete(inputs):
        return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(inputs))

    @jax.custom_jvp
    def run(inputs):
        if concrete(inputs):
            options = compiler_options(throughput=cfg.stages == "per_state")
            return _from_program_cache(terms, cfg, options, *inputs, adjoint, **settings)
        return plain(inputs)

    @functools.partial(run.defjvp, symbolic_zeros=True)
    def run_jvp(primals, tangents):
        inputs, leaves, treedef, dleaves, moved = _rule_inputs(primals, tangents)
        if not concrete(inputs):
            dleaves = [
                jnp.zeros(x.shape, x.dtype) if isinstance(d, SymbolicZero) else d
                for x, d in zip(leaves, dleaves, strict=True)
            ]
            return jax.jvp(plain, (inputs,), (treedef.unflatten(dleaves),))
        if not moved:
            out = run(inputs)
            return out, jax.tree_util.tree_map(_zero_tangent, out)
        program = _tangent_program(terms, cfg, leaves, treedef, moved, settings)
        values, columns = program(*leaves)
        out = ImpactResult(**values)
        dxs = [dleaves[i] for i in moved]
        # (the last sums of ``_differentiable``'s rule, on the program's columns)
        columns = ImpactResult(**{f: columns.get(f, v) for f, v in values.items()})
        return out, _combine(out, columns, dxs)

    return run((params, speed, angle_deg, omega0))


def _tangent_program(terms, cfg, leaves, treedef, moved, settings):
    """The compiled program of :func:`_differentiable`'s tangent solve for concrete inputs
    (``leaves`` of ``treedef``, tangents along ``moved``): ``(values, columns)``, dicts by
    ``ImpactResult`` field (columns of the float fields only), through the traced-program
    cache (``jaximpact._io.cache.compiled_program``)."""
    from .._io.cache import compiled_program

    example = [jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding) for x in leaves]
    options = compiler_options()
    settings = dict(sorted(settings.items()))
    key = repr((terms, cfg, settings, sorted(options.items()), jax.local_devices(), treedef, moved))
    memo = ("tangents", key, repr(example))
    if memo not in _CACHED_PROGRAMS:
        compact = dataclasses.replace(cfg, stages=PROGRAMS["compact"])
        solve_with_tangents = functools.partial(
            _solve_batch,
            terms,
            compact,
            settings.get("chunk"),
            settings.get("shards", 1),
            settings.get("loop", "lean"),
            None,
        )

        def tangents(*xs):
            # as in ``_solve_flat``: XLA must not see that lanes repeat
            xs = [jax.lax.optimization_barrier(x) for x in xs]
            out, cols = _output_columns(solve_with_tangents, xs, treedef, moved)
            fields = tuple(ImpactResult.__dataclass_fields__)
            values = {f: getattr(out, f) for f in fields if getattr(out, f) is not None}
            floats = [f for f in values if jnp.issubdtype(values[f].dtype, jnp.inexact)]
            return values, {f: getattr(cols, f) for f in floats}

        _CACHED_PROGRAMS[memo], _ = compiled_program(
            "tangents", tangents, example, key, options or None
        )
        while len(_CACHED_PROGRAMS) > _CACHED_PROGRAMS_KEPT:
            _CACHED_PROGRAMS.popitem(last=False)
    _CACHED_PROGRAMS.move_to_end(memo)
    return _CACHED_PROGRAMS[memo]


def _solve_flat(
    terms, cfg, params, speed, angle_deg, omega0, adjoint=None, chunk=None, shards=1, loop="lean"
):
    """The batch of impacts (1-D inputs): :func:`_solve_batch`, differentiable.

    On the lean loop (``loop`` ``"lean"`` or ``"pool"``, explicit adaptive solvers), values and
    derivatives come from that loop (:func:`_differentiable`); ``loop="diffrax"`` (and every
    solver the lean loop does not handle) differentiates ``diffeqsolve`` with ``adjoint``.
    """
    inputs = (params, speed, angle_deg, omega0)
    # XLA must not see that lanes repeat (the padding copies, a scene parameter broadcast over
    # the batch): it would compute such values once, as scalars, and the rounding of scalar
    # and vector arithmetic differ (FMA contraction follows the fusion).
    # One barrier per leaf: under autodiff a joint barrier would give every input a tangent.
    inputs = jax.tree_util.tree_map(jax.lax.optimization_barrier, inputs)
    if loop == "diffrax" or not _lean_method(cfg):
        return _solve_batch(terms, cfg, chunk, shards, "diffrax", adjoint, inputs)
    solve = functools.partial(_solve_batch, terms, cfg, chunk, shards, loop, None)
    # Derivatives take Tsit5's stages in a loop (the compact program) whatever the program of
    # the values: the tangent program of the unrolled stages compiles 4x slower (measured:
    # 64 against 16 s for output_jacobian) and runs no faster on a fit's batch.
    compact = dataclasses.replace(cfg, stages=PROGRAMS["compact"])
    solve_with_tangents = functools.partial(_solve_batch, terms, compact, chunk, shards, loop, None)
    return _differentiable(solve, solve_with_tangents)(inputs)


# ``_solve_flat`` compiled with each set of XLA options (``compiler_options``), made on first use
_SOLVE_FLAT_JIT: dict = {}
# Concrete batches' programs of this process, by settings and input shapes and shardings (the
# most recently used few).
_CACHED_PROGRAMS: collections.OrderedDict = collections.OrderedDict()
_CACHED_PROGRAMS_KEPT = 32


def _from_program_cache(
    terms, cfg, options, params, speed, angle_deg, omega0, adjoint=None, **settings
):
    """:func:`_solve_flat` on concrete inputs through the traced-program cache
    (``jaximpact._io.cache.compiled_program``): a process whose compilation cache already
    holds this batch's program loads it instead of tracing and lowering it again (about 2 s of
    a warm process's first ``simulate``). The same program as the ``jit`` path (the same
    function traced at the same shapes), so the same bits; values only (a traced input never
    comes here)."""
    from .._io.cache import compiled_program

    inputs = (params, speed, angle_deg, omega0)
    example = jax.tree_util.tree_map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding), inputs
    )
    settings = dict(sorted(settings.items()))
    key = repr((terms, cfg, adjoint, settings, sorted(options.items()), jax.local_devices()))
    memo = (key, repr(example))
    if memo not in _CACHED_PROGRAMS:
        fields = tuple(ImpactResult.__dataclass_fields__)

        def solve(params, speed, angle_deg, omega0):
            r = _solve_flat(terms, cfg, params, speed, angle_deg, omega0, adjoint, **settings)
            return tuple(getattr(r, f) for f in fields)

        program, _ = compiled_program("simulate", solve, example, key, options or None)
        _CACHED_PROGRAMS[memo] = (program, fields)
        while len(_CACHED_PROGRAMS) > _CACHED_PROGRAMS_KEPT:
            _CACHED_PROGRAMS.popitem(last=False)
    _CACHED_PROGRAMS.move_to_end(memo)
    program, fields = _CACHED_PROGRAMS[memo]
    return ImpactResult(**dict(zip(fields, program(*inputs), strict=True)))


def _lean_method(cfg: Integration) -> bool:
    """Whether the lean step loop runs this method (explicit, adaptive, PID-controlled)."""
    return cfg.method in ("tsit5", "dopri5", "dopri8")


def _differentiable(solve, solve_with_tangents):
    """``solve`` (inputs -> ``ImpactResult``, each lane a function of its own inputs), with
    derivatives from forward mode through the same step loop: ``solve_with_tangents``, the
    same integration in the program form used for derivatives (it also gives the values that
    come with derivatives).

    The rule computes, for every input leaf that carries a tangent, the per-lane Jacobian
    column ``d out / d x`` (:func:`_output_columns`), then returns ``sum_j column_j *
    tangent_j``. That is linear in the tangents with coefficients that depend on the primal
    values only, so JAX can transpose it: ``jax.grad`` (reverse mode) works on the
    forward-only ``lax.while_loop`` at the cost of one tangent solve per perturbed input (a
    few per impact: a scene's parameters and the impact's inputs)."""

    @jax.custom_jvp
    def run(inputs):
        return solve(inputs)

    @functools.partial(run.defjvp, symbolic_zeros=True)
    def run_jvp(primals, tangents):
        inputs, leaves, treedef, dleaves, moved = _rule_inputs(primals, tangents)
        if not moved:
            out = solve(inputs)
            return out, jax.tree_util.tree_map(_zero_tangent, out)
        out, columns = _output_columns(solve_with_tangents, leaves, treedef, moved)
        return out, _combine(out, columns, [dleaves[i] for i in moved])

    return run


def _rule_inputs(primals, tangents):
    """A JVP rule's ``(inputs, leaves, treedef, tangent leaves, moved)``: ``moved``, the
    indices of the input leaves that carry a tangent (not a symbolic zero)."""
    (inputs,), (dinputs,) = primals, tangents
    leaves, treedef = jax.tree_util.tree_flatten(inputs)
    dleaves = treedef.flatten_up_to(dinputs)
    moved = [i for i, d in enumerate(dleaves) if not isinstance(d, SymbolicZero)]
    return inputs, leaves, treedef, dleaves, moved


def _output_columns(solve_with_tangents, leaves, treedef, moved):
    """``(out, columns)``: the outputs and, stacked on a leading axis, their per-lane
    derivatives along each input leaf in ``moved`` (``jax.jvp`` along a ones-vector: lanes are
    independent, so one tangent solve gives the column of every lane)."""

    def of_moved(xs):
        full = list(leaves)
        for i, x in zip(moved, xs, strict=True):
            full[i] = x
        return solve_with_tangents(treedef.unflatten(full))

    xs = [leaves[i] for i in moved]
    basis = [
        [jnp.full_like(x, 1.0 if i == j else 0.0) for j, x in enumerate(xs)] for i in range(len(xs))
    ]
    basis = jax.tree_util.tree_map(lambda *b: jnp.stack(b), *basis)
    return jax.vmap(lambda t: jax.jvp(of_moved, (xs,), (t,)), out_axes=(None, 0))(basis)


def _combine(out, columns, dxs):
    """The outputs' tangents ``sum_j column_j * dx_j`` (zero for integer outputs)."""

    def combine(y, col):
        if not jnp.issubdtype(y.dtype, jnp.inexact):
            return _zero_tangent(y)
        acc = col[0] * dxs[0]
        for j in range(1, len(dxs)):
            acc = acc + col[j] * dxs[j]
        return acc

    return jax.tree_util.tree_map(combine, out, columns)


def _zero_tangent(y):
    if jnp.issubdtype(y.dtype, jnp.inexact):
        return jnp.zeros_like(y)
    return np.zeros(y.shape, jax.dtypes.float0)


def _solve_batch(terms, cfg, chunk, shards, loop, adjoint, inputs):
    """The batch of impacts (1-D inputs), vmapped; with ``chunk``, in chunks one after another.

    ``chunk``: at most this many lanes per device in one vmapped solve. A larger batch becomes
    ``n`` equal chunks (the last padded with copies of a real lane) that ``lax.map`` solves one
    after another inside the compiled program. A lane's arithmetic does not depend on its chunk
    (every operation is elementwise over lanes, and a chunk holds at least 2 lanes), so outputs
    and step counts are bitwise those of the unchunked batch. ``shards``: the batch is split in
    that many contiguous parts, one per device (``_shard_over_devices``), each solved on its
    device as a batch of its own. ``loop``: see ``_solve_one``.
    """
    if shards > 1:
        # Each device solves its part on its own (``shard_map``): as one partitioned program
        # every step waited for an all-reduce of "any lane still running" over the devices
        # (measured on 2 CPU devices, 20,000 impacts: 22,400 against 19,400 impacts/s).
        per_device = functools.partial(_solve_batch, terms, cfg, chunk, 1, loop, adjoint)
        # (check_vma=False: the loops' carries start from constants that JAX's type check
        # would want cast to per-device values; nothing here crosses devices.)
        spec = jax.sharding.PartitionSpec("batch")
        return jax.shard_map(
            per_device, mesh=_batch_mesh(), in_specs=spec, out_specs=spec, check_vma=False
        )(inputs)
    params, speed, angle_deg, omega0 = inputs
    solve = lambda xs: jax.vmap(  # noqa: E731
        lambda prm, s, a, w: _solve_one(terms, cfg, prm, s, a, w, adjoint, loop)
    )(*xs)
    size = speed.shape[0]
    if not _lean_method(cfg) and size <= IMPLICIT_MAPPED_LANES:
        # A few impacts of an implicit method one after another: tracing diffrax's implicit
        # stages, root finds and event under vmap doubles the tracing (Kvaerno5, 3 impacts:
        # first call 12.4 s against 19.2 s), at about 5x the run time per impact.
        solve = lambda xs: jax.lax.map(  # noqa: E731
            lambda x: _solve_one(terms, cfg, *x, adjoint, loop), xs
        )
    # lanes per chunk: the chunks as equal as can be, whole lane groups (per_state)
    group = lane_group(speed.dtype, cfg.stages)
    n_chunks = -(-size // chunk) if chunk else 1
    width = min(-(-size // (n_chunks * group)) * group, size)
    first = jax.tree_util.tree_map(lambda x: x[0], inputs)
    if loop == "pool" and chunk and _lean_supported(_problem(terms, cfg, *first)):
        # lanes that take the next impact as theirs finish (``step_loop.solve_pool``; which
        # batches get it: ``default_loop``)
        tail = -(-width // (TAIL_FRACTION * group)) * group
        return _solve_pooled(terms, cfg, inputs, width, tail)
    if not chunk or size <= chunk:
        return solve(inputs)
    n_chunks = -(-size // width)
    pad = n_chunks * width - size

    def split(x):  # (size,) -> (n_chunks, width)
        return jnp.pad(x, (0, pad), mode="edge").reshape(n_chunks, width)

    out = jax.lax.map(solve, jax.tree_util.tree_map(split, inputs))
    return jax.tree_util.tree_map(lambda y: y.reshape(-1)[:size], out)


def _solve_pooled(terms, cfg, inputs, lanes, tail_lanes):
    """``_solve_one`` (lean loop) on a 1-D batch, with ``lanes`` lanes refilled from the batch
    (``step_loop.solve_pool``). Every impact starts through the pool's one refill code, so its
    bits do not depend on the batch, its place in it or the chunk size; they are not bitwise
    the vmapped lean loop's (in float32, 13 of 4,000 slow impacts took another step sequence
    after a last-bit difference in their first stage: another fusion of the same arithmetic)."""

    def initial(prm, s, a, w):
        prob = _problem(terms, cfg, prm, s, a, w)
        return prob.y0, prob.p

    def outputs(prm, s, a, w, sol):
        return _outputs(terms, _problem(terms, cfg, prm, s, a, w), s, w, sol)

    y0s, args = jax.vmap(initial)(*inputs)
    prob = _problem(terms, cfg, *jax.tree_util.tree_map(lambda x: x[0], inputs))
    sols = step_loop.solve_pool(
        prob.term,
        prob.solver,
        0.0,
        T_MAX,
        prob.dt0,
        y0s,
        args,
        event=prob.event,
        stepsize_controller=prob.controller,
        max_steps=cfg.max_steps,
        lanes=lanes,
        tail_lanes=tail_lanes,
    )
    return jax.vmap(outputs)(*inputs, sols)


def simulate(
    scene: Scene,
    speed=None,
    angle_deg=None,
    omega0=None,
    *,
    method: str | None = None,
    adjoint: diffrax.AbstractAdjoint | None = None,
    program: str = "throughput",
) -> ImpactResult:
    """Simulate impacts of the scene's sphere on its surface.

    **Arguments:**
    - `scene`: a `Scene` (see `load_scene`, `table1_scene`). Any float parameter may be an array
      broadcastable against the impacts: one value per impact.
    - `speed`: impact speed (m/s, > 0); default ``scene.impact.speed``.
    - `angle_deg`: incidence from the surface normal (degrees, in (-90, 90)); default the
      scene's. Positive: the tangential velocity is along the positive spin's rolling sense.
    - `omega0`: initial spin (rad/s), signed so that ``v_t == r*omega`` is rolling.
    - `method`: override ``scene.solver.method``.
    - `adjoint`: how ``diffrax`` differentiates the solve; default
      ``RecursiveCheckpointAdjoint()`` (reverse mode, ``jax.grad``). Pass
      ``diffrax.ForwardMode()`` for forward mode (``jax.jacfwd``, ``jax.jvp``).
    - `program`: what the compiled program is made for (Tsit5, the default method; other
      methods ignore it): ``"throughput"`` (default: the fastest to run) or ``"compact"``
      (one-off work that compiling dominates, such as a fit or a few impacts: half the
      compile time, about 2x the run time). Each is batch-independent; they agree with each
      other to the solver's tolerance, not bit for bit (BENCHMARKS.md, "Throughput").

    Scalars or arrays (broadcast together; batched internally with ``vmap``).

    **Returns:** an `ImpactResult` with the broadcast shape; check ``status`` (a failed impact
    has NaN outputs, never silently wrong ones).

    **Raises:** `SceneError` (a `ValueError`) for invalid concrete inputs, naming the field.

    Works under ``jax.jit``, ``jax.vmap`` and ``jax.grad``; changing values does not recompile.
    """
    return _simulate(
        scene, speed, angle_deg, omega0, method=method, adjoint=adjoint, program=program
    )


def _simulate(
    scene,
    speed=None,
    angle_deg=None,
    omega0=None,
    *,
    method=None,
    adjoint=None,
    chunk=None,
    loop=None,
    program="throughput",
):
    """``simulate`` with the batch path's private settings: ``chunk``, lanes per device in one
    vmapped solve (default ``_default_chunk``; 0: the whole batch in one); ``loop``: the step
    loop, ``"lean"`` (``step_loop``, chunked), ``"pool"`` (the lean loop with lanes refilled
    as impacts finish) or ``"diffrax"`` (``diffeqsolve``, differentiated with ``adjoint``);
    default (None): :func:`default_loop`. Values and derivatives come
    from the chosen loop (``_simulate_flat``). The lean loop gives diffeqsolve's bits; the pool
    runs 9-12x faster on slow float32 impacts near capture, not bit for bit
    (tests/test_throughput_paths.py).

    Traced inputs cannot raise: a lane with an input outside its range (``_ranges.RANGES``)
    is solved with the scene's nominal inputs in its place and reported with status
    ``invalid_input`` and NaN outputs."""
    speed = scene.impact.speed if speed is None else speed
    angle_deg = scene.impact.angle_deg if angle_deg is None else angle_deg
    omega0 = scene.impact.omega0 if omega0 is None else omega0
    dtype = jnp.result_type(float)
    speed, angle_deg, omega0 = (jnp.asarray(x, dtype) for x in (speed, angle_deg, omega0))
    check_impact(speed, angle_deg, omega0)
    params = {k: jnp.asarray(v, dtype) for k, v in scene_parameters(scene).items()}
    shape = jnp.broadcast_shapes(
        speed.shape, angle_deg.shape, omega0.shape, *(v.shape for v in params.values())
    )
    size = int(np.prod(shape))
    flat = lambda x: jnp.broadcast_to(x, shape).reshape(size)  # noqa: E731
    params = {k: flat(v) for k, v in params.items()}
    speed, angle_deg, omega0 = flat(speed), flat(angle_deg), flat(omega0)
    valid = None
    if not all(map(_is_concrete, (speed, angle_deg, omega0, *params.values()))):
        (params, speed, angle_deg, omega0), valid = _replace_invalid(
            (params, speed, angle_deg, omega0)
        )

    terms = required_terms(scene, params, angle_deg, omega0)
    cfg = integration_settings(scene, params, speed, angle_deg, dtype, method)
    if program not in PROGRAMS:
        raise SceneError(f"program must be one of {', '.join(PROGRAMS)}, got {program!r}")
    cfg = dataclasses.replace(cfg, stages=PROGRAMS[program])
    inputs = (params, speed, angle_deg, omega0)
    # A batch of one is simplified differently by XLA (measured: the last bit of the Hertz
    # damping force), which an adaptive solve can amplify: at least 2 lanes; and in the
    # per_state form every lane on the vectorized path: a multiple of `lane_group` lanes per
    # device (and per chunk, in `_simulate_flat`), padded with copies of the last impact.
    group = max(2, lane_group(dtype, cfg.stages))
    if valid is None and _lean_method(cfg) and size <= SHARED_PROGRAM_LANES[-1]:
        group = max(group, next(n for n in SHARED_PROGRAM_LANES if n >= size))
    loop = default_loop(dtype) if loop is None else loop
    inputs, shards = _shard_over_devices(inputs, size, group)
    chunk = _default_chunk(shards, dtype) if chunk is None else chunk
    result = _simulate_flat(terms, cfg, *inputs, adjoint, chunk=chunk, shards=shards, loop=loop)
    if shards > 1:  # (concrete inputs only) sharded results cut and reshaped on one device
        result = gathered(result)
    result = jax.tree_util.tree_map(lambda x: x[:size], result)
    if valid is not None:
        result = _mark_invalid(result, valid)
    return jax.tree_util.tree_map(lambda x: x.reshape(shape), result)


# Batches of an implicit method (Kvaerno5) of at most this many impacts are solved one impact
# after another (``lax.map``) instead of vmapped: a few impacts' first call compiles in about
# 2/3 of the time (BENCHMARKS.md, "First result"), for about 80 ms per impact instead of 15
# (Table 1, 0.3-3 m/s). Implicit solves are not batch-exact either way (docs/open_points.md).
IMPLICIT_MAPPED_LANES = 16

# A small concrete batch of an explicit method is padded (copies of its last impact) to the
# first of these lane counts that holds it, so that batches of 3, 10 and 50 impacts of a scene
# run one compiled program instead of three: compiling takes seconds, 64 lanes of a Table 1
# impact a few milliseconds more. (In the test suite the Table 1 scene's program was compiled
# for 8, 16, 24, 32, 80 and 152 lanes: 66 s of 243 s of `simulate` compilations.) Lanes do not
# depend on their batch, so the values are the same bits.
SHARED_PROGRAM_LANES = (64, 128, 256)

# Inputs that stand in for an invalid traced lane: a plain, quick Table 1 impact.
_NOMINAL = {
    "speed": 1.0,
    "angle_deg": 0.0,
    "omega0": 0.0,
    "radius": 21.7e-6,
    "density": 2500.0,
    "K": 5.3e10,
    "f0": 300.0,
    "C_A": 0.75,
    "C_H": 0.25,
    "friction": 0.3,
    "lambda": 0.0,
    "G_star": 2e10,
    "w": 0.1,
    "p_y": 1e9,
    "radius2": 21.7e-6,
    "density2": 2500.0,
    "omega2": 0.0,
}


def _replace_invalid(inputs):
    """``(inputs, valid)``: each lane valid where every input is in its range
    (``_ranges.RANGES``); an invalid lane's inputs replaced by :data:`_NOMINAL`."""
    from .._model.ranges import RANGES

    params, speed, angle_deg, omega0 = inputs
    named = {**params, "speed": speed, "angle_deg": angle_deg, "omega0": omega0}
    valid = jnp.ones(speed.shape, bool)
    for name, x in named.items():
        rng = RANGES[name]
        above = x >= rng.lo if rng.lo_closed else x > rng.lo
        below = x <= rng.hi if rng.hi_closed else x < rng.hi
        valid = valid & jnp.isfinite(x) & above & below
    pick = lambda name, x: jnp.where(valid, x, jnp.asarray(_NOMINAL[name], x.dtype))  # noqa: E731
    params = {k: pick(k, v) for k, v in params.items()}
    return (
        params,
        pick("speed", speed),
        pick("angle_deg", angle_deg),
        pick("omega0", omega0),
    ), valid


def _mark_invalid(result: ImpactResult, valid) -> ImpactResult:
    """Status ``invalid_input`` and NaN outputs (0 steps) on the invalid lanes."""

    def mark(x):
        if jnp.issubdtype(x.dtype, jnp.floating):
            return jnp.where(valid, x, jnp.nan)
        return x

    marked = jax.tree_util.tree_map(mark, result)
    return dataclasses.replace(
        marked,
        status=jnp.where(valid, result.status, Status.INVALID_INPUT).astype(result.status.dtype),
        steps=jnp.where(valid, result.steps, 0).astype(result.steps.dtype),
    )


def _shard_over_devices(inputs, size, group=1):
    """Pad a batch with copies of its last impact to a multiple of ``group`` lanes per device
    and, if it is concrete and large enough, split it over all local devices (GPUs, or host
    devices on a CPU with ``XLA_FLAGS=--xla_force_host_platform_device_count=N``), sharded
    along the batch. Returns the inputs and the number of devices they are split over."""
    devices = jax.local_devices()
    leaves = jax.tree_util.tree_leaves(inputs)
    if len(devices) == 1 or size < 2 * len(devices) or not all(map(_is_concrete, leaves)):
        pad = -size % group
        return jax.tree_util.tree_map(lambda x: jnp.pad(x, (0, pad), mode="edge"), inputs), 1
    pad = -size % (len(devices) * group)
    sharding = jax.sharding.NamedSharding(_batch_mesh(), jax.sharding.PartitionSpec("batch"))
    inputs = jax.tree_util.tree_map(
        lambda x: jax.device_put(jnp.pad(x, (0, pad), mode="edge"), sharding), inputs
    )
    return inputs, len(devices)


def _batch_mesh():
    """The local devices as a 1-D mesh over the batch axis."""
    return jax.sharding.Mesh(np.array(jax.local_devices()), ("batch",))


def integration_settings(scene, params, speed, angle_deg, dtype, method=None) -> Integration:
    """The solver ``simulate`` runs for these impacts: method (``auto`` resolved), tolerances.

    ``params`` as :func:`scene_parameters` gives them (arrays or scalars), ``speed`` and
    ``angle_deg`` the impacts, ``dtype`` the float type; ``method`` overrides the scene's.
    """
    s = scene.solver
    method = method or s.method
    rtol, atol = default_tolerances(dtype, s.rtol, s.atol)
    if method == "auto":
        method = "tsit5"
        # A slip width below the solver's noise (~rtol) lets the slip wander into the steep part
        # of the friction switch, which an explicit solver crosses only with tiny steps.
        if default_slip_width(dtype, s.slip_width, rtol) < 30 * rtol:
            method = "kvaerno5"
        elif _all(list(params.values()) + [speed, angle_deg], lambda v: True):
            if float(_stiffness_estimate_jit(params, speed, angle_deg)) > s.stiffness_limit:
                method = "kvaerno5"
    if method not in ("tsit5", "dopri5", "dopri8", "rk4", "kvaerno3", "kvaerno5"):
        raise SceneError(f"solver.method {method!r} is not a known method")
    return Integration(method=method, rtol=rtol, atol=atol, dt=s.dt, max_steps=s.max_steps)
