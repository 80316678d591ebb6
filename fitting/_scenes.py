"""Scenes that go with the bundled data sets."""

from __future__ import annotations

import jaximpact

__all__ = ["kharaz2001_scene"]


def kharaz2001_scene(friction: float = 0.1) -> jaximpact.Scene:
    """A scene for the Kharaz (2001) experiments: 5 mm alumina spheres on a thick glass anvil.

    As in the Chung & Ooi (2011) DEM benchmark, the anvil is taken as rigid, so
    ``K = 4/3 E*`` with ``1/E* = (1 - nu^2)/E`` of the sphere alone (E = 380 GPa, nu = 0.23):
    ``K = 5.35e11 Pa``. Radius 2.5 mm, density 4000 kg/m^3, no adhesion (``f0 = C_A = 0``),
    no rolling moments, and ``C_H = 0.008 s/m``, which gives the reported normal restitution
    of about 0.98 at 3.9 m/s (0.980 at 30 degrees incidence, 0.985 at 60).

    Arguments:
        friction: the Coulomb coefficient (the quantity to fit; the published value is 0.092).

    Returns:
        jaximpact.Scene: the scene, default impact 3.9 m/s at 45 degrees, no spin.
    """
    E, nu = 380e9, 0.23
    return jaximpact.Scene(
        particle=jaximpact.Particle(radius=2.5e-3, density=4000.0),
        contact=jaximpact.Contact(
            K=4.0 / 3.0 * E / (1.0 - nu**2), f0=0.0, C_A=0.0, C_H=0.008, friction=friction
        ),
        model=jaximpact.Model(rotation=True, adhesion=False, rolling_moments="none"),
        impact=jaximpact.Impact(speed=3.9, angle_deg=45.0, omega0=0.0),
    )
