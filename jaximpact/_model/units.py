"""Hertz units: the scales in which every impact is integrated.

Mass unit: the particle mass ``m``. Length unit: the undamped Hertz peak overlap at the normal
speed, ``n* = (5 m v_n^2 / (4 K sqrt(r)))^(2/5)``. Time unit: ``n*/v_n``. In these units the
normal speed at first touch is 1, the Hertz force is ``-(5/4) x^1.5`` and solver tolerances are
dimensionless, whatever the size or speed of the sphere (nanometres and nanoseconds in SI).
"""

import equinox as eqx
import jax
import jax.numpy as jnp

from . import laws


class HertzUnits(eqx.Module):
    """Length (m), time (s) and mass (kg) units of one impact."""

    length: jax.Array
    time: jax.Array
    mass: jax.Array

    @property
    def speed(self):
        return self.length / self.time

    @property
    def energy(self):
        return self.mass * self.speed**2


def hertz_units(mass, radius, K, normal_speed) -> HertzUnits:
    """Hertz units of an impact at ``normal_speed`` (m/s) of a sphere on a surface ``K``."""
    length = (5.0 * mass * normal_speed**2 / (4.0 * K * jnp.sqrt(radius))) ** 0.4
    return HertzUnits(length=length, time=length / normal_speed, mass=mass)


class ScaledParameters(eqx.Module):
    """The scene's parameters of one impact, in its Hertz units (mass 1)."""

    radius: jax.Array
    K: jax.Array
    f0: jax.Array
    C_A: jax.Array
    C_H: jax.Array
    friction: jax.Array
    lam: jax.Array
    inertia: jax.Array  # k^2 = kappa r^2
    G_star: jax.Array | None = None  # only with the Mindlin tangential spring
    w_adhesion: jax.Array | None = None  # only with the DMT normal law (a force per length)
    # The particle's moment arm (its radius; ``radius`` is the contact's, the reduced radius
    # of a sphere-sphere impact) and, with a second sphere, its arm and ``k^2 m2 / m*``.
    arm: jax.Array | None = None
    arm2: jax.Array | None = None
    inertia2: jax.Array | None = None
    # Thornton-Ning: the limiting contact pressure and the yield radius it gives.
    p_yield: jax.Array | None = None
    a_yield: jax.Array | None = None
    # A LAMMPS normal damping (``model.damping``, ``laws.LAMMPS_DAMPING``): its coefficient in
    # Hertz units (mass 1), as ``laws.lammps_damping_coefficient`` takes it (tsuji: alpha(e)).
    eta_n: jax.Array | None = None
    # LAMMPS's linear_history tangential stiffness (model.tangential = "lammps_linear_history").
    k_t: jax.Array | None = None

    @staticmethod
    def from_si(
        u: HertzUnits,
        *,
        radius,
        K,
        f0,
        C_A,
        C_H,
        friction,
        lam,
        inertia_factor,
        G_star=None,
        w_adhesion=None,
        target=None,
        p_yield=None,
        damping=None,
        eta_n=None,
        k_t=None,
    ):
        """``damping``, ``eta_n``: a LAMMPS normal damping model and its coefficient (SI, as
        LAMMPS takes it: kg/s, 1/s, 1/(m s), or the restitution coefficient of "tsuji").
        ``target``: ``(r1, m1, r2, m2)`` (SI) of a sphere-sphere impact, whose contact radius
        ``radius`` is the reduced one and mass unit ``u.mass`` the reduced mass."""
        L, T, m = u.length, u.time, u.mass
        r = radius / L
        arm, arm2, inertia, inertia2 = r, None, inertia_factor * r * r, None
        if target is not None:
            r1, m1, r2, m2 = target
            arm, arm2 = r1 / L, r2 / L
            inertia = inertia_factor * (m1 / m) * arm * arm
            inertia2 = inertia_factor * (m2 / m) * arm2 * arm2
        K_scaled = K * L * T**2 / m
        w_scaled = None if w_adhesion is None else w_adhesion * T**2 / m
        a_yield = None
        if p_yield is not None:  # a pressure scales as K
            p_yield = p_yield * L * T**2 / m
            a_yield = laws.thornton_ning_yield_radius(r, 0.75 * K_scaled, w_scaled, p_yield)
        eta_scaled = None
        if damping in laws.LAMMPS_DAMPING:
            scale = {"velocity": T / m, "mass_velocity": T, "viscoelastic": L * T}
            if damping == "tsuji":
                eta_scaled = laws.tsuji_alpha(jnp.asarray(eta_n))
            else:
                eta_scaled = eta_n * scale[damping]
        return ScaledParameters(
            radius=r,
            K=K_scaled,
            f0=f0 * T**2 / m,
            C_A=C_A * L / T,
            C_H=C_H * L / T,
            friction=jnp.asarray(friction),
            lam=lam * T**2 / (m * L**2),
            inertia=inertia,
            G_star=None if G_star is None else G_star * L * T**2 / m,
            w_adhesion=w_scaled,
            arm=arm,
            arm2=arm2,
            inertia2=inertia2,
            p_yield=p_yield,
            a_yield=a_yield,
            eta_n=eta_scaled,
            k_t=None if k_t is None else k_t * T**2 / m,
        )
