"""The contact shells in closed form: the approach through the shell ``0 <= n <= floor``
below the contact floor and the separation through it (or, with the JKR law, the stretch down
to the snap-off), with their friction impulse and the Mindlin spring's share; the solve runs
between the two."""

import jax.numpy as jnp

from .._model import dynamics as dyn
from .._model import laws
from .._model.units import ScaledParameters


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
    if terms.lammps_damping:  # the damping's loss and the speed solved together
        work = -hertz
        if terms.adhesion:
            work = work + _shell_adhesion(terms, p)[0]
        ndot, loss = dyn.entry_shell_damping(terms, p, jnp.asarray(work, dtype))
    else:
        work = -hertz * (1.0 + p.C_H)
        if terms.adhesion:
            work = work + _shell_adhesion(terms, p)[0]
        ndot, loss = jnp.sqrt(jnp.asarray(1.0 + 2.0 * work, dtype)), hertz * p.C_H
    shell = {"ndot": ndot, "time": 2.0 * eps / (1.0 + ndot), "peak": eps}
    shell["loss_hertz_damping"] = loss
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
        if terms.lammps_spring:  # no normal force: the spring's energy is lost at the release
            k_sep, k_c = _spring_constant(terms, p, a_sep), _spring_constant(terms, p, a_c)
            spring_lost = half_xi2 * k_sep
            k_mean = 0.5 * (k_sep + k_c)
        else:
            energy = energy + 2.0 * half_xi2 * 8.0 * p.G_star * (a_sep - a_c)
            spring_lost = half_xi2 * 8.0 * p.G_star * a_c
            k_mean = 4.0 * p.G_star * (a_sep + a_c)
    if terms.lammps_damping:  # eta_n at the mean of the two ends, at the mean speed
        eta = 0.5 * (
            laws.lammps_damping_coefficient(terms.damping, a_sep, p.eta_n, p.K)
            + laws.lammps_damping_coefficient(terms.damping, a_c, p.eta_n, p.K)
        )
        D = eta * width
        energy = energy - D * speed
        ok = energy > 0
        out_speed = dyn.damped_exit_speed(D, jnp.where(ok, energy, 1.0))
        damping = 0.5 * D * (speed + out_speed)
    else:
        ok = energy > 0
        out_speed = jnp.sqrt(jnp.where(ok, energy, 1.0))
    shell = {"loss_hertz_damping": damping, "loss_adhesion_damping": barrier}
    shell["peak"] = jnp.zeros_like(ndot)
    shell["ok"] = ok
    shell["ndot"] = -out_speed
    shell["time"] = 2.0 * width / (speed + out_speed)
    # |integral of the friction load over n| across the stretch (for its tangential impulse)
    adhesive = 0.5 * (
        laws.jkr_adhesion_force(a_sep, p.K, p.w_adhesion)
        + laws.jkr_adhesion_force(a_c, p.K, p.w_adhesion)
    )
    net = adhesive - hertz * (1.0 + p.C_H * ndot)
    if terms.lammps_damping:
        net = net - eta * ndot
    net = jnp.abs(net) * width
    shell["load_work"] = net if terms.friction_load == "net" else hertz * width
    shell["width"] = width
    if spring_lost is not None:  # with the spring's tangential impulse across the stretch
        shell["spring_lost"] = spring_lost
        shell["spring_impulse"] = -k_mean * xi * shell["time"]
    return shell


def _spring_constant(terms: dyn.Terms, p: ScaledParameters, a):
    """The spring's stiffness at contact radius ``a``: ``8 G* a``, or LAMMPS's ``k_t``."""
    if terms.spring == "lammps_linear_history":
        return p.k_t + 0.0 * a
    return 8.0 * p.G_star * a


def _shell_exit(
    terms: dyn.Terms, p: ScaledParameters, ndot, spring=None, xi=None, peak=None, balance=None
) -> dict:
    """The separation through the shell below the floor, in closed form (see ``_shell_entry``).

    ``ndot`` (< 0) is the normal velocity at the floor; returns the velocity at ``n = 0`` and
    ``ok = False`` where the normal energy runs out inside the shell (then a capture).
    ``spring``: the Mindlin spring's energy at the floor, which its normal force returns to the
    normal motion in the shell (its tangential impulse there, ``O(floor^2.5)``, is left out);
    ``xi``: the spring's displacement, for JKR's stretch (:func:`_jkr_exit`); ``peak``:
    Thornton-Ning's peak overlap; ``balance``: the normal energy at the floor from the energy
    balance (``dyn.balanced_normal_energy``), which then gives the speed there and the exit
    energy (``balance`` less the shell's losses), instead of ``ndot``.
    """
    if terms.jkr:
        return _jkr_exit(terms, p, ndot, xi, peak)
    eps = terms.contact_floor
    if balance is not None:
        kinetic = balance - dyn.normal_potential(terms, p, jnp.full_like(ndot, eps))
        ndot = -jnp.sqrt(jnp.maximum(2.0 * kinetic, 0.0))
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
    if balance is not None:  # the same sum, without the well's terms that cancel in it
        lost = shell["loss_hertz_damping"] + shell["loss_adhesion_damping"]
        energy = 2.0 * (balance - lost) + (0.0 if spring is None else 2.0 * spring)
    if terms.lammps_damping:  # its loss D (in + out) / 2, solved with the balance
        D = dyn.shell_damping_integral(terms, p)
        energy = energy - D * speed
        shell["ok"] = energy > 0
        out_speed = dyn.damped_exit_speed(D, jnp.where(shell["ok"], energy, 1.0))
        shell["loss_hertz_damping"] = shell["loss_hertz_damping"] + 0.5 * D * (speed + out_speed)
    else:
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
        if terms.lammps_damping:  # -int eta_n ndot dn across the shell
            load = load - dyn.shell_damping_integral(terms, p) * ndot
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
    k_t = dyn.spring_stiffness(terms, p, n)[0]
    cap = dyn.friction_limit(terms, p, n, y["ndot"], dyn.spins(terms, y)[1]) / k_t
    return jnp.clip(slip * shell["time"], -cap, cap)


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
