"""Scenes that go with the bundled data sets."""

from __future__ import annotations

import jaximpact

__all__ = ["kharaz2001_scene"]


def kharaz2001_scene(friction: float = 0.1) -> jaximpact.Scene:
    """The embedded ``kharaz2001`` scene (5 mm alumina spheres on a thick glass anvil) with
    the given friction coefficient.

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
    # One source of truth: the embedded scene file jaximpact/scenes/kharaz2001.toml.
    return jaximpact.load_scene("kharaz2001").replace(contact={"friction": friction})
