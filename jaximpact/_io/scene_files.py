"""Reading scene files (TOML) into a ``Scene``, with every value validated by name."""

import math
import tomllib
from importlib import resources
from pathlib import Path

from .._model.ranges import RANGES, range_text
from .._model.scene import (
    Contact,
    Impact,
    Model,
    Particle,
    Scene,
    SceneError,
    Solver,
    Target,
    check_input,
    damping_from_zeta,
    hertz_stiffness,
    shear_modulus_star,
)

ALLOWED = {
    "particle": {"radius", "density"},
    "contact": {
        "K",
        "E1",
        "nu1",
        "E2",
        "nu2",
        "f0",
        "C_A",
        "C_H",
        "zeta_A",
        "zeta_H",
        "reference_speed",
        "friction",
        "G_star",
        "w",
        "p_y",
        "eta_n",
        "k_t",
    },
    "model": {
        "rotation",
        "adhesion",
        "rolling_moments",
        "lambda",
        "friction_load",
        "tangential",
        "normal",
        "damping",
        "jkr_release",
    },
    "impact": {"speed", "angle_deg", "omega0"},
    "target": {"radius", "density", "omega0"},
    "solver": {
        "outputs",
        "method",
        "rtol",
        "atol",
        "dt",
        "slip_width",
        "ring_width",
        "max_steps",
        "stiffness_limit",
    },
}
# [priors]: a Bayesian prior per parameter that `fitting` may sample (`fitting.sample_posterior`,
# `jaximpact fit --posterior`), as text "loguniform:LO:HI" or "normal:MU:SD" (SI units); the
# simulator ignores them. The spec itself is checked by `fitting` (it names the scene key).
PRIOR_NAMES = {
    "C_A", "C_H", "f0", "friction", "K", "G_star", "w", "p_y", "eta_n", "k_t", "lambda",
    "radius", "density",
}  # fmt: skip
ALLOWED["priors"] = PRIOR_NAMES
REQUIRED_SECTIONS = ("particle", "contact")


def embedded_scenes() -> dict[str, str]:
    """The scenes shipped with jaximpact: ``{name: first line of the file's description}``."""
    folder = resources.files("jaximpact") / "scenes"
    out = {}
    for entry in sorted(folder.iterdir(), key=lambda e: e.name):
        if entry.name.endswith(".toml"):
            first = entry.read_text(encoding="utf-8").splitlines()[0]
            out[entry.name[: -len(".toml")]] = first.lstrip("#").strip()
    return out


def default_scene_path() -> Path:
    """Path of the embedded default scene (the paper's Table 1)."""
    return scene_path("table1")


def scene_path(scene=None) -> Path:
    """The file of a scene given by embedded name or path (``None``: the default, Table 1).

    A bare word that names an embedded scene (``table1``, ``kharaz2001``; see
    :func:`embedded_scenes`) is that scene; anything else is a path.
    """
    if scene is None:
        scene = "table1"
    text = str(scene)
    if isinstance(scene, str) and text in embedded_scenes():
        return Path(str(resources.files("jaximpact") / "scenes" / f"{text}.toml"))
    return Path(scene)


def describe_scene_source(scene=None) -> str:
    """How a report names the scene: ``embedded NAME (description)`` or the path."""
    name = "table1" if scene is None else str(scene)
    known = embedded_scenes()
    if isinstance(scene, (str, type(None))) and name in known:
        return f"embedded {name} ({known[name]})"
    return str(scene)


def load_scene(path=None) -> Scene:
    """Read a scene: an embedded name (``table1``, ``kharaz2001``) or a TOML file path;
    without one, the embedded Table 1 scene.

    **Raises:** `SceneError` naming the file and the section.key for unknown keys, missing
    values, wrong types and out-of-range values, and for a file that does not exist (with the
    embedded names, in case a name was meant).
    """
    path = scene_path(path)
    try:
        with open(path, "rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError:
        names = ", ".join(embedded_scenes())
        raise SceneError(
            f"{path}: scene file not found (embedded scenes, by name: {names})"
        ) from None
    except IsADirectoryError:
        raise SceneError(f"{path}: is a directory, not a scene file") from None
    except PermissionError:
        raise SceneError(f"{path}: permission denied") from None
    except UnicodeDecodeError as err:
        raise SceneError(f"{path}: not valid TOML: {err}") from None
    except tomllib.TOMLDecodeError as err:
        raise SceneError(f"{path}: not valid TOML: {err}") from None
    try:
        return scene_from_dict(data)
    except SceneError as err:
        raise SceneError(f"{path}: {err}") from None


def scene_from_dict(data: dict) -> Scene:
    """Build a ``Scene`` from the nested dict of a scene file (same rules as `load_scene`)."""
    _check_sections(data)
    number = _numbers(data)
    particle = Particle(radius=number("particle", "radius"), density=number("particle", "density"))
    contact, f0, G_star = _contact(data, particle)
    model = _model(data, contact, G_star)
    impact = Impact(
        speed=number("impact", "speed", 1.0),
        angle_deg=number("impact", "angle_deg", 0.0),
        omega0=number("impact", "omega0", 0.0),
    )
    target = None
    if "target" in data:
        target = Target(
            radius=number("target", "radius"),
            density=number("target", "density"),
            omega0=number("target", "omega0", 0.0),
        )
    return Scene(
        particle=particle,
        contact=contact,
        model=model,
        impact=impact,
        solver=_solver(data),
        priors=_priors(data),
        target=target,
    )


def _check_sections(data: dict) -> None:
    """Only known sections and keys, and the required sections."""
    unknown = set(data) - set(ALLOWED)
    if unknown:
        raise SceneError(f"unknown section(s) {sorted(unknown)}; allowed: {sorted(ALLOWED)}")
    for section, table in data.items():
        if not isinstance(table, dict):
            raise SceneError(f"[{section}] must be a table")
        bad = set(table) - ALLOWED[section]
        if bad:
            raise SceneError(
                f"unknown key(s) {', '.join(f'{section}.{k}' for k in sorted(bad))}"
                f"; allowed in [{section}]: {', '.join(sorted(ALLOWED[section]))}"
            )
    for section in REQUIRED_SECTIONS:
        if section not in data:
            raise SceneError(f"missing section [{section}]")


def _numbers(data: dict):
    """``number(section, key, default=None)``: a finite number of ``data`` (or the default)."""

    def number(section, key, default=None):
        value = data.get(section, {}).get(key, default)
        if value is None:
            raise SceneError(f"missing {section}.{key}")
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SceneError(f"{section}.{key} must be a number, got {value!r}")
        if not math.isfinite(value):
            field = f"{section}.{key}"
            rule = range_text(key, field) if key in RANGES else f"{field} must be finite"
            raise SceneError(f"{rule}, got {value!r}")
        return float(value)

    return number


def _contact(data: dict, particle: Particle) -> tuple:
    """The ``[contact]`` section (K or the elastic moduli, damping or zeta, f0, friction, G*),
    with its f0 and G* as numbers."""
    number = _numbers(data)

    def has(section, key):
        return key in data.get(section, {})

    c = data["contact"]
    elastic = [k for k in ("E1", "nu1", "E2", "nu2") if k in c]
    if has("contact", "K") and elastic:
        raise SceneError("give either contact.K or contact.E1, nu1, E2, nu2, not both")
    if has("contact", "K"):
        K = number("contact", "K")
    elif elastic:
        K = hertz_stiffness(*(number("contact", k) for k in ("E1", "nu1", "E2", "nu2")))
    else:
        raise SceneError("missing contact.K (or contact.E1, nu1, E2, nu2)")
    check_input("contact.K", "K", K)
    damping = {}
    for name in ("A", "H"):
        if has("contact", f"C_{name}") and has("contact", f"zeta_{name}"):
            raise SceneError(f"give either contact.C_{name} or contact.zeta_{name}, not both")
        if has("contact", f"zeta_{name}"):
            zeta = number("contact", f"zeta_{name}")
            check_input(f"contact.zeta_{name}", "zeta", zeta)
            v = number("contact", "reference_speed")
            check_input("contact.reference_speed", "reference_speed", v)
            damping[name] = damping_from_zeta(
                zeta, particle.radius.item(), particle.density.item(), K, v
            )
        else:
            damping[name] = number("contact", f"C_{name}", 0.0)
    if has("contact", "reference_speed") and not any(
        has("contact", k) for k in ("zeta_A", "zeta_H")
    ):
        raise SceneError("contact.reference_speed is only used with zeta_A / zeta_H")
    f0 = number("contact", "f0", 0.0)
    if has("contact", "G_star"):
        G_star = number("contact", "G_star")
        if not G_star > 0:
            raise SceneError(f"contact.G_star must be > 0 (Pa), got {G_star!r}")
        check_input("contact.G_star", "G_star", G_star)
    elif elastic:  # from the same moduli as K
        G_star = shear_modulus_star(*(number("contact", k) for k in ("E1", "nu1", "E2", "nu2")))
    else:
        G_star = 0.0  # not given: only model.tangential = "mindlin" needs it
    contact = Contact(
        K=K,
        f0=f0,
        C_A=damping["A"],
        C_H=damping["H"],
        friction=number("contact", "friction", 0.0),
        G_star=G_star,
        w=number("contact", "w", 0.0),
        p_y=number("contact", "p_y", 0.0),
        eta_n=number("contact", "eta_n", 0.0),
        k_t=number("contact", "k_t", 0.0),
    )
    return contact, f0, G_star


def _model(data: dict, contact: Contact, G_star: float) -> Model:
    """The ``[model]`` switches, checked against the contact parameters they need."""
    number = _numbers(data)
    m = data.get("model", {})
    c = data["contact"]
    for key in ("rotation", "adhesion"):
        if key in m and not isinstance(m[key], bool):
            raise SceneError(f"model.{key} must be true or false, got {m[key]!r}")
    keys = ("rolling_moments", "friction_load", "tangential", "normal", "damping", "jkr_release")
    for key in keys:
        if key in m and not isinstance(m[key], str):
            raise SceneError(f"model.{key} must be a string, got {m[key]!r}")
    normal = m.get("normal", "brach_dunn")
    if normal != "brach_dunn" and "f0" in c:
        raise SceneError(
            f'contact.f0 is the adhesion ring of model.normal = "brach_dunn"; the {normal} law '
            "takes the work of adhesion contact.w (J/m^2)"
        )
    if normal == "brach_dunn" and "w" in c:
        raise SceneError(
            'contact.w (work of adhesion) is used only with model.normal = "dmt", "jkr" or '
            '"thornton_ning"'
        )
    if normal != "thornton_ning" and "p_y" in c:
        raise SceneError(
            "contact.p_y (limiting contact pressure) is used only with model.normal = "
            '"thornton_ning"'
        )
    damping = m.get("damping", "hertzian")
    if damping == "hertzian" and "eta_n" in c:
        raise SceneError(
            "contact.eta_n is the coefficient of a LAMMPS normal damping: give model.damping "
            '("velocity", "mass_velocity", "viscoelastic" or "tsuji")'
        )
    if damping != "hertzian" and "eta_n" not in c:
        raise SceneError(f'model.damping = "{damping}" needs contact.eta_n')
    strength = contact.f0 if normal == "brach_dunn" else contact.w
    if normal == "thornton_ning" and "adhesion" not in m and not strength > 0:
        raise SceneError(
            f'contact.w must be > 0 with model.normal = "thornton_ning", got {contact.w:g} '
            "(J/m^2): its law is JKR's with yield; for the adhesion-free limit take a small w "
            "(e.g. 1e-6)"
        )
    model = Model(
        rotation=m.get("rotation", True),
        adhesion=m.get("adhesion", bool(strength > 0)),
        rolling_moments=m.get("rolling_moments", "analytical"),
        friction_load=m.get("friction_load", "net"),
        lambda_=number("model", "lambda", 0.0),
        tangential=m.get("tangential", "rigid"),
        normal=normal,
        damping=damping,
        jkr_release=m.get("jkr_release", "snap_off"),
    )
    if model.tangential in ("mindlin", "lammps_mindlin") and not G_star > 0:
        raise SceneError(
            f'model.tangential = "{model.tangential}" needs contact.G_star (Pa, > 0) or '
            "contact.E1, nu1, E2, nu2"
        )
    if model.rolling_moments == "lambda" and "lambda" not in m:
        raise SceneError('model.rolling_moments = "lambda" needs model.lambda (N m)')
    return model


def _solver(data: dict) -> Solver:
    """The ``[solver]`` settings."""
    number = _numbers(data)
    s = data.get("solver", {})
    if "max_steps" in s and (
        isinstance(s["max_steps"], bool) or not isinstance(s["max_steps"], int)
    ):
        raise SceneError(f"solver.max_steps must be an integer, got {s['max_steps']!r}")
    if "method" in s and not isinstance(s["method"], str):
        raise SceneError(f"solver.method must be a string, got {s['method']!r}")
    if "outputs" in s and not isinstance(s["outputs"], str):
        raise SceneError(f"solver.outputs must be a string, got {s['outputs']!r}")
    text_keys = ("method", "max_steps", "outputs")
    solver_kwargs = {k: (v if k in text_keys else number("solver", k)) for k, v in s.items()}
    solver = Solver(**solver_kwargs)
    return solver


def _priors(data: dict) -> tuple:
    """The ``[priors]`` of a fit: ``(name, spec)`` pairs, sorted by name."""
    priors = []
    for name, spec in sorted(data.get("priors", {}).items()):
        if not isinstance(spec, str):
            raise SceneError(
                f'priors.{name} must be a string like "loguniform:LO:HI" or "normal:MU:SD", '
                f"got {spec!r}"
            )
        priors.append((name, spec))
    return tuple(priors)
