"""``jaximpact show``: a scene as the simulator resolves it, in words and numbers.

Derived quantities (K from E and nu, C_A and C_H from zeta, the moment of inertia), the Hertz
scales of the scene's default impact, the solver ``method = "auto"`` picks and why, and which
terms that impact compiles and which it leaves out (and why).
"""

import math
import tomllib

import jax.numpy as jnp
import numpy as np

from .._engine.settings import (
    integration_settings,
    required_terms,
    scene_parameters,
    stiffness_estimate,
)
from .._engine.solvers import default_slip_width
from .._model.scene import INERTIA_FACTOR
from .scene_files import describe_scene_source, load_scene, scene_path

HERTZ_DURATION = (
    2.9432  # undamped Hertz contact time in units of n*/v_n: 2 * int_0^1 dx/sqrt(1-x^2.5)
)


def _raw(scene) -> dict:
    """The scene file's own keys (to say which values were given and which derived)."""
    try:
        with open(scene_path(scene), "rb") as fh:
            return tomllib.load(fh)
    except (OSError, tomllib.TOMLDecodeError):
        return {}


def _g(x) -> str:
    return f"{float(x):.6g}"


def scene_report(scene_arg=None) -> str:
    """The text ``jaximpact show [SCENE]`` prints."""
    scene = load_scene(scene_arg)
    raw = _raw(scene_arg).get("contact", {})
    p, c, m, i = scene.particle, scene.contact, scene.model, scene.impact
    r, rho, K = float(p.radius), float(p.density), float(c.K)
    mass = rho * 4.0 / 3.0 * math.pi * r**3
    lines = [f"scene: {describe_scene_source(scene_arg)}", ""]
    lines += _particle_and_contact(scene, raw, r, rho, K, mass)
    lines += _model_lines(m)
    speed, angle, omega0 = float(i.speed), float(i.angle_deg), float(i.omega0)
    if scene.target is not None:  # the relative motion's scales
        r2, m2 = float(scene.target.radius), float(scene.target.mass)
        r, mass = r * r2 / (r + r2), mass * m2 / (mass + m2)
    lines += _impact_lines(speed, angle, omega0, r, K, mass)
    params = scene_parameters(scene)
    lines += _solver_lines(scene, params, speed, angle)
    terms = required_terms(scene, params, angle, omega0)
    lines += _terms_lines(terms, m)
    return "\n".join(lines)


def _particle_and_contact(scene, raw: dict, r, rho, K, mass) -> list[str]:
    """The particle and contact sections, each derived value with its origin."""
    c, m = scene.contact, scene.model
    lines = []
    lines.append("particle")
    lines.append(f"  radius r            {_g(r)} m")
    lines.append(f"  density             {_g(rho)} kg/m^3")
    lines.append(f"  mass m              {_g(mass)} kg")
    lines.append(
        f"  k^2 = {INERTIA_FACTOR} r^2       {_g(INERTIA_FACTOR * r * r)} m^2  (solid sphere)"
    )
    t = scene.target
    if t is not None:
        r2, rho2 = float(t.radius), float(t.density)
        m2 = rho2 * 4.0 / 3.0 * math.pi * r2**3
        lines.append("target (a second sphere instead of the wall)")
        lines.append(f"  radius r2           {_g(r2)} m")
        lines.append(f"  density             {_g(rho2)} kg/m^3")
        lines.append(f"  spin omega0         {_g(float(t.omega0))} rad/s")
        lines.append(f"  reduced radius      {_g(r * r2 / (r + r2))} m  (every contact law)")
        lines.append(f"  reduced mass        {_g(mass * m2 / (mass + m2))} kg  (normal motion)")

    lines.append("contact")
    if "E1" in raw:
        origin = (
            f"from E1 = {_g(raw['E1'])} Pa, nu1 = {raw['nu1']}, E2 = {_g(raw['E2'])} Pa, "
            f"nu2 = {raw['nu2']}: K = 4 / (3 pi (k1 + k2))"
        )
    else:
        origin = "given"
    lines.append(f"  K                   {_g(K)} Pa  ({origin})")
    if m.normal != "brach_dunn":
        pull_off = "work of adhesion; pull-off " + (
            "2 pi w r (DMT)" if m.normal == "dmt" else "1.5 pi w r (JKR)"
        )
        lines.append(f"  w                   {_g(c.w)} J/m^2  ({pull_off})")
        if m.normal == "thornton_ning":
            lines.append(
                f"  p_y                 {_g(c.p_y)} Pa  (limiting contact pressure: yield)"
            )
    else:
        lines.append(f"  f0                  {_g(c.f0)} N/m")
    for name in ("A", "H"):
        value = float(getattr(c, f"C_{name}"))
        if f"zeta_{name}" in raw:
            why = (
                f"from zeta_{name} = {_g(raw[f'zeta_{name}'])} at {_g(raw['reference_speed'])} m/s"
            )
        else:
            why = "given"
        lines.append(f"  C_{name}                 {_g(value)} s/m  ({why})")
    lines.append(f"  friction            {_g(c.friction)}")
    if m.tangential == "mindlin":
        why = "from E1, nu1, E2, nu2" if "E1" in raw and "G_star" not in raw else "given"
        lines.append(f"  G_star              {_g(c.G_star)} Pa  ({why}; tangential k_t = 8 G* a)")

    return lines


def _model_lines(m) -> list[str]:
    """The model switches."""
    lines = []
    lines.append("model")
    lines.append(f"  normal              {m.normal}")
    lines.append(f"  rotation            {m.rotation}")
    lines.append(f"  adhesion            {m.adhesion}")
    lines.append(f"  rolling_moments     {m.rolling_moments}")
    if m.rolling_moments == "lambda":
        lines.append(f"  lambda              {_g(m.lambda_)} N m")
    lines.append(f"  friction_load       {m.friction_load}")
    lines.append(f"  tangential          {m.tangential}")

    return lines


def _impact_lines(speed, angle, omega0, r, K, mass) -> list[str]:
    """The scene's default impact and its Hertz scales."""
    lines = []
    v_n = speed * math.cos(math.radians(angle))
    n_star = (5.0 * mass * v_n**2 / (4.0 * K * math.sqrt(r))) ** 0.4
    t_unit = n_star / v_n
    lines.append(f"impact [impact]: {_g(speed)} m/s at {_g(angle)} deg, omega0 {_g(omega0)} rad/s")
    lines.append(f"  normal speed v_n    {_g(v_n)} m/s")
    lines.append("Hertz scales of this impact (the solver's units)")
    lines.append(f"  length n*           {_g(n_star)} m  (undamped peak overlap)")
    lines.append(f"  time n*/v_n         {_g(t_unit)} s")
    lines.append(f"  contact time        {_g(HERTZ_DURATION * t_unit)} s  (undamped, no adhesion)")
    lines.append(f"  peak force          {_g(K * math.sqrt(r) * n_star**1.5)} N")
    lines.append(f"  contact radius      {_g(math.sqrt(r * n_star))} m  (at n*)")
    lines.append(f"  spin unit v_n/r     {_g(v_n / r)} rad/s")

    return lines


def _solver_lines(scene, params, speed, angle) -> list[str]:
    """The solver settings resolved for the default impact (``method = "auto"`` explained)."""
    s = scene.solver
    lines = []
    dtype = jnp.result_type(float)
    chosen = integration_settings(scene, params, np.array(speed), np.array(angle), dtype)
    stiff = float(stiffness_estimate(params, speed, angle, scene.model.damping))
    lines.append("solver")
    if s.method == "auto":
        width = default_slip_width(dtype, s.slip_width, s.rtol)
        if chosen.method == "kvaerno5" and stiff <= s.stiffness_limit:
            why = f"slip_width {width:g} is below 30 rtol: the friction switch is stiff"
        elif chosen.method == "kvaerno5":
            why = f"stiffness estimate {stiff:.3g} > stiffness_limit {s.stiffness_limit:g}"
        else:
            why = f"stiffness estimate {stiff:.3g} <= stiffness_limit {s.stiffness_limit:g}"
        lines.append(f"  method              auto -> {chosen.method}  ({why})")
    else:
        lines.append(
            f"  method              {chosen.method}  (given; stiffness estimate {stiff:.3g})"
        )
    lines.append(f"  rtol, atol          {chosen.rtol:g}, {chosen.atol:g}  ({dtype.name})")
    lines.append(f"  max_steps           {chosen.max_steps}")
    lines.append(f"  slip_width          {default_slip_width(dtype, s.slip_width, s.rtol):g}")
    lines.append(f"  outputs             {s.outputs}")

    return lines


def _terms_lines(terms, m) -> list[str]:
    """The terms the default impact compiles, and those it leaves out and why."""
    lines = []
    used, left = [], []
    damping = "Hertz damping" if not terms.lammps_damping else f"LAMMPS {m.damping} damping"
    used.append(f"normal: Hertz force, {damping}")
    strength = "f0 = 0" if m.normal == "brach_dunn" else "w = 0"
    if terms.ring:
        used.append("adhesion ring force and adhesion damping")
    elif terms.plastic:
        used.append(
            "Thornton-Ning: JKR adhesion, plastic yield at p_y, elastic unloading on a flatter "
            "JKR curve (peak overlap as a state; the snap-off and yield losses in the ledger)"
        )
    elif terms.jkr:
        end = "pull-off" if terms.jkr_release == "pull_off" else "snap-off overlap"
        used.append(f"JKR adhesion (contact until the {end}; its loss in the ledger)")
    elif terms.adhesion:
        used.append("DMT adhesion 2 pi w r (constant in contact, undamped)")
    else:
        left.append("adhesion (" + ("model.adhesion = false" if not m.adhesion else strength) + ")")
    if m.normal != "brach_dunn":
        left.append(
            f'adhesion ring, its damping and peeling moment M_A (model.normal = "{m.normal}")'
        )
    if terms.lammps_spring:
        stiffness = "k_t" if terms.spring == "lammps_linear_history" else "8 G* a"
        used.append(
            f"LAMMPS's history spring {stiffness}, capped by friction (LAMMPS's critical normal "
            "force; no normal force of the spring)"
        )
    elif terms.mindlin:
        used.append(
            f"Mindlin tangential spring 8 G* a, capped by friction ({m.friction_load} normal load)"
        )
    elif terms.tangential:
        used.append(f"friction ({m.friction_load} normal load)")
    else:
        left.append("tangential motion and friction (normal impact without spin)")
    if terms.tangential and not terms.mindlin:
        left.append('tangential compliance (model.tangential = "rigid")')
    if terms.rotation and terms.target:
        used.append("rotation of both spheres (the friction turns each at its own radius)")
    elif terms.rotation:
        used.append("rotation (spin driven by the friction moment)")
    elif terms.tangential:
        left.append("rotation (model.rotation = false)")
    if terms.has_moments:
        kind = "M_A + M_H" if terms.ring else "M_H"
        kind = kind if terms.rolling_moments == "analytical" else "constant lambda"
        used.append(f"rolling dissipation moments ({kind})")
    elif m.rolling_moments == "none":
        left.append('rolling moments (model.rolling_moments = "none")')
    elif terms.rotation:
        zero = "lambda = 0" if m.rolling_moments == "lambda" else "C_A = C_H = 0"
        left.append(f"rolling moments ({zero})")
    if terms.ledger:
        used.append("energy ledger, peak overlap, roll time")
    else:
        left.append('energy ledger, peak overlap, roll time (solver.outputs = "rebound")')
    lines.append("terms this impact compiles")
    lines += [f"  {t}" for t in used]
    lines.append("left out")
    lines += [f"  {t}" for t in left] or ["  nothing"]
    lines.append(
        "(a batch compiles the union of what its impacts need; zero values of f0 (w), lambda or "
        "C_A and C_H leave their terms out only when known before tracing)"
    )
    return lines
