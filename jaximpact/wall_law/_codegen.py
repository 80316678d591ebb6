"""Generated code: the dependency-free C99 header, an OpenFOAM patch interaction model and a
Fluent ``DEFINE_DPM_BC`` UDF, each applying a :class:`WallLaw`."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from ._law import KINK_MIN_DEG, KINKS, WallLaw

__all__ = ["c_header", "write_code"]

HEADER_NAME = "jaximpact_wall_law.h"
OPENFOAM_FILES = (
    "JaximpactWallLaw.H",
    "JaximpactWallLaw.C",
    "makeJaximpactWallLawKinematic.C",
    "makeJaximpactWallLawColliding.C",
    "makeJaximpactWallLawMPPIC.C",
    "makeJaximpactWallLawThermo.C",
    "makeJaximpactWallLawReacting.C",
    "makeJaximpactWallLawReactingMultiphase.C",
    "Make/files",
    "Make/options",
    "cloudProperties.jaximpact",
)
FLUENT_FILES = ("jaximpact_dpm_bc.c",)


def _template(name: str) -> str:
    return (resources.files("jaximpact.wall_law") / "templates" / name).read_text()


def _fill(text: str, values: dict) -> str:
    for key, value in values.items():
        text = text.replace(f"@{key}@", value)
    return text


def _array(name: str, values, per_line: int = 4) -> str:
    flat = np.asarray(values, dtype=float).ravel()
    if not np.all(np.isfinite(flat)):
        raise ValueError(f"wall law table {name} has non-finite values")
    items = [repr(float(v)) for v in flat]
    lines = [
        "    " + ", ".join(items[i : i + per_line]) + "," for i in range(0, len(items), per_line)
    ]
    return f"static const double {name}[{flat.size}] = {{\n" + "\n".join(lines) + "\n};\n"


def _version() -> str:
    from .. import __version__

    return __version__


def c_header(law: WallLaw, scene_name: str = "") -> str:
    """The text of ``jaximpact_wall_law.h`` for ``law``."""
    parts = [
        _header_comment(law, scene_name),
        _header_macros(law),
        *_header_tables(law),
        "\n" + _template("wall_law_functions.h.in"),
        "\n#endif /* JAXIMPACT_WALL_LAW_H */\n",
    ]
    return "".join(parts)


def _header_comment(law: WallLaw, scene_name: str) -> str:
    """The header's opening comment: what the table is, its axes and interpolation, the
    scene."""
    R, U, W, X = law.shape
    A = law.angle_deg.size
    capture = law.speed_axis == "capture_ratio"
    g_note = (
        "\n   Capture speed: g = (v_c cos(angle))^(-1/4) is interpolated, v_c = g^-4 / cos(angle);"
        "\n   g = 0 on radii where the sphere sticks at every speed (captured whatever the speed)."
        if capture
        else ""
    )
    scene_lines = "\n".join(f"     {k} = {v}" for k, v in law.scene.items())
    axis = (
        "speed / capture speed of the (radius, angle, spin); below 1 the sphere sticks"
        if capture
        else "speed in m/s (the scene has no adhesion: nothing sticks)"
    )
    aligned_note = (
        f"; the results on {U} nodes of the kink-aligned angle coordinate\n   (piecewise "
        "linear in the angle between 0, the kink angles (radius, spin, speed) and the\n   "
        "top angle: below the first the sphere still rolls when it leaves, below the\n   "
        "second, theta*, it reaches rolling) instead of the angles"
        if law.aligned
        else ""
    )
    return f"""/* {HEADER_NAME}: a wall law tabulated by jaximpact {_version()} (Brach-Dunn-Cheng
   impact model) from the scene {scene_name or "(given in Python)"}. Generated: do not edit.

   Dependency-free C99 (only <math.h>; link with -lm). One function, jaximpact_wall_law(),
   maps an impact (sphere radius, normal and tangential speed, spin) to captured or the
   rebound velocities and spin, by multilinear interpolation of the table below; and
   jaximpact_capture_speed() gives the interpolated capture speed.

   Table: {R} radius x {A} angle x {W} spin x {X} speed nodes{aligned_note}.
   Speed axis: {axis}.
   Interpolation: log(radius), angle (deg), spin (rad/s) linear; speed in
   u = {"asinh(sqrt(x - 1))" if capture else "x^0.2"}; outside the table the nearest edge (flagged
   JAXIMPACT_WL_CLAMPED), and above a row's valid top (the speed range, or a speed at which
   the sphere sticks again) that row's last results, also flagged JAXIMPACT_WL_CLAMPED; so is
   a radius in one of the JAXIMPACT_WL_NUNRES intervals the build could not resolve to its
   tolerances (next to the radius below which the sphere sticks at every speed).{g_note}
   Tangential speeds of either sign: the table is mirrored.

   Scene:
{scene_lines}
*/

"""


def _header_macros(law: WallLaw) -> str:
    """The include guard, the result codes and the table's sizes and switches as macros."""
    R, U, W, X = law.shape
    A = law.angle_deg.size
    capture = law.speed_axis == "capture_ratio"
    return f"""#ifndef JAXIMPACT_WALL_LAW_H
#define JAXIMPACT_WALL_LAW_H

#include <math.h>

#define JAXIMPACT_WL_REBOUND 0
#define JAXIMPACT_WL_CAPTURED 1
#define JAXIMPACT_WL_CLAMPED 2
#define JAXIMPACT_WL_INVALID 4

#define JAXIMPACT_WL_NR {R}
#define JAXIMPACT_WL_NA {A}
#define JAXIMPACT_WL_NW {W}
#define JAXIMPACT_WL_NX {X}
/* 1: the results are on the kink-aligned angle coordinate (JAXIMPACT_WL_NU nodes) */
#define JAXIMPACT_WL_ALIGNED {1 if law.aligned else 0}
#define JAXIMPACT_WL_NU {U}
/* number of kinks of the aligned coordinate (jaximpact.wall_law._law.KINKS) */
#define JAXIMPACT_WL_NK {len(KINKS)}
#define JAXIMPACT_WL_KINK_MIN_DEG {KINK_MIN_DEG!r}
/* radius intervals not resolved to the build's tolerances (flagged as clamped) */
#define JAXIMPACT_WL_NUNRES {law.unresolved_radii.shape[0]}
/* 1: the speed axis is the speed over the capture speed; 0: the speed in m/s */
#define JAXIMPACT_WL_CAPTURE_RATIO {1 if capture else 0}
/* the sphere's density the table was made for, kg/m^3 */
#define JAXIMPACT_WL_DENSITY {float(law.scene["particle.density"])!r}

"""


def _header_tables(law: WallLaw) -> list:
    """The table's axes, reference speeds, kink angles, row tops and results as C arrays,
    each under a comment that names it."""
    capture = law.speed_axis == "capture_ratio"
    reference = law.reference_table
    axis2 = "aligned angle coordinate" if law.aligned else "angle"
    return [
        "/* log(radius / m) */\n" + _array("jaximpact_wl_log_radius", np.log(law.radius)),
        "/* incidence angle from the normal, deg */\n"
        + _array("jaximpact_wl_angle_deg", law.angle_deg),
        "/* spin, rad/s */\n" + _array("jaximpact_wl_omega0", law.omega0),
        "/* the unresolved radius intervals, m: lo, hi pairs (a placeholder where none) */\n"
        + _array(
            "jaximpact_wl_unresolved_radii",
            law.unresolved_radii if law.unresolved_radii.size else [0.0, 0.0],
        ),
        "/* interpolation coordinate u of the speed nodes */\n"
        + _array("jaximpact_wl_u", law.u_of(law.speed_ratio)),
        (
            "/* g = (v_c cos(angle))^(-1/4), (m/s)^(-1/4); 0: sticks at every speed "
            "[radius][angle][spin] */\n"
            if capture
            else "/* reference speed (1 m/s) [radius][angle][spin] */\n"
        )
        + _array("jaximpact_wl_reference", reference),
        (
            "/* nodes of the kink-aligned angle coordinate */\n"
            + _array("jaximpact_wl_kink_u", law.kink_u)
            + f"/* kink angles ({', '.join(KINKS)}), deg [kink][radius][spin][speed] */\n"
            + _array("jaximpact_wl_kink_angles", law.kink_angles)
            if law.aligned
            else ""
        ),
        f"/* u of each row's valid top speed [radius][{axis2}][spin] */\n"
        + _array("jaximpact_wl_u_top", law.u_top),
        "/* 1: the row sticks again above its top; 0: its top is the speed range's */\n"
        + _array("jaximpact_wl_captured_above_top", law.captured_above_top),
        f"/* vn_out / vn [radius][{axis2}][spin][speed] */\n"
        + _array("jaximpact_wl_cor_n", law.cor_n),
        "/* vt_out / speed */\n" + _array("jaximpact_wl_vt_ratio", law.vt_ratio),
        "/* omega_out radius / speed */\n" + _array("jaximpact_wl_spin_ratio", law.spin_ratio),
    ]


def write_code(law: WallLaw, directory, scene_name: str = "", write=None) -> list[Path]:
    """Write the header, ``openfoam/`` and ``fluent/`` into ``directory``; ``write(path,
    text)`` writes one file (default: atomically). Returns the paths written."""
    from .._io.paths import atomic_output

    def default_write(path: Path, text: str) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(path, "generated file") as temp:
            Path(temp).write_text(text)

    write = write or default_write
    directory = Path(directory)
    header = c_header(law, scene_name)
    values = {"VERSION": _version(), "SCENE": scene_name or "(given in Python)"}
    written = []
    for path, text in [(directory / HEADER_NAME, header)]:
        write(path, text)
        written.append(path)
    for name in OPENFOAM_FILES:
        path = directory / "openfoam" / name
        write(path, _fill(_template(f"openfoam/{name}"), values))
        written.append(path)
    write(directory / "openfoam" / HEADER_NAME, header)
    written.append(directory / "openfoam" / HEADER_NAME)
    for name in FLUENT_FILES:
        path = directory / "fluent" / name
        write(path, _fill(_template(f"fluent/{name}"), values))
        written.append(path)
    write(directory / "fluent" / HEADER_NAME, header)
    written.append(directory / "fluent" / HEADER_NAME)
    return written
