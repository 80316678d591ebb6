"""``jaximpact export lammps FIT.json``: a fitted normal contact law as LAMMPS commands.

Reads a fit JSON (``jaximpact fit ... -o FIT.json``): its ``scene`` (the TOML text the fit
started from; JSON files written before it existed need ``--scene``) and its
``params[NAME].value``, puts the fitted values in the scene
(``jaximpact.parameters.with_parameters``) and writes the LAMMPS 29 Sep 2021 commands of its
normal law (``jaximpact._io.lammps``: ``fix ... wall/gran granular`` or ``pair_style
granular`` / ``pair_coeff * *``), with comments: the units, each fitted parameter's posterior
median and 90 % interval (else its value and standard error), and which jaximpact parameter
each LAMMPS number came from. Pure Python: no JAX computation.
"""

from __future__ import annotations

import argparse
import json
import math
import sys

__all__ = ["add_export_command", "cmd_export_lammps", "export_lines"]

_DESCRIPTION = """\
Write the LAMMPS (29 Sep 2021, GRANULAR package) commands of a fitted model's normal contact
law: the scene the fit ran on (recorded in FIT.json by `jaximpact fit -o`; --scene for an
older JSON) with the fitted values put in. The file is meant for `include` after the box and
the atoms exist, in an input with `units si` (every number is SI), `atom_style sphere` and
`fix nve/sphere`. Comments give each fitted parameter's posterior median and 90 % interval
(else its value and standard error) and the jaximpact parameter each LAMMPS number comes from.

Laws: the Brach-Dunn law without adhesion (hertz, or hertz/material with --material), DMT
and JKR (coh = w/2), with LAMMPS's damping models (model.damping = velocity, mass_velocity,
viscoelastic, tsuji; contact.eta_n) or none (C_H = 0). The tangential force only where the
scene has LAMMPS's own history spring (model.tangential = lammps_linear_history or
lammps_mindlin, with friction); no rolling resistance. JKR needs --geometry pair (this LAMMPS
version's JKR wall is broken).

Exit status: 0 written; 2 bad input (the file, a field, or a law LAMMPS lacks, named in one
line, with what to fit instead)."""

#: Fitted parameters the LAMMPS commands cannot carry, and why (the normal law only).
_NOT_EXPORTED = {
    "friction": "friction is tangential: LAMMPS's tangential models are not mapped yet",
    "G_star": "G_star is the Mindlin tangential spring's: LAMMPS's tangential models are not "
    "mapped yet",
    "lambda": "lambda is a rolling moment's: LAMMPS's rolling models are not mapped yet",
    "C_A": "C_A is the Brach-Dunn adhesion damping, which LAMMPS lacks",
    "C_H": "C_H is Brach-Dunn's Hertzian damping, which LAMMPS lacks",
    "f0": "f0 is the Brach-Dunn adhesion ring's, which LAMMPS lacks",
    "p_y": "p_y is Thornton-Ning's, which LAMMPS lacks",
}
_INSTEAD = (
    "fit instead K, w or eta_n of a scene LAMMPS has: model.normal = 'dmt' or 'jkr' (w) "
    "or 'brach_dunn' without adhesion (K), with model.damping = 'velocity', "
    "'mass_velocity', 'viscoelastic' or 'tsuji' (eta_n) and contact.C_H = 0"
)
_DAMPING_UNITS = {
    "velocity": "kg/s",
    "mass_velocity": "1/s (LAMMPS multiplies it by m_eff)",
    "viscoelastic": "1/(m s) (LAMMPS multiplies it by a m_eff, a = sqrt(R delta))",
    "tsuji": "a restitution (LAMMPS's alpha(e) sqrt(m_eff kn a))",
}


class ExportError(ValueError):
    """Bad input of ``jaximpact export``: the message names the file or field."""


def add_export_command(subparsers) -> argparse.ArgumentParser:
    """Add ``export`` (with its format ``lammps``) to a ``jaximpact`` argument parser's
    subparsers; returns the ``export lammps`` parser."""
    export = subparsers.add_parser(
        "export",
        help="a fitted model as another code's input (lammps)",
        description="Export a fitted model (a `jaximpact fit -o FIT.json` result) as another "
        "code's input. Formats: lammps.",
    )
    formats = export.add_subparsers(dest="format", required=True, metavar="FORMAT")
    p = formats.add_parser(
        "lammps",
        help="LAMMPS commands of the fitted normal contact law",
        description=_DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("fit_json", metavar="FIT.json", help="a `jaximpact fit -o` result")
    p.add_argument(
        "-o", "--output", metavar="OUT.in", help="write here (atomically); default: stdout"
    )
    p.add_argument(
        "--geometry",
        choices=("wall", "pair"),
        help="wall: fix wall/gran (a flat wall, zplane 0); pair: pair_style granular / "
        "pair_coeff * * (sphere-sphere); default: pair for a scene with a [target], else wall",
    )
    p.add_argument(
        "--material",
        action="store_true",
        help="hertz/material E eta nu instead of hertz kn eta (DMT and JKR always are)",
    )
    p.add_argument(
        "--poisson",
        type=float,
        default=0.3,
        metavar="NU",
        help="the Poisson ratio of the material laws (default 0.3; E is solved from K and NU, "
        "so the normal force does not depend on it)",
    )
    p.add_argument(
        "--scene",
        metavar="SCENE",
        help="the scene the fit ran on (name or TOML file), for a fit JSON that does not "
        "record it; overrides the JSON's",
    )
    p.set_defaults(func=cmd_export_lammps)
    return p


def cmd_export_lammps(args) -> int:
    """Run ``jaximpact export lammps``; 0 written. Bad input raises a ``ValueError`` naming
    the file or field (``jaximpact.cli.main``: exit 2)."""
    import jax

    # float64 before the scene holds any value: the commands carry the fitted digits
    jax.config.update("jax_enable_x64", True)
    from jaximpact._io.atomic import atomic_write_text
    from jaximpact._io.paths import prepare_output, write_failed

    if args.output is not None:
        prepare_output(args.output, "LAMMPS input")
    document = _read_fit(args.fit_json)
    scene, source = _fitted_scene(args, document)
    geometry = args.geometry or ("pair" if scene.target is not None else "wall")
    text = export_lines(
        scene, document, geometry=geometry, material=args.material, poisson=args.poisson,
        fit_name=args.fit_json, scene_source=source,
    )  # fmt: skip
    if args.output is None:
        sys.stdout.write(text)
        return 0
    try:
        atomic_write_text(args.output, text)
    except OSError as err:
        raise write_failed(args.output, err) from None
    print(f"wrote {args.output}")
    return 0


def _read_fit(path) -> dict:
    """The fit JSON, checked to have ``params`` with a finite ``value`` each."""
    from jaximpact._io.paths import check_readable
    from jaximpact.parameters import PARAMETERS

    check_readable(path, "fit JSON")
    try:
        with open(path, encoding="utf-8") as fh:
            document = json.load(fh)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ExportError(f"{path}: not valid JSON: {err}") from None
    params = document.get("params") if isinstance(document, dict) else None
    if not isinstance(params, dict) or not params:
        raise ExportError(f"{path}: no 'params' object: not a `jaximpact fit -o` result")
    for name, entry in params.items():
        if name not in PARAMETERS:
            raise ExportError(f"{path}: params.{name}: not a jaximpact scene parameter")
        value = entry.get("value") if isinstance(entry, dict) else None
        if not _finite(value):
            raise ExportError(
                f"{path}: params.{name}.value: {json.dumps(value)} is not a finite number (the "
                "fit did not give it a value)"
            )
    return document


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _fitted_scene(args, document) -> tuple:
    """``(scene with the fitted values, how the comments name its source)``."""
    import tomllib

    import jaximpact
    from jaximpact._io.scene_files import describe_scene_source, scene_from_dict
    from jaximpact.parameters import with_parameters

    path = args.fit_json
    if args.scene is not None:
        scene, source = jaximpact.load_scene(args.scene), describe_scene_source(args.scene)
    else:
        record = document.get("scene")
        if record is None:
            raise ExportError(
                f"{path}: no 'scene' (a fit JSON written before jaximpact fit recorded its "
                "scene): give the scene the fit ran on with --scene SCENE"
            )
        text = record.get("toml") if isinstance(record, dict) else None
        if not isinstance(text, str):
            raise ExportError(f"{path}: scene.toml: missing or not a text (give --scene SCENE)")
        try:
            scene = scene_from_dict(tomllib.loads(text))
        except tomllib.TOMLDecodeError as err:
            raise ExportError(f"{path}: scene.toml: not valid TOML: {err}") from None
        except ValueError as err:
            raise ExportError(f"{path}: scene.toml: {err}") from None
        name = str(record.get("source", "?"))
        source = f"embedded {name}" if record.get("embedded") else name
        source += f" (as recorded in {path})"
    values = {n: float(e["value"]) for n, e in document["params"].items()}
    spring = scene.model.tangential  # LAMMPS's own springs carry friction and their stiffness
    carried = {"lammps_linear_history": ("friction",), "lammps_mindlin": ("friction", "G_star")}
    for name in values:
        if name in _NOT_EXPORTED and name not in carried.get(spring, ()):
            raise ExportError(
                f"{path}: params.{name}: {_NOT_EXPORTED[name]}; the export writes the normal "
                f"law only: {_INSTEAD}"
            )
    try:
        return with_parameters(scene, values), source
    except ValueError as err:
        raise ExportError(f"{path}: the fitted values in the scene: {err}") from None


def _law(scene, path):
    from jaximpact._io import lammps

    try:
        return lammps.contact_law(scene)
    except ValueError as err:
        raise ExportError(f"{path}: the fitted scene: {err}; {_INSTEAD}") from None


def export_lines(
    scene, document, *, geometry="wall", material=False, poisson=0.3, fit_name="FIT.json",
    scene_source="",
) -> str:  # fmt: skip
    """The exported file's text: comments, then the LAMMPS commands of ``scene``'s normal law
    (``scene`` with the fitted values already in; ``document`` the fit JSON, for the comments).

    Raises:
        ExportError: a law or option LAMMPS cannot reproduce, named, with what to fit instead.
    """
    from jaximpact._io import lammps

    law = _law(scene, fit_name)
    if law.normal == "jkr" and geometry == "wall":
        raise ExportError(
            "--geometry wall with model.normal = 'jkr': fix wall/gran's JKR of LAMMPS "
            f"{lammps.VERSION} is broken (pull-off distance not dimensionless, NaN force past "
            "snap-off); use --geometry pair (a frozen partner sphere much larger than the "
            "particle stands in for a wall)"
        )
    if not -1.0 < poisson < 0.5:
        raise ExportError(f"--poisson must be in (-1, 0.5), got {poisson!r}")
    lines = _header(scene, document, geometry, fit_name, scene_source)
    if law.normal == "jkr" and getattr(scene.model, "jkr_release", "snap_off") == "snap_off":
        lines.append(
            "# NOTE: LAMMPS's JKR contact ends at the pull-off force minimum, jaximpact's at the"
        )
        lines.append(
            "#   snap-off overlap further out: their rebounds differ (docs/physics.md, LAMMPS)"
        )
    lines += _fitted_comments(document, scene.model.damping)
    lines += _mapping_comments(scene, law, geometry, material, poisson, set(document["params"]))
    if geometry == "wall":
        lines += lammps.wall_fix(law, material=material, poisson=poisson).splitlines()
    else:
        lines += lammps.pair_commands(law, material=material, poisson=poisson)
    return "\n".join(lines) + "\n"


def _g(x) -> str:
    return f"{x:.6g}" if _finite(x) else "undefined"


def _header(scene, document, geometry, fit_name, scene_source) -> list[str]:
    from jaximpact._io import lammps

    status = document.get("status", "unknown")
    data = document.get("data")
    data = data.get("source", "?") if isinstance(data, dict) else "?"
    where = (
        "fix wall/gran: a flat wall at z = 0 below the spheres (group all)"
        if geometry == "wall"
        else "pair_style granular / pair_coeff * *: every atom type with every other"
    )
    lines = [
        f"# jaximpact export lammps: the fitted normal contact law, LAMMPS {lammps.VERSION} "
        "(GRANULAR package)",
        f"# fit: {fit_name} (status {status}; data {data})",
        f"# scene: {scene_source}",
        "# units si: every number below is SI (m, kg, s, Pa, J/m^2); the input must say",
        "#   'units si' before the box is created; needs atom_style sphere, fix nve/sphere"
        + ("" if geometry == "wall" else " and comm_modify vel yes"),
        f"# geometry: {where}",
    ]
    if status != "converged":
        lines.append(f"# WARNING: the fit's status is {status!r}: the values may not be trusted")
        print(f"warning: {fit_name}: the fit's status is {status!r}", file=sys.stderr)
    p = scene.particle
    lines.append(
        f"# the particle: radius {_g(float(p.radius))} m, density {_g(float(p.density))} "
        f"kg/m^3 (per atom in LAMMPS: set ... diameter {_g(2 * float(p.radius))} density "
        f"{_g(float(p.density))})"
    )
    if scene.target is not None:
        t = scene.target
        lines.append(
            f"# the fit's [target] sphere: radius {_g(float(t.radius))} m, density "
            f"{_g(float(t.density))} kg/m^3"
        )
    return lines


def _fitted_comments(document, damping) -> list[str]:
    from jaximpact.parameters import PARAMETERS

    params = document["params"]
    posterior = any(isinstance(e.get("posterior"), dict) for e in params.values())
    lines = [
        "# fitted parameters: "
        + (
            "posterior median [90 % interval] (least-squares value +- standard error)"
            if posterior
            else "least-squares value +- standard error (no posterior in the fit JSON)"
        )
    ]
    for name, entry in params.items():
        unit = PARAMETERS[name].unit
        if name == "eta_n":  # its unit is the damping model's
            unit = _DAMPING_UNITS.get(damping, unit).partition(" (")[0]
        unit = "" if unit in ("1", "a restitution") else f" {unit}"
        ls = f"{_g(entry['value'])} +- {_g(entry.get('stderr'))}"
        post = entry.get("posterior")
        if isinstance(post, dict):
            q = [post.get(k) for k in ("median", "q05", "q95")]
            lines.append(f"#   {name} = {_g(q[0])} [{_g(q[1])}, {_g(q[2])}]{unit} ({ls})")
        else:
            lines.append(f"#   {name} = {ls}{unit}")
    lines.append("#   (the commands use the least-squares values)")
    return lines


def _mapping_comments(scene, law, geometry, material, poisson, fitted) -> list[str]:
    """Where each LAMMPS number comes from (``kn = K``, ``coh = w/2``, ...)."""
    from jaximpact._io import lammps

    def src(name):
        return "fitted" if name in fitted else "the scene's"

    lines = ["# LAMMPS's numbers from jaximpact's parameters:"]
    if law.normal == "hertz" and not material:
        lines.append(f"#   kn = K = {_g(law.K)} Pa ({src('K')}; F = kn sqrt(R) delta^1.5)")
    else:
        E = lammps.youngs_modulus(law.K, poisson, geometry)
        formula = "1.5 K (1 - nu)" if geometry == "wall" else "1.5 K (1 - nu^2)"
        why = (
            "fix wall/gran's kn = 4/3 E / (2 (1 - nu))"
            if geometry == "wall"
            else "pair_coeff * *'s kn = 4/3 E / (2 (1 - nu^2))"
        )
        lines.append(f"#   E = {formula} = {_g(E)} Pa with K = {_g(law.K)} Pa ({src('K')}; {why})")
        lines.append(
            f"#   nu = {_g(poisson)} (--poisson; E is solved for it, the normal force does not "
            "depend on it)"
        )
    if law.normal != "hertz":
        lines.append(f"#   coh = w/2 = {_g(law.w / 2)} J/m^2 with w = {_g(law.w)} ({src('w')})")
    if law.damping == "none":
        lines.append("#   damping velocity with coefficient 0: undamped (the scene's C_H = 0)")
    else:
        lines.append(
            f"#   damping {law.damping} coefficient = eta_n = {_g(law.eta_n)} "
            f"{_DAMPING_UNITS[law.damping]} ({src('eta_n')})"
        )
    m, c = scene.model, scene.contact
    if m.tangential.startswith("lammps_"):  # (the tangential words: the renderer's line)
        fitted = [n for n in ("friction", "G_star", "k_t") if src(n) == "fitted"]
        lines.append(f"#   tangential spring's fitted parameters: {', '.join(fitted) or 'none'}")
    else:
        lines.append(
            f"# not exported: the tangential model ({m.tangential}, friction "
            f"{_g(float(c.friction))}): LAMMPS has no rigid Coulomb law or jaximpact's own "
            "spring; use model.tangential = 'lammps_linear_history' or 'lammps_mindlin'"
        )
    if m.rolling_moments != "none":
        lines.append(
            f"# not exported: the rolling moments ({m.rolling_moments}): LAMMPS's rolling "
            "models are not mapped yet"
        )
    return lines
