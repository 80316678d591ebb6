"""LAMMPS input commands for a jaximpact scene's normal contact law (issue 54).

Renders the GRANULAR package's commands that reproduce a `Scene`'s normal contact: the
sphere-wall ``fix ID group wall/gran granular ... zplane LO NULL`` line, the sphere-sphere
``pair_style granular`` / ``pair_coeff * * ...`` lines, and the whole input script of one normal
sphere-wall (or sphere-sphere) impact, in ``units si``. Pure Python (no JAX import): the
scene's values are read as floats, so they must be concrete scalars.

Written against LAMMPS 29 Sep 2021 (Update 2; Debian's 0~20220106), read from its source
``src/GRANULAR/fix_wall_gran.cpp`` and ``pair_granular.cpp``; the facts below are that
version's, each checked by probing ``lmp`` (benchmarks/lammps_impacts.py, tests/):

- Laws. ``model.normal = "brach_dunn"`` without adhesion (``model.adhesion = false``, or
  ``contact.f0 = 0``) is ``hertz K eta`` (LAMMPS's ``kn`` is jaximpact's ``contact.K``, the
  force ``kn sqrt(R) delta^1.5``) or ``hertz/material E eta nu``; ``"dmt"`` is ``dmt E eta nu
  coh`` (force ``kn sqrt(R) delta^1.5 - 4 pi coh R``) and ``"jkr"`` is ``jkr E eta nu coh``,
  both with ``coh = w / 2`` (jaximpact's work of adhesion ``contact.w = 2 coh``).
- Material laws' modulus. The wall (fix wall/gran) computes ``kn = 4/3 E / (2 (1 - nu))``:
  ``(1 - nu)``, not the ``(1 - nu^2)`` of two identical materials. ``pair_coeff I I`` computes
  ``kn = 4/3 E / (2 (1 - nu^2))`` (``mix_stiffnessE(E, E, nu, nu)``). So ``E = 1.5 K (1 - nu)``
  on the wall and ``E = 1.5 K (1 - nu^2)`` for a pair; the normal force does not depend on the
  Poisson ratio chosen (it is solved for), only the Mindlin ``NULL`` tangential stiffness would.
  Mixed types (``pair_coeff I J`` left to mixing) drop the 4/3 (``normal_coeffs[0] =
  mix_stiffnessE(...)``): this module always writes ``pair_coeff * *``.
- Damping (``model.damping``, coefficient ``contact.eta_n``): ``F_d = -eta v_n`` with ``eta =``
  ``eta_n`` (velocity, kg/s), ``eta_n m_eff`` (mass_velocity, 1/s), ``eta_n a m_eff``
  (viscoelastic, 1/(m s); ``a = sqrt(R delta)``, JKR's own ``a``), ``alpha(e) sqrt(m_eff kn
  a)`` (tsuji: ``eta_n`` is a restitution ``e``, turned into ``alpha`` by the polynomial in
  :data:`TSUJI_POLYNOMIAL`). ``m_eff`` is the sphere's mass on the wall, ``m1 m2 / (m1 + m2)``
  for a pair (the free one's mass when the other is in ``fix freeze``). The damping acts
  whenever the contact does, so it is attractive while the sphere separates
  (``limit_damping`` would clip the total force at 0; LAMMPS refuses it with DMT and JKR, and
  this module does not write it). Brach-Dunn's Hertzian damping (``contact.C_H``) has no
  LAMMPS counterpart.
- Contact start and end. Hertz and DMT: in contact while ``delta >= 0`` (at the step's
  positions; DMT's adhesion ``4 pi coh R`` switches on and off there). JKR pair: snaps in at
  ``delta = 0`` and, once touching, stays in contact down to the load-controlled pull-off
  overlap (contact radius ``a^3 = 9 pi coh R^2 / (4 E*)``, where the force is its minimum
  ``-3 pi coh R``), not the displacement-controlled snap-off further out that jaximpact's JKR
  uses. JKR wall: the pull-off distance reads ``a^3 = 9 pi coh R / (4 E*)`` (``R``, not
  ``R^2``: not dimensionless; in SI units it keeps the contact to a gap of about 1.8 um for a
  10 um sphere), and past JKR's snap-off overlap the force is NaN: a rebound from the JKR wall
  ends in NaN. Use a pair with a large frozen partner for JKR (:func:`impact_script`'s
  ``partner_radius``).
- Tangential part, without a jaximpact tangential model of LAMMPS's (``model.tangential =
  "rigid"`` with ``contact.friction = 0``, or any model for a normal impact without spin):
  ``tangential linear_nohistory 0 0`` on the wall, ``tangential linear_history 0 0 0`` for a
  pair (no tangential force either way: a pair_style granular JKR contact without a
  tangential history stops every run with "Neighbor history overflow"
  (fix_neigh_history.cpp:392), even a run of one step before any contact).
- Tangential models (issue 54): ``model.tangential = "lammps_linear_history"`` is
  ``tangential linear_history k_t 0 mu`` (``contact.k_t`` in N/m) and ``"lammps_mindlin"``
  is ``tangential mindlin k_t0 0 mu`` with ``k_t0 = 8 contact.G_star`` (Pa; LAMMPS's spring is
  ``k_t0 a``, ``a = sqrt(R delta)``, JKR's own ``a``), ``mu = contact.friction``, the
  tangential damping ``x_gamma,t = 0``; the same words on the wall and for a pair. ``k_t0`` is
  always written as a number: the wall's ``NULL`` computes ``E/4 (2 - nu)(1 + nu)``
  (fix_wall_gran.cpp, FixWallGran constructor), not ``8 G_eff = 2 E / ((2 - nu)(1 + nu))`` of
  two identical materials (a factor ``(2 - nu)^2 (1 + nu)^2 / 8``, 0.61 at ``nu = 0.3``);
  the pair's ``NULL`` is ``8 mix_stiffnessG(E, E, nu, nu)`` = ``8 G_eff``. The history rule
  (``FixWallGran::granular``, ``PairGranular::compute``, identical in both): each step in
  contact ``xi += v_rel dt`` (``v_rel`` the contact point's slip at the step's half-step
  velocity), then ``F_t = -k_t xi``, and where ``|F_t| > mu Fncrit`` the history is rescaled
  to ``xi = -F_t mu Fncrit / (|F_t| k_t)`` (the force held at the cap; a cap of 0 zeroes the
  history). ``Fncrit`` is ``|Fne + Fdamp|`` for hertz and ``|Fne + 2 F_pulloff|`` for jkr
  (``F_pulloff = 3 pi coh R``): the adhesive laws load the friction with the elastic force
  only, without the damping. For dmt the source reads ``|Fne + 2 F_pulloff|`` with
  ``F_pulloff = 4 pi coh R``, but ``coh`` is a local that only the JKR branch sets
  (uninitialised for DMT, in FixWallGran::granular and PairGranular::compute alike): this
  build behaves as ``coh = 0`` there, ``Fncrit = |Fne| = |F_hertz - 4 pi coh R|``
  (benchmarks/lammps_oblique.py: DMT sliding impacts agree with ``|Fne|`` to 2e-7 of the
  speed and differ from ``|F_hertz + 4 pi coh R|`` by up to 0.04). The
  Mindlin spring ``k_t0 a`` shrinks with ``a`` on unloading while the history is kept
  (``mindlin``; ``mindlin_rescale`` would shrink the history too). The history is zeroed when
  the contact ends. Torque ``-arm n x F_t`` with the arm the sphere's radius on the wall and
  ``r - delta/2`` for a pair (pair_granular.cpp ``dist_to_contact``); the pair's slip uses
  ``r_i omega_i + r_j omega_j``. A jaximpact scene with ``model.tangential = "mindlin"`` or
  ``"rigid"`` friction is refused for impacts with tangential motion: LAMMPS has no rigid
  Coulomb law (its nearest is ``linear_history`` with a stiff ``k_t``: the spring's period
  ``2 pi sqrt(2 m / (7 k_t))`` well below the contact time), and jaximpact's Mindlin law
  (micro-slip, ``k_t = 8 G* a`` with load-history rules) is not LAMMPS's ``mindlin``; so are
  ``model.rolling_moments`` other than ``"none"`` (LAMMPS's rolling models are not mapped) and
  ``model.rotation = false`` (``fix nve/sphere`` always turns the sphere).

Hooke's linear law and Thornton-Ning, the Brach-Dunn adhesion ring and Hertzian ``C_H``
damping are not mapped (jaximpact has no linear law; LAMMPS has none of the others).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: The LAMMPS version whose source and behaviour this module follows.
VERSION = "29 Sep 2021"
#: LAMMPS's damping models (``damping NAME``); ``"none"`` here means undamped (coefficient 0).
DAMPINGS = ("velocity", "mass_velocity", "viscoelastic", "tsuji")
#: The LAMMPS normal laws a jaximpact scene maps to.
LAWS = ("hertz", "dmt", "jkr")
#: Tsuji's ``alpha(e)``, coefficients of ``e^0 .. e^6`` (fix_wall_gran.cpp, pair_granular.cpp).
TSUJI_POLYNOMIAL = (1.2728, -4.2783, 11.087, -22.348, 27.467, -18.022, 4.8218)
GEOMETRIES = ("wall", "pair")
#: LAMMPS's tangential models a jaximpact scene maps to (``"none"``: no tangential force).
TANGENTIALS = ("linear_history", "mindlin")
#: jaximpact's ``model.tangential`` of each of :data:`TANGENTIALS`.
SCENE_TANGENTIALS = {"lammps_linear_history": "linear_history", "lammps_mindlin": "mindlin"}
_OFFERS = (
    "LAMMPS (29 Sep 2021) offers the normal laws hooke, hertz, hertz/material, dmt and jkr "
    "(jaximpact model.normal = 'brach_dunn' without adhesion, 'dmt', 'jkr')"
)
_DAMPING_OFFERS = (
    "LAMMPS offers the damping models velocity, mass_velocity, viscoelastic and tsuji "
    "(model.damping with contact.eta_n), or none (contact.C_H = 0)"
)
_TANGENTIAL = (
    "LAMMPS has no rigid Coulomb law nor jaximpact's Mindlin micro-slip law; use "
    "model.tangential = 'lammps_linear_history' (contact.k_t; a stiff k_t approaches rigid "
    "Coulomb friction) or 'lammps_mindlin' (contact.G_star), which map to LAMMPS's "
    "linear_history and mindlin"
)


@dataclass(frozen=True)
class ContactLaw:
    """A normal contact law in plain numbers (SI): ``normal`` one of :data:`LAWS`, ``K`` the
    Hertz stiffness ``4 E*/3`` (Pa), ``w`` the work of adhesion (J/m^2; dmt, jkr),
    ``damping`` one of :data:`DAMPINGS` or ``"none"``, ``eta_n`` its coefficient (LAMMPS's
    meaning and units); ``tangential`` one of :data:`TANGENTIALS` or ``"none"``, ``k_t`` its
    stiffness (linear_history: N/m; mindlin: LAMMPS's ``k_t0 = 8 G*``, Pa), ``mu`` the
    friction coefficient (no tangential damping)."""

    normal: str
    K: float
    w: float = 0.0
    damping: str = "none"
    eta_n: float = 0.0
    tangential: str = "none"
    k_t: float = 0.0
    mu: float = 0.0

    def __post_init__(self):
        if self.normal not in LAWS:
            raise ValueError(f"normal must be one of {LAWS}, got {self.normal!r}")
        if self.damping not in (*DAMPINGS, "none"):
            raise ValueError(f"damping must be one of {(*DAMPINGS, 'none')}, got {self.damping!r}")
        if not (math.isfinite(self.K) and self.K > 0):
            raise ValueError(f"K must be a finite number > 0, got {self.K!r}")
        if self.tangential not in (*TANGENTIALS, "none"):
            raise ValueError(
                f"tangential must be one of {(*TANGENTIALS, 'none')}, got {self.tangential!r}"
            )
        if self.tangential != "none" and not (math.isfinite(self.k_t) and self.k_t > 0):
            raise ValueError(f"k_t must be a finite number > 0, got {self.k_t!r}")
        for name in ("w", "eta_n", "k_t", "mu"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if self.damping == "tsuji" and not 0 < self.eta_n <= 1:
            raise ValueError(f"tsuji's eta_n is a restitution in (0, 1], got {self.eta_n!r}")
        if self.w > 0 and self.normal == "hertz":
            raise ValueError("w > 0 needs normal = 'dmt' or 'jkr'")


def tsuji_alpha(e: float) -> float:
    """Tsuji's damping factor ``alpha(e)`` as LAMMPS computes it from the restitution ``e``."""
    return sum(c * e**k for k, c in enumerate(TSUJI_POLYNOMIAL))


def _scalar(scene_value, field: str) -> float:
    try:
        return float(scene_value)
    except (TypeError, ValueError):
        raise ValueError(
            f"{field} must be one concrete number to render LAMMPS commands, got {scene_value!r}"
        ) from None


def contact_law(scene, *, angle_deg: float = 0.0, omega0: float = 0.0) -> ContactLaw:
    """The `ContactLaw` of a jaximpact ``Scene`` for impacts at ``angle_deg`` with spin
    ``omega0`` (the impacts the commands are for; default normal, no spin).

    Raises:
        ValueError: naming the scene field LAMMPS cannot reproduce (``model.normal``,
        ``model.damping``, ``model.tangential``, ``contact.friction``, ...) and what it offers.
    """
    model, contact = scene.model, scene.contact
    normal = model.normal
    if normal == "brach_dunn":
        f0 = _scalar(contact.f0, "contact.f0")
        if model.adhesion and f0 > 0:
            raise ValueError(
                "model.normal = 'brach_dunn' with model.adhesion = true and contact.f0 > 0 (the "
                f"Brach-Dunn adhesion ring) has no LAMMPS law; {_OFFERS}"
            )
        law = "hertz"
    elif normal in ("dmt", "jkr"):
        law = normal
    else:
        raise ValueError(f"model.normal = {normal!r} has no LAMMPS law; {_OFFERS}")
    damping = getattr(model, "damping", "hertzian")
    C_H = _scalar(contact.C_H, "contact.C_H")
    if damping == "hertzian":
        if C_H > 0:
            raise ValueError(
                "model.damping = 'hertzian' with contact.C_H > 0 (Brach-Dunn's Hertzian "
                f"damping) has no LAMMPS model; {_DAMPING_OFFERS}"
            )
        damping, eta_n = "none", 0.0
    elif damping in DAMPINGS:
        eta_n = _scalar(getattr(contact, "eta_n", 0.0), "contact.eta_n")
    else:
        raise ValueError(f"model.damping = {damping!r} has no LAMMPS model; {_DAMPING_OFFERS}")
    tangential, k_t, mu = _tangential(scene, angle_deg, omega0)
    w = _scalar(contact.w, "contact.w") if law != "hertz" else 0.0
    K = _scalar(contact.K, "contact.K")
    return ContactLaw(law, K, w, damping, eta_n, tangential, k_t, mu)


def _tangential(scene, angle_deg, omega0):
    """``(tangential, k_t, mu)`` of the ContactLaw; refusals as ``_check_tangential``."""
    model, contact = scene.model, scene.contact
    name = SCENE_TANGENTIALS.get(model.tangential)
    if name is None:
        _check_tangential(scene, angle_deg, omega0)
        return "none", 0.0, 0.0
    if name == "linear_history":
        k_t = _scalar(contact.k_t, "contact.k_t")
    else:
        k_t = 8.0 * _scalar(contact.G_star, "contact.G_star")
    mu = _scalar(contact.friction, "contact.friction")
    if _moving(scene, angle_deg, omega0):
        if model.rotation and model.rolling_moments != "none":
            raise ValueError(
                f"model.rolling_moments = {model.rolling_moments!r} with tangential motion: "
                "LAMMPS's rolling models are not mapped yet (use 'none')"
            )
        if not model.rotation and mu > 0:
            raise ValueError(
                "model.rotation = false with friction and tangential motion: LAMMPS's fix "
                "nve/sphere always turns the sphere (use model.rotation = true)"
            )
    return name, k_t, mu


def _moving(scene, angle_deg, omega0):
    """Whether the impacts have tangential motion or spin (the sphere's or a target's)."""
    if float(angle_deg) == 0.0 and float(omega0) == 0.0:
        target = getattr(scene, "target", None)
        if target is None or _scalar(target.omega0, "target.omega0") == 0.0:
            return False
    return True


def _check_tangential(scene, angle_deg, omega0):
    if not _moving(scene, angle_deg, omega0):
        return  # a normal impact without spin: no tangential force in either code
    if scene.model.tangential != "rigid":
        raise ValueError(
            f"model.tangential = {scene.model.tangential!r} with tangential motion (angle "
            f"{angle_deg} deg, omega0 {omega0} rad/s): {_TANGENTIAL}"
        )
    if _scalar(scene.contact.friction, "contact.friction") > 0:
        raise ValueError(
            f"contact.friction > 0 with tangential motion (angle {angle_deg} deg, omega0 "
            f"{omega0} rad/s): {_TANGENTIAL}"
        )
    if scene.model.rotation and scene.model.rolling_moments != "none":
        raise ValueError(
            f"model.rolling_moments = {scene.model.rolling_moments!r} with tangential motion: "
            "LAMMPS's rolling models are not mapped yet"
        )


def _law(law_or_scene, angle_deg=0.0, omega0=0.0) -> ContactLaw:
    if isinstance(law_or_scene, ContactLaw):
        return law_or_scene
    return contact_law(law_or_scene, angle_deg=angle_deg, omega0=omega0)


def youngs_modulus(K: float, poisson: float, geometry: str = "wall") -> float:
    """The ``E`` to give LAMMPS's material laws so that its ``kn`` is ``K``: ``1.5 K (1 - nu)``
    on the wall (fix wall/gran's ``kn = 4/3 E / (2 (1 - nu))``), ``1.5 K (1 - nu^2)`` for a
    pair of one type (``kn = 4/3 E / (2 (1 - nu^2))``)."""
    _check_geometry(geometry)
    if not -1.0 < poisson < 0.5:
        raise ValueError(f"poisson must be in (-1, 0.5), got {poisson!r}")
    return 1.5 * K * ((1.0 - poisson) if geometry == "wall" else (1.0 - poisson**2))


def _check_geometry(geometry):
    if geometry not in GEOMETRIES:
        raise ValueError(f"geometry must be one of {GEOMETRIES}, got {geometry!r}")


def _num(x: float) -> str:
    """A float as LAMMPS reads it back exactly (Python's shortest round-trip form)."""
    return repr(float(x))


def normal_arguments(law: ContactLaw, *, geometry="wall", material=False, poisson=0.3) -> str:
    """The normal-law and damping words of a ``wall/gran granular`` or ``pair_coeff`` command:
    ``hertz K eta damping D`` / ``hertz/material E eta nu damping D`` / ``dmt E eta nu coh
    damping D`` / ``jkr E eta nu coh damping D`` (``D``: ``velocity`` with ``eta = 0`` when
    undamped). DMT and JKR are material laws in LAMMPS, whatever ``material`` says."""
    _check_geometry(geometry)
    damping = "velocity" if law.damping == "none" else law.damping
    eta = _num(law.eta_n)
    if law.normal == "hertz" and not material:
        words = f"hertz {_num(law.K)} {eta}"
    else:
        E = _num(youngs_modulus(law.K, poisson, geometry))
        name = "hertz/material" if law.normal == "hertz" else law.normal
        words = f"{name} {E} {eta} {_num(poisson)}"
        if law.normal != "hertz":
            words += f" {_num(law.w / 2.0)}"
    return f"{words} damping {damping}"


_TANGENTIAL_COMMENT = "# tangential models are not mapped yet: no tangential force"


def tangential_arguments(law: ContactLaw, *, geometry="wall") -> str:
    """The tangential words of a ``wall/gran granular`` or ``pair_coeff`` command:
    ``tangential linear_history k_t 0 mu`` / ``tangential mindlin k_t0 0 mu`` (``k_t0 = 8 G*``
    as a number, never ``NULL``: see the module's notes), or no tangential force
    (``linear_nohistory 0 0`` on the wall, ``linear_history 0 0 0`` for a pair)."""
    _check_geometry(geometry)
    if law.tangential == "none":
        if geometry == "wall":
            return "tangential linear_nohistory 0 0"
        return "tangential linear_history 0 0 0"
    return f"tangential {law.tangential} {_num(law.k_t)} 0 {_num(law.mu)}"


def _tangential_comment(law: ContactLaw) -> str:
    if law.tangential == "none":
        return _TANGENTIAL_COMMENT
    if law.tangential == "linear_history":
        spring = f"k_t = {law.k_t:.6g} N/m (contact.k_t)"
    else:
        spring = f"k_t0 = 8 G* = {law.k_t:.6g} Pa (8 contact.G_star), spring k_t0 a"
    return (
        f"# tangential {law.tangential}: {spring}, no tangential damping, mu = {law.mu:.6g} "
        "(contact.friction)"
    )


def wall_fix(
    law_or_scene,
    *,
    fix_id="wall",
    group="all",
    z=0.0,
    material=False,
    poisson=0.3,
    angle_deg=0.0,
    omega0=0.0,
) -> str:
    """The ``fix ID GROUP wall/gran granular ... zplane Z NULL`` command (with a comment line
    before it) of a scene or `ContactLaw`: a flat wall at ``z`` below the spheres."""
    law = _law(law_or_scene, angle_deg, omega0)
    words = normal_arguments(law, geometry="wall", material=material, poisson=poisson)
    return (
        f"{_tangential_comment(law)}\n"
        f"fix {fix_id} {group} wall/gran granular {words} "
        f"{tangential_arguments(law, geometry='wall')} zplane {_num(z)} NULL"
    )


def pair_commands(
    law_or_scene, *, material=False, poisson=0.3, angle_deg=0.0, omega0=0.0
) -> list[str]:
    """``["pair_style granular", "pair_coeff * * ..."]`` (with a comment line between) for
    sphere-sphere contacts of a scene or `ContactLaw`: every atom type with every other, so
    LAMMPS's mixing (which drops the 4/3 of the material laws) is never used."""
    law = _law(law_or_scene, angle_deg, omega0)
    words = normal_arguments(law, geometry="pair", material=material, poisson=poisson)
    comment = _tangential_comment(law)
    if law.tangential == "none":
        comment += " (linear_history with kt = 0: see the module's notes)"
    return [
        "pair_style granular",
        comment,
        f"pair_coeff * * {words} {tangential_arguments(law, geometry='pair')}",
    ]


def contact_time_estimate(radius, density, K, speed) -> float:
    """Hertz's contact time ``2.868 (m^2 / (R E*^2 v))^(1/5)`` (``E* = 3K/4``), in s."""
    m = density * 4.0 / 3.0 * math.pi * radius**3
    return 2.868 * (m * m / (radius * (0.75 * K) ** 2 * speed)) ** 0.2


def wall_pulloff_distance(law: ContactLaw, radius: float) -> float:
    """fix wall/gran's JKR pull-off distance in this version (``a^3 = 9 pi coh R / (4 E*)``,
    as written; metres in ``units si``): the gap beyond contact out to which a touching
    sphere is kept in contact. 0 for the other laws."""
    if law.normal != "jkr" or law.w == 0:
        return 0.0
    coh, E = law.w / 2.0, 0.75 * law.K
    a = (9.0 * math.pi * coh * radius / (4.0 * E)) ** (1.0 / 3.0)
    return a * a / radius - 2.0 * math.sqrt(math.pi * coh * a / E)


def pair_pulloff_overlap(law: ContactLaw, reff: float) -> float:
    """pair granular's JKR pull-off overlap (``< 0``): contact radius ``a^3 = 9 pi coh R^2 /
    (4 E*)``, the force's minimum ``-3 pi coh R``. 0 for the other laws."""
    if law.normal != "jkr" or law.w == 0:
        return 0.0
    coh, E = law.w / 2.0, 0.75 * law.K
    a = (9.0 * math.pi * coh * reff * reff / (4.0 * E)) ** (1.0 / 3.0)
    return a * a / reff - 2.0 * math.sqrt(math.pi * coh * a / E)


def impact_script(
    law_or_scene,
    speed: float,
    *,
    radius: float | None = None,
    density: float | None = None,
    dt: float,
    max_steps: int,
    partner_radius: float | None = None,
    material=False,
    poisson=0.3,
) -> str:
    """The input script of one normal impact at ``speed`` (m/s) in ``units si``: one sphere
    (``atom_style sphere``, ``fix nve/sphere``, no gravity) starting 1.5 steps of flight above
    contact, moving down onto the wall at z = 0 (``partner_radius=None``) or onto a frozen
    sphere of that radius whose top is at z = 0 (``pair_style granular``; ``fix freeze``
    makes ``m_eff`` the moving sphere's mass; the contact's ``R`` is ``r Rp / (r + Rp)``).

    The run stops (``fix halt``, ``error soft``) once the sphere has left the contact moving
    up, else after ``max_steps`` steps of ``dt``; the last line printed is ``JAXIMPACT
    step=N z=Z vz=VZ`` (17 digits). ``radius``/``density`` default to the scene's."""
    law = _law(law_or_scene)
    if radius is None or density is None:
        radius = _scalar(law_or_scene.particle.radius, "particle.radius")
        density = _scalar(law_or_scene.particle.density, "particle.density")
    if not (speed > 0 and dt > 0 and max_steps > 0):
        raise ValueError("speed, dt and max_steps must be > 0")
    z0 = radius + 1.5 * speed * dt
    if partner_radius is None:
        leave = radius + max(wall_pulloff_distance(law, radius), 0.0)
        contact = [wall_fix(law, material=material, poisson=poisson)]
    else:
        reff = radius * partner_radius / (radius + partner_radius)
        leave = radius - min(pair_pulloff_overlap(law, reff), 0.0)
        contact = pair_commands(law, material=material, poisson=poisson)
    lines = _setup_lines(radius, density, z0, speed, partner_radius)
    lines += contact
    lines += [
        f"timestep {_num(dt)}",
        f"variable left equal (z[1]>{_num(leave)})&&(vz[1]>0)",
        "fix stop all halt 1 v_left > 0.5 error soft",
        "variable vzf format vzv %.17g",
        "variable vzv equal vz[1]",
        "variable zf format zv %.17g",
        "variable zv equal z[1]",
        "thermo 1000000000",
        f"run {int(max_steps)}",
        'print "JAXIMPACT step=$(step) z=${zf} vz=${vzf}"',
    ]
    return "\n".join(lines) + "\n"


def _setup_lines(radius, density, z0, speed, partner_radius, x0=0.0, vx=0.0, omega=0.0, nsq=False):
    size = 4.0 * radius if partner_radius is None else 1.01 * partner_radius + 2 * radius
    zlo = -radius if partner_radius is None else -2.02 * partner_radius
    lines = [
        f"# jaximpact: one normal impact, LAMMPS {VERSION} GRANULAR",
        "units si",
        "atom_style sphere",
        "atom_modify map array",
        "boundary f f f",
        "comm_modify vel yes",
        f"region box block {_num(-size)} {_num(size)} {_num(-size)} {_num(size)} "
        f"{_num(zlo)} {_num(z0 + 4.0 * radius)}",
        f"create_box {1 if partner_radius is None else 2} box",
        f"create_atoms 1 single {_num(x0)} 0.0 {_num(z0)}",
        f"set atom 1 diameter {_num(2.0 * radius)} density {_num(density)}",
        "group ball id 1",
    ]
    if partner_radius is not None:
        lines += [
            f"create_atoms 2 single 0.0 0.0 {_num(-partner_radius)}",
            f"set atom 2 diameter {_num(2.0 * partner_radius)} density {_num(density)}",
            "group partner id 2",
            "fix hold partner freeze",
        ]
    lines.append(f"velocity ball set {_num(vx)} 0.0 {_num(-speed)}")
    if omega != 0.0:
        lines.append(f"set atom 1 omega 0.0 {_num(omega)} 0.0")
    return lines + [
        f"neighbor {_num(0.5 * radius)} {'nsq' if nsq else 'bin'}",
        "neigh_modify every 1 delay 0 check yes",
        "fix integrate ball nve/sphere",
    ]


#: The quantities the last line of :func:`oblique_script` prints (``JAXIMPACT k=v ...``).
OBLIQUE_FIELDS = ("step", "x", "z", "vx", "vz", "wy", "fx", "fz", "ty", "mass")


def oblique_script(
    law_or_scene,
    speed: float,
    angle_deg: float,
    omega0: float,
    *,
    radius: float | None = None,
    density: float | None = None,
    dt: float,
    max_steps: int,
    partner_radius: float | None = None,
    material=False,
    poisson=0.3,
) -> str:
    """The input script of one oblique, spinning impact (``units si``): as
    :func:`impact_script`, with the tangential velocity ``speed sin(angle)`` along +x and the
    spin ``omega0`` about +y (jaximpact's signs: ``vx - r omega_y`` is the contact point's
    slip, so a positive ``omega0`` with a positive angle is the rolling sense), the normal
    speed ``speed cos(angle)`` down -z. The sphere starts 1.5 steps of flight above contact, at
    ``x = -1.5 vx dt`` so that the contact starts at x = 0 (on the top of a frozen partner,
    whose neighbour list is ``nsq``: a partner of many radii would need too many bins).

    The run stops (``fix halt``) at the last step in contact: when the next step's position
    ``x + dt (v + dt f / (2 m))`` leaves the contact moving away (the wall's ``z > r``, JKR's
    pull-off distance; for a partner the distance from its centre), else after ``max_steps``.
    The last line printed is ``JAXIMPACT`` with :data:`OBLIQUE_FIELDS` as ``k=v`` (17
    digits): position, velocity, spin ``omega_y``, force and torque ``T_y`` of that step, from
    which the exit state is ``v + s dt f / m``, ``omega + s dt T_y / I`` (``s`` the step's
    fraction to the exit)."""
    law = _law(law_or_scene, angle_deg, omega0)
    if radius is None or density is None:
        radius = _scalar(law_or_scene.particle.radius, "particle.radius")
        density = _scalar(law_or_scene.particle.density, "particle.density")
    if not (speed > 0 and dt > 0 and max_steps > 0 and -90.0 < angle_deg < 90.0):
        raise ValueError("speed, dt and max_steps must be > 0, angle_deg in (-90, 90)")
    vn = speed * math.cos(math.radians(angle_deg))
    vx = speed * math.sin(math.radians(angle_deg))
    z0 = radius + 1.5 * vn * dt
    lines = _setup_lines(radius, density, z0, vn, partner_radius, x0=-1.5 * vx * dt, vx=vx,
                         omega=omega0, nsq=partner_radius is not None)  # fmt: skip
    lines[0] = f"# jaximpact: one oblique impact, LAMMPS {VERSION} GRANULAR"
    h = _num(dt)
    xn = f"(x[1]+{h}*(vx[1]+0.5*{h}*fx[1]/mass[1]))"
    zn = f"(z[1]+{h}*(vz[1]+0.5*{h}*fz[1]/mass[1]))"
    if partner_radius is None:
        leave = radius + max(wall_pulloff_distance(law, radius), 0.0)
        lines.append(wall_fix(law, material=material, poisson=poisson))
        left = f"({zn}>{_num(leave)})&&(vz[1]>0)"
    else:
        reff = radius * partner_radius / (radius + partner_radius)
        leave = partner_radius + radius - min(pair_pulloff_overlap(law, reff), 0.0)
        lines += pair_commands(law, material=material, poisson=poisson)
        c = _num(partner_radius)
        left = (f"(sqrt({xn}^2+({zn}+{c})^2)>{_num(leave)})"
                f"&&(x[1]*vx[1]+(z[1]+{c})*vz[1]>0)")  # fmt: skip
    lines += [
        f"timestep {h}",
        "fix state ball store/state 1 omegay tqy",  # current at every step, unlike a compute
        f"variable left equal {left}",
        "fix stop all halt 1 v_left > 0.5 error soft",
    ]
    values = {"x": "x[1]", "z": "z[1]", "vx": "vx[1]", "vz": "vz[1]", "wy": "f_state[1][1]",
              "fx": "fx[1]", "fz": "fz[1]", "ty": "f_state[1][2]", "mass": "mass[1]"}  # fmt: skip
    for k, expr in values.items():
        lines += [f"variable {k}v equal {expr}", f"variable {k}f format {k}v %.17g"]
    printed = " ".join(f"{k}=${{{k}f}}" for k in values)
    lines += ["thermo 1000000000", f"run {int(max_steps)}",
              f'print "JAXIMPACT step=$(step) {printed}"']  # fmt: skip
    return "\n".join(lines) + "\n"
