"""Force and moment laws of the Brach–Dunn–Cheng model, one function per law.

The laws are written in physical form and hold in any consistent unit system: the simulator
evaluates them in Hertz units (see ``_units.py``), the tests in SI. Signs follow
CONVENTIONS: ``n`` is the overlap (> 0 in contact), ``ndot > 0`` approaching, normal forces are
positive toward the surface, the spin ``w`` is signed so that ``tdot == r*w`` is rolling, and
the slip is ``s = tdot - r*w``. Every law is zero for ``n <= 0`` (free flight).
"""

import math

import jax.numpy as jnp

from .safe import safe_pow, safe_sqrt, smooth_sign_flat, smooth_step_flat


def contact_radius(n, radius, n_min=0.0):
    """Hertz contact radius ``a = sqrt(r n)`` (0 out of contact).

    ``n_min > 0`` continues ``a`` below ``n_min`` along its tangent there (down to 0 at
    ``n = -n_min``): the simulator integrates only ``n >= n_min`` and treats the thin shell
    below analytically, but Runge-Kutta stages of the last step overshoot into it, where the
    infinite slope of ``sqrt`` at 0 would wreck the derivatives of the step (see docs/physics.md).
    """
    if n_min <= 0.0:
        return safe_sqrt(radius * n)
    root = jnp.sqrt(n_min)
    tangent = jnp.maximum((n + n_min) / (2.0 * root), 0.0)
    return jnp.sqrt(radius) * jnp.where(n > n_min, jnp.sqrt(jnp.maximum(n, n_min)), tangent)


def hertz_force(n, radius, K):
    """Hertz restoring force ``F_H = -K sqrt(r) n^1.5`` (eq. 2; negative = repulsive)."""
    return -K * jnp.sqrt(radius) * safe_pow(n, 1.5)


def hertz_damping_force(n, ndot, radius, K, C_H):
    """Hertzian damping ``F_HD = -K sqrt(r) n^1.5 C_H ndot`` (eq. 2); power ``F_HD ndot <= 0``."""
    return hertz_force(n, radius, K) * C_H * ndot


#: LAMMPS's normal damping models (``pair_style granular`` / ``fix wall/gran granular``,
#: keyword ``damping``; version 29 Sep 2021), ``model.damping`` in a scene: the force is
#: ``-eta_n ndot`` with ``eta_n`` = ``eta`` (velocity), ``eta m`` (mass_velocity), ``eta a m``
#: (viscoelastic) or ``alpha(e) sqrt(m K a)`` (tsuji), ``a`` the contact radius, ``m`` the
#: (reduced) mass and ``K a`` LAMMPS's ``knfac`` (``4/3 E* a``). "hertzian" is Brach-Dunn's
#: ``C_H`` (:func:`hertz_damping_force`).
LAMMPS_DAMPING = ("velocity", "mass_velocity", "viscoelastic", "tsuji")

# LAMMPS's fit of Tsuji, Tanaka & Ishida (1992): alpha as a polynomial of the restitution
# coefficient e (coefficients of e^0 .. e^6, as LAMMPS's fix wall/gran and pair granular apply).
_TSUJI = (1.2728, -4.2783, 11.087, -22.348, 27.467, -18.022, 4.8218)


def tsuji_alpha(e):
    """``alpha(e)`` of LAMMPS's ``damping tsuji``, whose coefficient is a restitution
    coefficient ``e`` (for a Hertz contact the restitution is then about ``e`` whatever the
    speed: the damping scales as the stiffness)."""
    out = 0.0
    for c in reversed(_TSUJI):
        out = out * e + c
    return out


def lammps_damping_coefficient(damping, a, eta, K, mass=1.0):
    """``eta_n`` of LAMMPS's normal damping force ``-eta_n ndot`` at contact radius ``a``
    (``damping`` one of :data:`LAMMPS_DAMPING`; for "tsuji" ``eta`` is ``alpha(e)``)."""
    if damping == "velocity":
        return eta + 0.0 * a
    if damping == "mass_velocity":
        return eta * mass + 0.0 * a
    if damping == "viscoelastic":
        return eta * a * mass
    if damping == "tsuji":
        return eta * safe_sqrt(mass * K * a)
    raise ValueError(f"unknown damping model {damping!r}")


def lammps_damping_integral(damping, n, radius, eta, K, mass=1.0):
    """``int_0^n eta_n dn'`` along the Hertz contact radius ``sqrt(r n')``: the work of the
    damping over the overlap ``n`` at unit speed (the contact shells in closed form)."""
    if damping in ("velocity", "mass_velocity"):
        return lammps_damping_coefficient(damping, 0.0, eta, K, mass) * n
    if damping == "viscoelastic":
        return eta * mass * jnp.sqrt(radius) * (2.0 / 3.0) * safe_pow(n, 1.5)
    if damping == "tsuji":
        return eta * jnp.sqrt(mass * K) * radius**0.25 * 0.8 * safe_pow(n, 1.25)
    raise ValueError(f"unknown damping model {damping!r}")


def adhesion_force(n, radius, f0, n_min=0.0):
    """Ring adhesion ``F_A = 2 pi a f0`` (eq. 2), attractive. (``n_min``: see contact_radius.)"""
    return 2.0 * jnp.pi * contact_radius(n, radius, n_min) * f0


def dmt_adhesion_force(n, radius, w):
    """DMT adhesion ``F = 2 pi w r`` (Derjaguin, Muller & Toporov 1975), attractive, constant
    while in contact; ``w`` is the work of adhesion. Returned for every ``n`` (the simulator
    integrates only the contact, and a constant continues smoothly into the stages that
    overshoot below its floor)."""
    return jnp.broadcast_to(2.0 * jnp.pi * w * radius, jnp.shape(n)).astype(jnp.result_type(n))


def dmt_potential(n, radius, w):
    """Potential energy of the DMT adhesion in contact, ``-2 pi w r n`` (continued linearly
    below ``n = 0``, as the force is)."""
    return -2.0 * jnp.pi * w * radius * n


def hertz_potential(n, radius, K):
    """Potential energy of the Hertz force, ``(2/5) K sqrt(r) n^2.5``."""
    return 0.4 * K * jnp.sqrt(radius) * safe_pow(n, 2.5)


def adhesion_potential(n, radius, f0):
    """Potential energy of the ring adhesion force, ``-(4/3) pi f0 sqrt(r) n^1.5``."""
    return -(4.0 / 3.0) * jnp.pi * f0 * jnp.sqrt(radius) * safe_pow(n, 1.5)


def ring_integrals(ndot, b, width=0.0):
    """Separating part of the adhesion ring, integrated around the contact edge.

    The ring point at angle ``alpha`` moves normally at ``u = ndot + b cos(alpha)`` with
    ``b = w a``. Returns ``(I0, I1)`` with ``I0 = int max(-u, 0) dalpha`` and
    ``I1 = int max(-u, 0) cos(alpha) dalpha`` over ``[0, 2 pi)`` (closed form; derivation in
    docs/physics.md). ``I1 <= 0`` for ``b > 0``: the peeling moment opposes the spin.

    ``width > 0`` regularizes the switch at ``|ndot| = |b|`` (which becomes a plain kink at
    ``ndot = 0`` when ``b = 0``): ``b`` is replaced by ``b_eff = sqrt(b^2 + width^2)`` and
    ``ndot`` by ``ndot + width^2 / b_eff``. That shift keeps the regularized ring dissipative
    (power ``ndot*F + w*M <= 0`` exactly) and vanishes for ``|b| >> width``.

    ``b = None``: a ring without spin (``b = 0``), with the terms of ``b`` left out (``b_eff``
    is the width; ``I1 = 0``): the ring of every model without the analytical rolling moments,
    evaluated six times a solver step.
    """
    if b is None:
        if width == 0.0:
            return 2.0 * jnp.pi * jnp.maximum(-ndot, 0.0), jnp.zeros_like(ndot)
        u0 = ndot + width
        c = jnp.clip(-u0 / width, -1.0, 1.0)
        s = safe_sqrt(1.0 - c * c)
        i0 = -2.0 * u0 * (jnp.pi - jnp.arctan2(s, c)) + 2.0 * width * s
        return i0, jnp.zeros_like(ndot)
    b_eff = safe_sqrt(b * b + width * width)
    safe_b_eff = jnp.where(b_eff > 0, b_eff, 1.0)
    u0 = ndot + jnp.where(b_eff > 0, width * width / safe_b_eff, 0.0)
    # c = cos(beta), where beta is the angle at which the ring point has u = 0; clipping c to
    # [-1, 1] makes the one formula cover the "all approaching" (c = -1) and "all separating"
    # (c = 1) regimes too.
    c = jnp.clip(-u0 / safe_b_eff, -1.0, 1.0)
    c = jnp.where(b_eff > 0, c, jnp.where(u0 < 0, 1.0, -1.0))
    s = safe_sqrt(1.0 - c * c)
    beta = jnp.arctan2(s, c)
    i0 = -2.0 * u0 * (jnp.pi - beta) + 2.0 * b_eff * s
    i1 = -b * (c * s + jnp.pi - beta)
    return i0, i1


def adhesion_damping(n, ndot, w, radius, f0, C_A, width=0.0, n_min=0.0):
    """Adhesion damping of the separating ring: normal force ``F_AD`` and peeling moment ``M_A``.

    Line force ``f0 C_A (-u)`` (attractive) where the ring point separates (``u < 0``). Limits:
    ``w = 0`` gives ``2 pi a f0 C_A max(-ndot, 0)``; a wholly separating ring gives
    ``M_A = -pi f0 C_A a^3 w`` (eq. 12). This replaces the printed ``2 pi a f0 C_A ndot``,
    which adds energy (CONVENTIONS erratum). Pass ``w = None`` for the spin-free ring.
    """
    a = contact_radius(n, radius, n_min)
    i0, i1 = ring_integrals(ndot, None if w is None else w * a, width)
    return f0 * C_A * a * i0, f0 * C_A * a * a * i1


def hertz_rolling_moment(n, w, radius, K, C_H):
    """Hertzian rolling-resistance moment ``M_H = -(K/5) sqrt(n/r) C_H a^4 w`` (eq. 18)."""
    # a^4 sqrt(n/r) = r^1.5 n^2.5: written without the square root of a.
    return -(K / 5.0) * C_H * radius**1.5 * safe_pow(n, 2.5) * w


def lambda_moment(n, w, radius, C_A, lam, n_min=0.0):
    """Constant-lambda rolling moment ``g = -lambda C_A a w`` (eq. 19-22), opposing the spin."""
    return -lam * C_A * contact_radius(n, radius, n_min) * w


def friction_force(slip, load, friction, hold_force, width, restoring=0.0):
    """Regularized Coulomb friction on the sphere at the contact point.

    Exact law: ``-f N sign(s)`` while sliding; in pure rolling (``s = 0``) the force that keeps
    ``s = 0``, ``hold_force``, bounded by ``f N``. Regularized with the flat-zero switch
    ``p = tanh((s/width)^2)``::

        F_t = (1 - p) clip(hold, -f N, f N) - f N sign(s) p

    At ``s = 0`` this is exactly the holding force, so pure rolling is kept without a stiff
    restoring term; ``|s| > 3 width`` gives Coulomb sliding to 1e-7. The power ``F_t s`` is
    ``<= 0`` whenever ``hold_force = 0`` (no rolling moments).

    ``restoring >= 0`` adds ``-restoring * s`` to the holding force (still bounded by ``f N``):
    a mild linear pull toward rolling. Without it the law is flat at ``s = 0`` (zero slope), so
    a derivative taken at zero slip sees no friction at all: at normal incidence
    ``d omega_out / d omega0`` came out 1 instead of the exact 2/7. The pull only dissipates
    (its power is ``-restoring s^2 (1 - p) <= 0``).
    """
    limit = friction * load
    z = slip / width
    hold = jnp.clip(hold_force - restoring * slip, -limit, limit)
    return (1.0 - smooth_step_flat(z)) * hold - limit * smooth_sign_flat(z)


def mindlin_stiffness(n, radius, G_star, n_min=0.0):
    """Tangential (Mindlin) stiffness of the contact, ``k_t = 8 G* a`` with ``a = sqrt(r n)``.

    Mindlin (1949): the no-slip tangential compliance of a circular Hertz contact of radius
    ``a``. (``n_min``: the continuation below the contact floor, see contact_radius.)
    """
    return 8.0 * G_star * contact_radius(n, radius, n_min)


def mindlin_stiffness_slope(n, radius, G_star, n_min=0.0):
    """``d k_t / d n = 8 G* da/dn`` (``da/dn = sqrt(r) / (2 sqrt(n))``, continued as ``a``)."""
    if n_min <= 0.0:
        positive = n > 0
        return jnp.where(positive, 4.0 * G_star * jnp.sqrt(radius / jnp.where(positive, n, 1.0)), 0)
    slope = 4.0 * G_star * jnp.sqrt(radius / jnp.maximum(n, n_min))
    return jnp.where(n > -n_min, slope, 0.0)


def mindlin_slip_rate(xi, slip, load_limit, k_t, cap_rate, cap_width, slip_width, floor=None):
    """Rate at which the contact slips at the Coulomb cap: ``xi' = slip - rate`` (Hertz units).

    ``xi`` is the elastic tangential displacement, the spring force on the sphere ``-k_t xi``
    and the cap ``|k_t xi| <= f N = load_limit``, i.e. ``|xi| <= c = f N / k_t``; ``cap_rate``
    is ``dc/dt``. Exact rule (elastic-perfectly plastic, the history spring of DEM codes):
    below the cap the contact sticks (``xi' = slip``); at the cap it slips just enough that
    ``|xi|`` follows ``c``, i.e. ``rate = sign(xi) max(slip sign(xi) - c', 0)``. Regularized:
    the switch ``phi`` rises from 0 to exactly 1 over the last ``cap_width`` (a fraction of
    ``c``) below the cap, with the flat-zero step of the friction law; ``max(x, 0)`` becomes
    ``(x + sqrt(x^2 + slip_width^2)) / 2``. Both keep the dissipated power
    ``k_t xi rate = k_t |xi| phi max(...)`` >= 0 and ``|xi| <= c`` once reached.
    """
    force = jnp.abs(k_t * xi)
    if floor is None:
        ok = load_limit > 0
        ratio = jnp.where(ok, force / jnp.where(ok, load_limit, 1.0), 2.0)
        phi = 1.0 - smooth_step_flat(jnp.maximum(1.0 - ratio, 0.0) / cap_width)
    else:  # the switch's width at least cap_width * floor in force: bounded stiffness as N -> 0
        band = cap_width * jnp.maximum(load_limit, floor)
        phi = 1.0 - smooth_step_flat(jnp.maximum(load_limit - force, 0.0) / band)
    direction = jnp.sign(xi)
    drive = slip * direction - cap_rate
    return direction * phi * 0.5 * (drive + jnp.sqrt(drive * drive + slip_width * slip_width))


# --- JKR (Johnson, Kendall & Roberts 1971) -------------------------------------------------
# With ``E = 3 K / 4`` (the project's K is 4 E*/3) and ``w`` the work of adhesion, the contact
# radius ``a`` and overlap ``n`` of the stable branch are tied by ``n = a^2/r - sqrt(2 pi w a/E)``
# and the force is ``P = K a^3/r - sqrt(6 pi w K a^3)`` (repulsive positive). In the scales
# ``a = lam u^2``, ``n = mu d`` (``lam = (w r^2/E)^(1/3)``, ``mu = (w^2 r/E^2)^(1/3)``):
# ``u^4 - sqrt(2 pi) u = d``, solved in closed form through the resolvent cubic
# ``m^3 + d m - pi/4 = 0``: ``u = (sqrt(2 m) + sqrt(s))/2`` with ``s = 2 sqrt(pi/m) - 2 m``
# (docs/physics.md, "Normal laws"). The branch ends at the snap-off overlap
# ``d_c = -(3/4) pi^(2/3)`` (``m = pi^(1/3)``, ``s = 0``), where ``a`` has a square-root
# singularity; the cubic's root is smooth there.

JKR_SNAP_OFF = -0.75 * math.pi ** (2.0 / 3.0)  # snap-off overlap over mu
JKR_TOUCH = (2.0 * math.pi) ** (1.0 / 3.0)  # a / lam at zero overlap (snap-in)
# The load-controlled pull-off, where the force is least (``-1.5 pi w r``): ``a / lam =
# (9 pi / 8)^(1/3)`` and ``d = x^2 - sqrt(2 pi x)`` there (``model.jkr_release = "pull_off"``,
# LAMMPS's rule: its JKR contact ends there, not at the snap-off further out).
JKR_PULL_OFF_RADIUS = (9.0 * math.pi / 8.0) ** (1.0 / 3.0)
JKR_PULL_OFF = JKR_PULL_OFF_RADIUS**2 - math.sqrt(2.0 * math.pi * JKR_PULL_OFF_RADIUS)


def jkr_scales(radius, E, w):
    """``(lam, mu)``: the JKR scales of contact radius and overlap."""
    return (w * radius * radius / E) ** (1.0 / 3.0), (w * w * radius / (E * E)) ** (1.0 / 3.0)


def _jkr_cubic_root(d):
    """The real root ``m > 0`` of ``m^3 + d m - pi/4 = 0`` for ``d >= d_c`` (stable forms: the
    hyperbolic one for ``d > 0``, where Cardano's sum cancels, Cardano's for ``d <= 0``)."""
    q = math.pi / 8.0
    positive = d > 0
    dp = jnp.where(positive, d, 1.0)
    m_pos = 2.0 * jnp.sqrt(dp / 3.0) * jnp.sinh(jnp.arcsinh(q * (3.0 / dp) ** 1.5) / 3.0)
    dn = jnp.where(positive, 0.0, d)
    big = jnp.cbrt(q + jnp.sqrt(jnp.maximum(q * q + (dn / 3.0) ** 3, 0.0)))
    m_neg = big - dn / (3.0 * big)
    return jnp.where(positive, m_pos, m_neg)


def _jkr_branch(d):
    """``(m, s)`` of the closed form at ``d`` (see above)."""
    m = _jkr_cubic_root(d)
    return m, 2.0 * jnp.sqrt(math.pi / m) - 2.0 * m


def _jkr_floor_values(floor):
    """``m, s`` and their slopes in ``d`` at ``d_c + floor`` (plain floats: Newton's method on
    the cubic from its value at the snap-off, ``pi^(1/3)``)."""
    d = JKR_SNAP_OFF + floor
    m = math.pi ** (1.0 / 3.0)
    for _ in range(60):
        m -= (m**3 + d * m - math.pi / 4.0) / (3.0 * m * m + d)
    dm = -m / (3.0 * m * m + d)  # implicit derivative of the cubic
    s = 2.0 * math.sqrt(math.pi / m) - 2.0 * m
    ds = (-math.sqrt(math.pi) * m**-1.5 - 2.0) * dm
    return d, m, dm, s, ds


def jkr_contact_radius(n, radius, E, w, floor=0.0):
    """JKR contact radius on the stable branch at overlap ``n >= n_c`` (``n_c < 0``).

    ``floor > 0`` (in units of ``mu``): below ``n = mu (d_c + floor)`` the closed form's two
    parts ``m`` and ``s`` continue along their tangents (``s`` down to 0), so that the
    Runge-Kutta stages that overshoot the separation event see a smooth, finite law instead
    of the square root at the snap-off (compare :func:`contact_radius`).
    """
    lam, mu = jkr_scales(radius, E, w)
    d = n / mu
    if floor <= 0.0:
        m, s = _jkr_branch(d)
    else:
        d_f, m_f, dm_f, s_f, ds_f = _jkr_floor_values(floor)
        below = d < d_f
        m, s = _jkr_branch(jnp.where(below, d_f, d))
        m = jnp.where(below, m_f + dm_f * (d - d_f), m)
        s = jnp.where(below, s_f + ds_f * (d - d_f), s)
    u = 0.5 * (jnp.sqrt(2.0 * m) + safe_sqrt(jnp.maximum(s, 0.0)))
    return lam * u * u


def jkr_hertz_force(a, radius, K):
    """The Hertzian part of the JKR force, ``-K a^3 / r`` (repulsive: negative)."""
    return -K * a**3 / radius


def jkr_adhesion_force(a, K, w):
    """The adhesive part of the JKR force, ``sqrt(6 pi w K a^3)`` (attractive: positive)."""
    return jnp.sqrt(6.0 * math.pi * w * K * a**3)


def _jkr_energy(a, radius, K, w):
    """An antiderivative in ``a`` of ``P(a) dn/da`` (see :func:`jkr_potential`)."""
    return (
        0.4 * K * a**5 / radius**2
        - (8.0 / (3.0 * radius)) * jnp.sqrt(3.0 * math.pi * w * K / 8.0) * a**3.5
        + math.pi * w * a * a
    )


def jkr_potential(a, radius, K, w):
    """Potential energy of the JKR force at contact radius ``a``, zero at first touch:
    ``V = G(a) - G(a0)`` with ``G' = P dn/da``, ``a0 = lam (2 pi)^(1/3)``. The elastic
    impact's loss is ``V(a_c)``, the barrier a leaving sphere must climb."""
    E = 0.75 * K
    lam, _ = jkr_scales(radius, E, w)
    return _jkr_energy(a, radius, K, w) - _jkr_energy(JKR_TOUCH * lam, radius, K, w)


def jkr_rolling_moment(a, w_spin, radius, K, C_H):
    """Hertzian rolling-resistance moment with the JKR contact radius, ``-(K/5) C_H a^5 w / r``
    (eq. 18's ``a^4 sqrt(n/r)`` is ``a^5 / r`` for Hertz's ``a = sqrt(r n)``)."""
    return -(K / 5.0) * C_H * a**5 / radius * w_spin


# --- Thornton & Ning (1998): JKR with plastic yield -------------------------------------
# Reconstructed from secondary sources (docs/thornton_ning.md: the paper itself was not
# available): below the yield radius the contact is elastic JKR; beyond it the centre
# pressure is capped at the limiting pressure ``p_y`` and the force grows as
# ``P = P_y + pi p_y (a^2 - a_y^2) - sqrt(8 pi w E) a_y (sqrt(a) - sqrt(a_y))`` (repulsive
# positive) along the JKR geometry of the particle's radius; the contact unloads (and
# reloads below the peak) elastically along a JKR curve of a larger radius ``R_p`` through
# the peak, shifted in overlap. So the law at every state is a JKR curve: ``(r, 0)`` until
# yield, ``(R_p, s)`` after it, both functions of the peak overlap alone.


def thornton_ning_yield_radius(radius, E, w, p_yield, iterations=16):
    """The contact radius ``a_y`` at which the JKR centre pressure reaches ``p_y`` (TN eq. 65),
    ``p_y = 2 E a / (pi r) - sqrt(2 w E / (pi a))``. In the JKR scales (``a = lam y^2``,
    pressure over ``(E^2 w / r)^(1/3)``) it is the positive root of ``y^3 - (pi P / 2) y -
    sqrt(pi / 2) = 0``, found by Newton's method from ``sqrt(pi P/2) + (pi/2)^(1/6)``, above
    the root, where the cubic is convex and increasing: the iterates fall monotonically."""
    lam = (w * radius * radius / E) ** (1.0 / 3.0)
    pressure = p_yield / (E * E * w / radius) ** (1.0 / 3.0)
    c1 = 0.5 * math.pi * pressure
    c0 = math.sqrt(0.5 * math.pi)
    y = jnp.sqrt(c1) + c0 ** (1.0 / 3.0)
    for _ in range(iterations):
        y = y - (y**3 - c1 * y - c0) / (3.0 * y * y - c1)
    return lam * y * y


def jkr_force(a, radius, K, w):
    """The JKR force ``K a^3 / r - sqrt(6 pi w K a^3)`` (repulsive positive)."""
    return K * a**3 / radius - jkr_adhesion_force(a, K, w)


def thornton_ning_loading_force(a, a_yield, radius, K, w, p_yield):
    """The plastic loading force at contact radius ``a >= a_y`` (repulsive positive)."""
    E = 0.75 * K
    return (
        jkr_force(a_yield, radius, K, w)
        + math.pi * p_yield * (a * a - a_yield * a_yield)
        - jnp.sqrt(8.0 * math.pi * w * E) * a_yield * (jnp.sqrt(a) - jnp.sqrt(a_yield))
    )


def _thornton_ning_peak(peak, radius, E, w, a_yield):
    """``(plastic, a_p)``: whether the peak overlap is past yield, and its contact radius on
    the particle's JKR curve there (``2 a_y`` where it is not: a finite stand-in for the
    double where of the plastic branches)."""
    a_m = jkr_contact_radius(peak, radius, E, w)
    plastic = a_m > a_yield
    return plastic, jnp.where(plastic, a_m, 2.0 * a_yield)


def thornton_ning_curve(peak, radius, K, w, a_yield, p_yield):
    """``(R_p, s)``: the radius and overlap shift of the JKR curve the contact follows after
    reaching the peak overlap ``peak``: ``(r, 0)`` while the peak is elastic; beyond yield
    the curve through the peak's force ``P_m`` at its contact radius ``a_m``, ``R_p = K a_m^3
    / (P_m + sqrt(6 pi w K a_m^3))`` (continuity of the force) and ``s = peak - (a_m^2 / R_p
    - sqrt(2 pi w a_m / E))``. ``R_p`` and ``s`` are continuous at yield."""
    E = 0.75 * K
    plastic, a_p = _thornton_ning_peak(peak, radius, E, w, a_yield)
    load = thornton_ning_loading_force(a_p, a_yield, radius, K, w, p_yield)
    r_p = K * a_p**3 / (load + jkr_adhesion_force(a_p, K, w))
    shift = peak - (a_p * a_p / r_p - jnp.sqrt(2.0 * math.pi * w * a_p / E))
    return jnp.where(plastic, r_p, radius), jnp.where(plastic, shift, 0.0)


def thornton_ning_plastic_loss(peak, radius, K, w, a_yield, p_yield):
    """The energy yield has taken once the contact reached the peak overlap ``peak``: the
    work of the loading law up to the peak less the potential the unloading curve holds there
    (both zero at first touch; a contact that yields before it touches, ``a_y`` below JKR's
    zero-overlap radius, is outside the law's range: the scene refuses it, and here its work
    starts at first touch). The plastic part of the work, ``int P dn`` over ``a_y..a_m``
    with ``P = al + be a^2 - ga sqrt(a)`` and ``dn/da = 2 a / r - (ka / 2) a^(-1/2)`` (``ka =
    sqrt(2 pi w / E)``), is a polynomial in ``sqrt(a)``."""
    E = 0.75 * K
    plastic, a_p = _thornton_ning_peak(peak, radius, E, w, a_yield)
    c = jnp.sqrt(8.0 * math.pi * w * E)
    ka = jnp.sqrt(2.0 * math.pi * w / E)
    al = jkr_force(a_yield, radius, K, w) - math.pi * p_yield * a_yield**2 + c * a_yield**1.5
    be = math.pi * p_yield
    ga = c * a_yield

    def primitive(a):
        return (
            al / radius * a * a
            - al * ka * jnp.sqrt(a)
            + be / (2.0 * radius) * a**4
            - (be * ka / 5.0 + 4.0 * ga / (5.0 * radius)) * a**2.5
            + 0.5 * ga * ka * a
        )

    a_start = jnp.maximum(a_yield, JKR_TOUCH * jkr_scales(radius, E, w)[0])
    work = jkr_potential(a_start, radius, K, w) + primitive(a_p) - primitive(a_start)
    r_p, _ = thornton_ning_curve(peak, radius, K, w, a_yield, p_yield)
    stored = jkr_potential(a_p, jnp.where(plastic, r_p, radius), K, w)
    return jnp.where(plastic, work - stored, 0.0)
