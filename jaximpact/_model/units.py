"""Hertz units: the scales in which every impact is integrated.

Mass unit: the particle mass ``m``. Length unit: the undamped Hertz peak overlap at the normal
speed, ``n* = (5 m v_n^2 / (4 K sqrt(r)))^(2/5)``. Time unit: ``n*/v_n``. In these units the
normal speed at first touch is 1, the Hertz force is ``-(5/4) x^1.5`` and solver tolerances are
dimensionless, whatever the size or speed of the sphere (nanometres and nanoseconds in SI).
"""

import equinox as eqx
import jax
import jax.numpy as jnp


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
    ):
        L, T, m = u.length, u.time, u.mass
        r = radius / L
        return ScaledParameters(
            radius=r,
            K=K * L * T**2 / m,
            f0=f0 * T**2 / m,
            C_A=C_A * L / T,
            C_H=C_H * L / T,
            friction=jnp.asarray(friction),
            lam=lam * T**2 / (m * L**2),
            inertia=inertia_factor * r * r,
            G_star=None if G_star is None else G_star * L * T**2 / m,
            w_adhesion=None if w_adhesion is None else w_adhesion * T**2 / m,
        )
