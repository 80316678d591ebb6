"""One impact: set up in Hertz units (:class:`_Problem`: initial state at the contact floor,
event, solver, controller), integrated (``_solve_one``, the only caller of
``diffrax.diffeqsolve``), and turned into its ``ImpactResult`` fields (SI)."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._model import dynamics as dyn
from .._model import laws
from .._model.units import ScaledParameters
from . import step_loop
from .results import ImpactResult, Status
from .settings import Integration, _scaled
from .shells import (
    JKR_STUCK_TIME,
    _jkr_spring_exit,
    _jkr_stuck,
    _shell_entry,
    _shell_exit,
    _shell_friction,
    _shell_spring,
)
from .solvers import IMPLICIT, make_controller, make_solver

T_MAX = 1e5  # in Hertz times; the step limit, not this, bounds a slow impact


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
    p, u = _scaled(params, speed, angle_deg, omega0, terms.damping)
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
    cond = _event_condition(terms, floor)
    # Event times to ~1e-10 Hertz times in float64: tighter chases rounding noise in E (a
    # difference of large terms when adhesion dominates a slow impact) and the root find would
    # not converge. float32: 1000 ulp (1.2e-4), where 100 ulp left Newton failing on 20 of
    # 30,000 slow impacts near capture (and 1000 ulp on 147 of 1e6: hence the bisection).
    tol = max(1e-10, 1000 * float(jnp.finfo(dtype).eps))
    if jnp.finfo(dtype).bits >= 64 and cfg.method not in IMPLICIT:
        root_finder = optx.Newton(rtol=tol, atol=tol)
    else:
        # float32: at a grazing capture the event function crosses zero with almost no slope,
        # and Newton did not converge there (147 of 1e6 slow impacts failed, issue 12).
        # The implicit solvers in float64 too: Newton on Kvaerno5's dense output ran out of
        # iterations on 8 of 41 random scenes' impacts within 1e-9 of their capture speed
        # (status solver_error; capture_speed reported them failed). Bisection inside the
        # last step always converges. flip=True: every lane's function
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


def _event_condition(terms: dyn.Terms, floor):
    """The event function ``(t, y, args) -> scalar``, decreasing through zero at the end."""
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
        # The step loops see an event where the function goes from > 0 to <= 0 across a step;
        # the overlap starts at the floor (0), so a capture inside the first step (an adhesion
        # far stronger than the impact: DMT with w = 1e3 J/m^2, r = 1e-8 m at 1e-4 m/s) went
        # unseen and the solve ran to max_steps. At t = 0 the separation term is 1 instead.
        cond = lambda t, y, args, **kw: jnp.minimum(  # noqa: E731
            jnp.where(t > 0, y["n"] - floor, 1.0), dyn.capture_margin(terms, args, y)
        )
    else:  # without adhesion the normal energy cannot fall below zero
        cond = lambda t, y, args, **kw: y["n"] - floor  # noqa: E731
    return cond


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


def _spring_exit(terms: dyn.Terms, p, y: dict, exit_: dict, separated, spring):
    """The spring at the end of the contact, in place: unloaded once separated (jaximpact's
    returned its energy ``spring`` to the normal motion in the exit shell; LAMMPS's drops its
    history, and that energy is booked in ``loss_friction``), JKR's exit stretch's share."""
    if terms.jkr:
        _jkr_spring_exit(terms, p, y, exit_, separated)
    elif terms.lammps_spring and "loss_friction" in y:
        y["loss_friction"] = y["loss_friction"] + jnp.where(separated, spring, 0.0)
    y["xi"] = jnp.where(separated, 0.0, y["xi"])


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
    balance = dyn.balanced_normal_energy(terms, p, y)
    xi = y["xi"] if terms.mindlin else None
    # jaximpact's spring returns its energy to the normal motion in the shell; LAMMPS's loses it
    returned = None if terms.lammps_spring else spring
    exit_ = _shell_exit(terms, p, y["ndot"], returned, xi, peak, balance)
    if terms.adhesion:
        # At the event one of the two is ~0 and the other positive. A sphere whose normal
        # energy runs out inside the shell below the floor is captured too.
        separation = dyn.separation(terms, p, peak)
        captured = event_hit & (
            (y["n"] - separation > dyn.capture_margin(terms, p, y)) | ~exit_["ok"]
        )
    elif terms.lammps_damping:  # it can take the normal energy in the shell: no exit
        captured = event_hit & ~exit_["ok"]
    else:
        captured = False
    separated = event_hit & ~captured
    if terms.mindlin:
        _spring_exit(terms, p, y, exit_, separated, spring)
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
