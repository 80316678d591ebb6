"""The equations of motion, assembled from only the terms a scene needs.

``Terms`` is the static description of what is compiled: a normal-only impact has the states
``n, ndot`` (plus its ledger) and never evaluates friction or moments; a scene without adhesion
never evaluates the ring. Everything here works in Hertz units (mass 1, see ``_units.py``).

State (a dict of scalars), by what the terms need:
- always: ``n``, ``ndot``, ``peak`` (integral of max(ndot, 0): the peak overlap, since the
  sphere approaches only once before it separates or is declared captured) and
  ``loss_hertz_damping``;
- the adhesion ring (Brach-Dunn normal law with adhesion): ``loss_adhesion_damping``;
- tangential: ``vt``, ``loss_friction`` and ``slide_time`` (the time until rolling first starts);
- rotation: ``w``; rolling moments: ``loss_rolling``;
- the Mindlin tangential spring (``Terms.mindlin``): ``xi``, its elastic displacement;
- Thornton-Ning (``Terms.plastic``): ``peak`` is part of the motion (the law's memory of
  yield; the energy yield took is a closed form of it, ``laws.thornton_ning_plastic_loss``).

With ``Terms.ledger = False`` (``[solver] outputs = "rebound"``) only the motion ``n, ndot, vt,
w`` is integrated: 1.22-1.33x the impacts/s of the full outputs with loop kernels
(``use_all_cpu_cores()``), but 0.8x on one CPU device with XLA's default settings, whose
fusion of the smaller step recomputes more (25,200 against 23,000 compiled operations);
20,000 oblique spinning impacts, 2026-11-25.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp

from . import laws
from .units import ScaledParameters


class Terms(eqx.Module):
    """Static switches: which states and force terms are compiled."""

    tangential: bool = eqx.field(static=True)
    rotation: bool = eqx.field(static=True)
    adhesion: bool = eqx.field(static=True)
    rolling_moments: str = eqx.field(static=True)  # "none" | "analytical" | "lambda"
    friction_load: str = eqx.field(static=True)  # "net" | "hertz"
    slip_width: float = eqx.field(static=True)
    ring_width: float = eqx.field(static=True)
    ledger: bool = eqx.field(static=True, default=True)  # losses, peak overlap, roll time
    # Numerical settings of the smooth model (Hertz units; see docs/physics.md, "Derivatives"):
    # the overlap below which the contact is treated analytically, and the rate of the linear
    # pull toward rolling inside the slip width.
    contact_floor: float = eqx.field(static=True, default=0.0)
    slip_relaxation: float = eqx.field(static=True, default=0.0)
    # model.tangential = "mindlin": the elastic tangential spring (state xi) replaces the rigid
    # friction law; cap_width is its regularization width at the Coulomb cap (fraction of it).
    mindlin: bool = eqx.field(static=True, default=False)
    cap_width: float = eqx.field(static=True, default=0.0)
    # model.normal: "brach_dunn" (the adhesion ring), "dmt" (constant adhesion 2 pi w r),
    # "jkr" (the JKR force of the contact radius; contact until the snap-off overlap n_c < 0)
    # or "thornton_ning" (JKR that yields at the limiting pressure p_y, then unloads along a
    # flatter JKR curve: see laws.thornton_ning_curve).
    normal: str = eqx.field(static=True, default="brach_dunn")
    # A second sphere instead of the wall: its spin w2 is a state (with rotation).
    target: bool = eqx.field(static=True, default=False)
    # model.damping: "hertzian" (Brach-Dunn's C_H) or one of LAMMPS's normal damping models
    # (laws.LAMMPS_DAMPING), whose coefficient is ScaledParameters.eta_n.
    damping: str = eqx.field(static=True, default="hertzian")
    # model.jkr_release: where a JKR contact ends: "snap_off" (displacement control, the least
    # overlap of the stable branch) or "pull_off" (load control, the force's minimum: LAMMPS).
    jkr_release: str = eqx.field(static=True, default="snap_off")
    # With the spring (``mindlin``): "mindlin" (jaximpact's: 8 G* a, its normal force
    # -dU/dn, the Coulomb load of friction_load) or LAMMPS's history springs
    # "lammps_linear_history" (k_t) and "lammps_mindlin" (8 G* a): no normal force, the
    # Coulomb load LAMMPS's critical normal force (lammps_critical_load).
    spring: str = eqx.field(static=True, default="mindlin")

    @property
    def lammps_spring(self):
        """A LAMMPS history spring (``model.tangential = "lammps_..."``)."""
        return self.mindlin and self.spring.startswith("lammps_")

    @property
    def lammps_damping(self):
        """A LAMMPS normal damping model replaces the Hertzian damping (``C_H`` is 0)."""
        return self.damping in laws.LAMMPS_DAMPING

    @property
    def has_moments(self):
        return self.rotation and self.rolling_moments != "none"

    @property
    def ring(self):
        """The Brach-Dunn adhesion ring, with its damping and peeling moment, is compiled."""
        return self.adhesion and self.normal == "brach_dunn"

    @property
    def jkr(self):
        """The JKR law (with ``w = 0`` it is Hertz's, and Hertz's terms are compiled), also
        as Thornton-Ning's elastic branches."""
        return self.adhesion and self.normal in ("jkr", "thornton_ning")

    @property
    def plastic(self):
        """Thornton-Ning: the JKR curve the contact follows depends on its peak overlap."""
        return self.adhesion and self.normal == "thornton_ning"

    @property
    def adhesion_loss(self):
        """The ledger's ``loss_adhesion_damping``: the ring's damping, or JKR's snap-off loss."""
        return self.ring or self.jkr


def initial_state(terms: Terms, vt0, w0, dtype, w2=0.0):
    zero = jnp.zeros((), dtype)
    y = {"n": zero, "ndot": jnp.ones((), dtype), "peak": zero, "loss_hertz_damping": zero}
    if terms.adhesion_loss:
        y["loss_adhesion_damping"] = zero
    if terms.tangential:
        y.update(vt=jnp.asarray(vt0, dtype), loss_friction=zero, slide_time=zero)
        if terms.mindlin:
            y["xi"] = zero
        if terms.rotation:
            y["w"] = jnp.asarray(w0, dtype)
            if terms.target:
                y["w2"] = jnp.asarray(w2, dtype)
            if terms.has_moments:
                y["loss_rolling"] = zero
    if not terms.ledger:
        motion = MOTION + (("peak",) if terms.plastic else ())
        y = {k: v for k, v in y.items() if k in motion}
    return y


MOTION = ("n", "ndot", "vt", "w", "w2", "xi")


def spins(terms: Terms, y):
    """``(w, w_roll)``: the particle's spin, and the spin the rolling moments and the ring
    see, relative to the wall or the second sphere (``w - w2``)."""
    n = y["n"]
    if not (terms.tangential and terms.rotation):
        zero = jnp.zeros_like(n)
        return zero, zero
    w = y["w"]
    return w, (w - y["w2"] if terms.target else w)


def moment_arm(p: ScaledParameters):
    """The particle's moment arm (its radius; given apart from the contact's radius only with
    a second sphere)."""
    return p.radius if p.arm is None else p.arm


def slip(terms: Terms, p: ScaledParameters, y, w):
    """The slip of the contact points, ``vt - r w`` (``- r2 w2`` with a second sphere)."""
    s = y["vt"] - moment_arm(p) * w
    if terms.target and terms.rotation:
        s = s - p.arm2 * y["w2"]
    return s


def slip_mass(terms: Terms, p: ScaledParameters):
    """``m_eff`` of ``s' = F_t / m_eff`` (the tangential force's effect on the slip)."""
    if not terms.rotation:
        return 1.0
    if terms.target:
        return 1.0 / (1.0 + p.arm**2 / p.inertia + p.arm2**2 / p.inertia2)
    return p.inertia / (p.inertia + moment_arm(p) ** 2)


def spin_rates(terms: Terms, p: ScaledParameters, F_t, M):
    """``(w', w2')``: the friction's moment ``-r F_t`` and the rolling moment ``M`` turn the
    particle; a second sphere gets ``-r2 F_t - M``."""
    wdot = (-moment_arm(p) * F_t + M) / p.inertia
    if not terms.target:
        return wdot, None
    return wdot, (-p.arm2 * F_t - M) / p.inertia2


def adhesion_potential(terms: Terms, p: ScaledParameters, n):
    """The potential energy of the normal law's adhesion force (``<= 0`` in contact; not for
    JKR, whose potential is one expression: :func:`normal_potential`)."""
    if terms.normal == "dmt":
        return laws.dmt_potential(n, p.radius, p.w_adhesion)
    return laws.adhesion_potential(n, p.radius, p.f0)


def jkr_curve(terms: Terms, p: ScaledParameters, peak=None):
    """``(r, s)``: the radius and overlap shift of the JKR curve the contact follows, the
    particle's own ``(r, 0)``, or with Thornton-Ning the curve of the peak overlap so far
    (``laws.thornton_ning_curve``; ``peak=None``: the elastic curve of first touch)."""
    if not terms.plastic or peak is None:
        return p.radius, 0.0
    return laws.thornton_ning_curve(peak, p.radius, p.K, p.w_adhesion, p.a_yield, p.p_yield)


def jkr_contact_radius(terms: Terms, p: ScaledParameters, n, peak=None):
    """The JKR contact radius (continued below the separation level, see ``separation``)."""
    E = 0.75 * p.K
    r, s = jkr_curve(terms, p, peak)
    return laws.jkr_contact_radius(n - s, r, E, p.w_adhesion, terms.contact_floor)


def jkr_snap_off(terms: Terms, p: ScaledParameters, peak=None):
    """``(n_c, a_c)``: the overlap (< 0 without plastic shift) and contact radius where a JKR
    contact ends: the snap-off, or the pull-off with ``model.jkr_release = "pull_off"``."""
    r, s = jkr_curve(terms, p, peak)
    lam, mu = laws.jkr_scales(r, 0.75 * p.K, p.w_adhesion)
    if terms.jkr_release == "pull_off":  # the force's minimum (load control)
        return s + laws.JKR_PULL_OFF * mu, lam * laws.JKR_PULL_OFF_RADIUS
    return s + laws.JKR_SNAP_OFF * mu, lam * math.pi ** (1.0 / 3.0) / 2.0


def jkr_barrier(terms: Terms, p: ScaledParameters, peak=None):
    """``V(n_c)``: the JKR potential at the snap-off, the energy a sphere in contact must have
    to leave and the elastic impact's loss (of the curve it follows)."""
    r, _ = jkr_curve(terms, p, peak)
    _, a_c = jkr_snap_off(terms, p, peak)
    return laws.jkr_potential(a_c, r, p.K, p.w_adhesion)


def separation(terms: Terms, p: ScaledParameters, peak=None):
    """The overlap at which the integration stops for a separation: the contact floor, or
    with JKR the floor above the snap-off, ``s + mu (d_c + floor)``; a closed form crosses the
    rest (``simulate._shell_exit``)."""
    if terms.jkr:
        r, s = jkr_curve(terms, p, peak)
        _, mu = laws.jkr_scales(r, 0.75 * p.K, p.w_adhesion)
        release = laws.JKR_PULL_OFF if terms.jkr_release == "pull_off" else laws.JKR_SNAP_OFF
        return s + mu * (release + terms.contact_floor)
    return terms.contact_floor


def normal_potential(terms: Terms, p: ScaledParameters, n, peak=None):
    """``V(n)``, the potential of the elastic and adhesive normal forces (0 at first touch;
    with Thornton-Ning, of the curve the peak overlap selects: 0 where it starts)."""
    if terms.jkr:
        a = jkr_contact_radius(terms, p, n, peak)
        return laws.jkr_potential(a, jkr_curve(terms, p, peak)[0], p.K, p.w_adhesion)
    v = laws.hertz_potential(n, p.radius, p.K)
    if terms.adhesion:
        v = v + adhesion_potential(terms, p, n)
    return v


def normal_energy(terms: Terms, p: ScaledParameters, y):
    """``ndot^2/2 + V(n)``: it never increases without spin, and ``< 0`` means capture
    (JKR: below the snap-off barrier ``V(n_c) > 0``)."""
    return 0.5 * y["ndot"] ** 2 + normal_potential(terms, p, y["n"], y.get("peak"))


def balanced_normal_energy(terms: Terms, p: ScaledParameters, y):
    """The normal energy from the energy balance, ``1/2`` less the Hertzian damping's loss
    (the entry shell's, ``C_H V_H(floor)``, and the solve's ledger), where that is the only
    force on the normal motion that is not conservative: the DMT law (its adhesion is not
    damped) with the rigid tangential law and some adhesion. ``None`` elsewhere (``w = 0`` is
    the Hertz law, computed as the Brach-Dunn law without adhesion is), or without the ledger.

    Far below the adhesion speed the well is deep in Hertz units (``~(v_ad/v)^2``) and
    ``ndot^2/2 + V(n)`` is a difference of terms that large: its error, ~5e-11 of the well
    depth at rtol 1e-10, made an undamped DMT rebound's ``cor_n`` 2.7e-3 off at 1e-4 v_ad and
    a capture at 1e-5 v_ad. The balance's error is that of the loss, relative to the loss.
    """
    if terms.normal != "dmt" or not terms.adhesion or terms.mindlin:
        return None  # without adhesion (w = 0) no deep well: the state's energy, as Hertz's
    if "loss_hertz_damping" not in y:
        return None
    work = laws.hertz_potential(terms.contact_floor, p.radius, p.K)
    work = work + adhesion_potential(terms, p, terms.contact_floor)
    _, shell = entry_shell_damping(terms, p, -work)
    return 0.5 - shell - y["loss_hertz_damping"]


def shell_damping_integral(terms: Terms, p: ScaledParameters, n=None):
    """``int_0^n eta_n dn`` of a LAMMPS damping (default ``n``: the contact floor): its work
    across the contact shell at unit speed."""
    n = terms.contact_floor if n is None else n
    return laws.lammps_damping_integral(terms.damping, n, p.radius, p.eta_n, p.K)


def entry_shell_damping(terms: Terms, p: ScaledParameters, work):
    """``(ndot, loss)``: the normal speed at the contact floor after the approach through the
    shell ``0 <= n <= floor`` (speed 1 at first touch, ``work`` the conservative forces' work
    there) and the damping's loss in the shell. The Hertzian damping's is ``C_H V_H(floor)``
    (at speed ~1); a LAMMPS damping's, ``D (1 + ndot) / 2`` with ``D`` its integral over the
    shell (:func:`shell_damping_integral`, the mean of the two speeds: the speed changes across
    the shell by ``O(D)``, which is ~1e-4 for a strongly damped contact), solved exactly
    together with the energy balance ``ndot^2 = 1 + 2 work - D (1 + ndot)``."""
    if not terms.lammps_damping:
        loss = p.C_H * laws.hertz_potential(terms.contact_floor, p.radius, p.K)
        return jnp.sqrt(1.0 + 2.0 * (work - loss)), loss
    D = shell_damping_integral(terms, p)
    ndot = damped_exit_speed(D, 1.0 + 2.0 * work - D)
    return ndot, 0.5 * D * (1.0 + ndot)


def damped_exit_speed(D, c):
    """The root ``v >= 0`` of ``v^2 + D v = c`` (``c >= 0``): the speed after a stretch whose
    damping work is ``D`` times the mean of the speeds before and after."""
    c = jnp.maximum(c, 0.0)
    return 2.0 * c / (D + jnp.sqrt(D * D + 4.0 * c))


def capture_margin(terms: Terms, p: ScaledParameters, y):
    """The normal energy divided by the sum of its terms' sizes: capture when it is ``< 0``.

    Same sign as :func:`normal_energy`, so the same event, but of order one: when adhesion
    dominates a slow impact the energy is a difference of terms much larger than one in Hertz
    units, and in float32 its rounding noise exceeded the root finder's tolerance, so the
    capture time was never found (``solver_error`` on 19 of 20,000 float32 impacts at
    0.02-0.3 m/s; issue 12). Relative to the terms' sizes the noise is a few ulp.
    """
    kinetic = 0.5 * y["ndot"] ** 2
    if terms.jkr:  # the barrier V(n_c) a leaving sphere must still climb
        barrier = jkr_barrier(terms, p, y.get("peak"))
        v = normal_potential(terms, p, y["n"], y.get("peak"))
        return (kinetic + v - barrier) / (kinetic + jnp.abs(v) + barrier)
    balance = balanced_normal_energy(terms, p, y)
    if balance is not None:  # the impact's energy, 1/2, is the scale
        return balance / (0.5 + jnp.abs(balance))
    hertz = laws.hertz_potential(y["n"], p.radius, p.K)
    adhesion = adhesion_potential(terms, p, y["n"])  # <= 0
    return (kinetic + hertz + adhesion) / (kinetic + hertz - adhesion)


def mechanical_energy(terms: Terms, p: ScaledParameters, y):
    """Normal energy plus tangential and rotational kinetic energy (and the Mindlin spring's)."""
    e = normal_energy(terms, p, y)
    if terms.tangential:
        e = e + 0.5 * y["vt"] ** 2
        if terms.rotation:
            e = e + 0.5 * p.inertia * y["w"] ** 2
            if terms.target:
                e = e + 0.5 * p.inertia2 * y["w2"] ** 2
        if terms.mindlin:
            e = e + tangential_energy(terms, p, y)
    return e


def tangential_energy(terms: Terms, p: ScaledParameters, y):
    """Energy of the Mindlin spring, ``k_t(n) xi^2 / 2``: the potential of both its forces."""
    k_t, _ = spring_stiffness(terms, p, y["n"])
    return 0.5 * k_t * y["xi"] ** 2


def spring_stiffness(terms: Terms, p: ScaledParameters, n):
    """``(k_t, dk_t/dn)`` of the Mindlin spring, ``k_t = 8 G* a`` with the normal law's contact
    radius: Hertz's ``sqrt(r n)`` (also DMT's), or JKR's, whose slope is that of the law as
    integrated (the continuation below the separation level included), so that the spring's
    normal force is exactly minus the gradient of its energy. JKR's ``da/dn`` grows like
    ``(n - n_c)^-1/2`` toward the snap-off: the force is singular there but its work, the
    change of ``k_t xi^2 / 2``, is finite (docs/physics.md, "Tangential compliance")."""
    if terms.spring == "lammps_linear_history":  # constant
        return p.k_t + jnp.zeros_like(n), jnp.zeros_like(n)
    if terms.jkr:
        return jax.jvp(
            lambda n_: 8.0 * p.G_star * jkr_contact_radius(terms, p, n_), (n,), (jnp.ones_like(n),)
        )
    floor = terms.contact_floor
    k_t = laws.mindlin_stiffness(n, p.radius, p.G_star, floor)
    return k_t, laws.mindlin_stiffness_slope(n, p.radius, p.G_star, floor)


def _normal_loads(terms: Terms, p: ScaledParameters, n, ndot, w, peak=None):
    """The normal forces (and the ring's peeling moment ``M_A``, or None); ``peak`` selects
    Thornton-Ning's curve."""
    f = {}
    f["F_H"] = laws.hertz_force(n, p.radius, p.K)
    if terms.lammps_damping:  # LAMMPS's normal damping -eta_n(a) ndot (C_H is 0)
        a = laws.contact_radius(n, p.radius, terms.contact_floor)
        f["F_HD"] = -laws.lammps_damping_coefficient(terms.damping, a, p.eta_n, p.K) * ndot
    else:
        f["F_HD"] = laws.hertz_damping_force(n, ndot, p.radius, p.K, p.C_H)
    F_n = f["F_H"] + f["F_HD"]
    M_A = None
    if terms.jkr:  # the Hertzian part (damped as Hertz's force) and the adhesive part
        a = jkr_contact_radius(terms, p, n, peak)
        f["a"] = a
        f["r_curve"] = jkr_curve(terms, p, peak)[0]
        f["F_H"] = laws.jkr_hertz_force(a, f["r_curve"], p.K)
        f["F_HD"] = f["F_H"] * p.C_H * ndot
        if terms.lammps_damping:
            f["F_HD"] = -laws.lammps_damping_coefficient(terms.damping, a, p.eta_n, p.K) * ndot
        f["F_A"] = laws.jkr_adhesion_force(a, p.K, p.w_adhesion)
        F_n = f["F_H"] + f["F_HD"] + f["F_A"]
        M_A = jnp.zeros_like(n)
    elif terms.adhesion and terms.normal == "dmt":  # no ring: no damping, no peeling moment
        f["F_A"] = laws.dmt_adhesion_force(n, p.radius, p.w_adhesion)
        F_n = F_n + f["F_A"]
        M_A = jnp.zeros_like(n)
    elif terms.adhesion:
        # The spin enters the ring only with the analytical moments, where the ring also
        # yields M_A; otherwise the spin-free ring keeps the adhesion damping dissipative.
        ring_spin = w if terms.rolling_moments == "analytical" else None
        f["F_A"] = laws.adhesion_force(n, p.radius, p.f0, terms.contact_floor)
        f["F_AD"], M_A = laws.adhesion_damping(
            n, ndot, ring_spin, p.radius, p.f0, p.C_A, terms.ring_width, terms.contact_floor
        )
        F_n = F_n + f["F_A"] + f["F_AD"]
    f["F_n"] = F_n
    return f, M_A


def _friction_load(terms: Terms, f):
    return jnp.abs(f["F_n"]) if terms.friction_load == "net" else -f["F_H"]


def lammps_critical_load(terms: Terms, p: ScaledParameters, f):
    """LAMMPS's critical normal force ``Fncrit`` (fix wall/gran, pair granular; 29 Sep 2021):
    ``|F_ne + 2 F_pulloff|`` for JKR (the elastic and adhesive force without the damping,
    ``F_pulloff = 1.5 pi w r``), ``|F_ne|`` for DMT (the source reads ``|F_ne + 2 F_pulloff|``
    there too, but its cohesion is set only in JKR's branch: the build computes ``|F_ne|``,
    measured by quadrature of sliding impacts, docs/dem.md), else ``|F_ne + F_damp|``."""
    if terms.normal == "dmt":
        return jnp.abs(-f["F_H"] - f.get("F_A", 0.0))
    if terms.normal == "jkr":
        return jnp.abs(-f["F_H"] - f.get("F_A", 0.0) + 3.0 * math.pi * p.w_adhesion * p.radius)
    return jnp.abs(f["F_n"])


def friction_limit(terms: Terms, p: ScaledParameters, n, ndot, w):
    """The Coulomb limit ``f N`` of the tangential force at this normal state (the Mindlin
    spring's cap: without the spring's own normal force)."""
    f = _normal_loads(terms, p, n, ndot, w)[0]
    if terms.lammps_spring:
        return p.friction * lammps_critical_load(terms, p, f)
    return p.friction * _friction_load(terms, f)


def contact_loads(terms: Terms, p: ScaledParameters, y):
    """Every force and moment on the sphere at state ``y`` (a dict; absent terms are left out)."""
    n, ndot = y["n"], y["ndot"]
    spin, w = spins(terms, y)  # w: relative to the wall or the second sphere
    f, M_A = _normal_loads(terms, p, n, ndot, w, y.get("peak"))
    if not terms.tangential:
        return f
    M = jnp.zeros_like(n)
    if terms.has_moments:
        if terms.rolling_moments == "analytical" and terms.jkr:
            f["M_H"] = laws.jkr_rolling_moment(f["a"], w, f["r_curve"], p.K, p.C_H)
            f["M_A"] = M_A
            M = f["M_H"]
        elif terms.rolling_moments == "analytical":
            f["M_H"] = laws.hertz_rolling_moment(n, w, p.radius, p.K, p.C_H)
            f["M_A"] = M_A if terms.adhesion else jnp.zeros_like(n)
            M = f["M_A"] + f["M_H"]
        elif terms.jkr:
            M = -p.lam * p.C_A * f["a"] * w
        else:
            M = laws.lambda_moment(n, w, p.radius, p.C_A, p.lam, terms.contact_floor)
        f["M_roll"] = M
    if terms.mindlin:
        return _mindlin_loads(terms, p, y, f, spin, w, M)
    if terms.friction_load == "net":
        load = jnp.abs(f["F_n"])
    else:
        load = -f["F_H"]
    # The pull toward rolling acts on the slip through the effective mass of s' = F_t / m_eff,
    # so that the slip relaxes at the same rate with or without rotation.
    m_eff = slip_mass(terms, p)
    # Friction that keeps s = 0 in pure rolling: from s' = F_t (1/m + r^2/(m k^2)) - r M/(m k^2)
    # (with a second sphere s' = F_t / m_eff - M (r / k^2 - r2 / k2^2), per unit mass).
    if not terms.has_moments:
        hold = jnp.zeros_like(n)
    elif terms.target:
        hold = M * (p.arm / p.inertia - p.arm2 / p.inertia2) * m_eff
    else:
        hold = moment_arm(p) * M / (p.inertia + moment_arm(p) ** 2)
    f["slip"] = slip(terms, p, y, spin)
    f["F_t"] = laws.friction_force(
        f["slip"], load, p.friction, hold, terms.slip_width, terms.slip_relaxation * m_eff
    )
    return f


def _mindlin_loads(terms: Terms, p: ScaledParameters, y, f, spin, w, M):
    """The Mindlin spring: tangential force ``-k_t xi``, its normal force and the slip rate.

    The spring has the potential ``U = k_t(n) xi^2 / 2``, so besides the tangential force it
    pushes the sphere out with ``-dU/dn = -k_t'(n) xi^2 / 2`` (at most ~0.2 f^2 of the normal
    force); with it the spring's energy is returned to the motion by separation and the
    ledger closes with the slip loss alone. The Coulomb cap ``f N`` takes the load without that
    force (as the reference does). See docs/physics.md, "Tangential compliance".
    """
    n, ndot, xi = y["n"], y["ndot"], y["xi"]
    k_t, dk_dn = spring_stiffness(terms, p, n)
    if terms.lammps_spring:  # no normal force: the stiffness's change does work on the spring
        f["stiffening"] = -0.5 * dk_dn * ndot * xi * xi  # booked in loss_friction
    else:
        f["F_U"] = -0.5 * dk_dn * xi * xi
        f["F_n"] = f["F_n"] + f["F_U"]
    F_t = -k_t * xi
    wdot = jnp.zeros_like(n)  # the rate of the spin the ring sees
    if terms.rotation:
        wdot, w2dot = spin_rates(terms, p, F_t, M)
        if terms.target:
            wdot = wdot - w2dot

    def limit_of(n_, ndot_, w_):
        return friction_limit(terms, p, n_, ndot_, w_)

    limit, limit_rate = jax.jvp(limit_of, (n, ndot, w), (ndot, f["F_n"], wdot))
    # c = f N / k_t and its rate (k_t > 0 above -floor; outside, the cap is irrelevant).
    ok = k_t > 0
    safe_k = jnp.where(ok, k_t, 1.0)
    cap_rate = jnp.where(ok, (limit_rate - limit * dk_dn * ndot / safe_k) / safe_k, 0.0)
    f["slip"] = slip(terms, p, y, spin)
    f["F_t"] = F_t
    f["k_t"] = k_t
    # A constant stiffness's cap f N / k_t vanishes like n^1.5 at the contact's ends: its
    # switch keeps a width of at least 1e-3 f (Hertz units: the peak normal force is ~1)
    floor = 1e-3 * p.friction if terms.spring == "lammps_linear_history" else None
    f["slip_rate"] = laws.mindlin_slip_rate(
        xi, f["slip"], limit, k_t, cap_rate, terms.cap_width, terms.slip_width, floor
    )
    return f


class ImpactField(eqx.Module):
    """The ODE vector field ``dy/dt`` of one impact, for ``diffrax.ODETerm``."""

    terms: Terms

    def __call__(self, t, y, p: ScaledParameters):
        terms = self.terms
        f = contact_loads(terms, p, y)
        ndot = y["ndot"]
        dy = {
            "n": ndot,
            "ndot": f["F_n"],
            "peak": jnp.maximum(ndot, 0.0),
            "loss_hertz_damping": -f["F_HD"] * ndot,
        }
        if terms.ring:
            dy["loss_adhesion_damping"] = -f["F_AD"] * ndot
        elif terms.adhesion_loss:  # JKR: its snap-off loss is added at the separation
            dy["loss_adhesion_damping"] = jnp.zeros_like(ndot)
        if terms.tangential:
            dy["vt"] = f["F_t"]
            if terms.mindlin:
                dy["xi"] = f["slip"] - f["slip_rate"]
                dy["loss_friction"] = f["k_t"] * y["xi"] * f["slip_rate"]
                if terms.lammps_spring:
                    dy["loss_friction"] = dy["loss_friction"] + f["stiffening"]
            else:
                dy["loss_friction"] = -f["F_t"] * f["slip"]
            # Latch: slide_time follows t until the slip first falls below the width, then
            # stays. (Excluded from error control: its derivative jumps once, at that moment.)
            still_sliding = (jnp.abs(f["slip"]) > terms.slip_width) & (
                y.get("slide_time", t) >= t * (1 - 1e-4) - 1e-6
            )
            dy["slide_time"] = jnp.where(still_sliding, 1.0, 0.0).astype(ndot.dtype)
            if terms.rotation:
                M = f.get("M_roll", jnp.zeros_like(ndot))
                dy["w"], w2dot = spin_rates(terms, p, f["F_t"], M)
                if terms.target:
                    dy["w2"] = w2dot
                if terms.has_moments:
                    dy["loss_rolling"] = -M * spins(terms, y)[1]
        return {k: dy[k] for k in y}  # the states this impact carries (see Terms.ledger)
