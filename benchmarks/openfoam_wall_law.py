"""Build the generated OpenFOAM patch interaction model with wmake and run it on a small
lagrangian case: particles hit a wall at known speeds and angles, and their velocities after
the impact are compared with the wall law (the table's interpolation, which the generated C
function implements) and with ``jaximpact.simulate``.

Needs OpenFOAM v1912 as Debian packages it (``apt-get install openfoam``: the solver
``icoUncoupledKinematicParcelFoam``, ``blockMesh`` and the libraries) and, to compile
against them, the matching source tree (headers and wmake), which the package does not
install: ``--openfoam-src DIR``, ``$OPENFOAM_SRC``, or it is fetched with ``apt-get source
openfoam`` (a ``deb-src`` line for Debian main is needed) into ``~/.cache/jaximpact``.

Run: ``python benchmarks/openfoam_wall_law.py [--scene table1] [--work DIR]``; 1-3 minutes
on 2 cores (77 s idle on 2026-11-28: a table over 32-40 um, the kink-aligned layout, 42 s,
wmake of the six cloud registrations 29 s, the cases seconds; the first run also builds
wmake's tools and links the source's headers, seconds). 80 particles of four radii (32.5,
35.7 and 39.2 um inside the table's range, 50 um above it) at 5 speeds and 4 angles hit the
floor. Exit status 0 when wmake printed no warning, every particle's velocity matches the
wall law to 1e-9 of its speed and its outcome (stuck or rebound) is the table's, the model
counted every impact outside the table on the floor patch, and a second run with
``onClamped rebound`` gives those the fallback coefficients; 1 otherwise; 2 when OpenFOAM or
its source is missing.

Duration: 1-3 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

LN_INCLUDE = (
    "OpenFOAM",
    "OSspecific/POSIX",
    "finiteVolume",
    "meshTools",
    "lagrangian/basic",
    "lagrangian/intermediate",
    "lagrangian/distributionModels",
    "regionModels/regionModel",
    "regionModels/surfaceFilmModels",
    "transportModels/compressible",
    "thermophysicalModels/basic",
    "thermophysicalModels/specie",
    "thermophysicalModels/thermophysicalProperties",
    "thermophysicalModels/SLGThermo",
    "thermophysicalModels/reactionThermo",
    "thermophysicalModels/radiation",
    "dynamicFvMesh",
    "dynamicMesh",
    "fileFormats",
    "surfMesh",
)

#: impacts (speed m/s, angle deg from the normal), each a particle per size; azimuth of its
#: tangent
SPEEDS = (0.05, 0.12, 0.3, 1.0, 3.0)
ANGLES = (0.0, 20.0, 45.0, 70.0)
#: The table's radius range (m; Table 1's sphere is 35 um) and the particles' radii: three
#: inside it, between its nodes, and one above it (clamped to the table's edge: counted on
#: the patch it hits)
RADIUS_RANGE = (32e-6, 40e-6)
RADII = (32.5e-6, 35.7e-6, 39.2e-6, 50e-6)
#: The generated model's default restitution of onClamped rebound (cloudProperties.jaximpact)
FALLBACK_EN, FALLBACK_ET = 0.5, 1.0
T_HIT = 4e-3  # s: every particle reaches the wall then
T_END = 6e-3  # s


def log(message: str) -> None:
    print(message, flush=True)


def find_source(arg: str | None) -> Path:
    """The OpenFOAM v1912 source tree (headers, wmake)."""
    for candidate in (arg, os.environ.get("OPENFOAM_SRC")):
        if candidate:
            path = Path(candidate)
            if (path / "etc" / "bashrc").exists():
                return path
            raise SystemExit(f"error: {path}: not an OpenFOAM source tree (no etc/bashrc)")
    cache = Path.home() / ".cache" / "jaximpact" / "openfoam-src"
    found = sorted(cache.glob("openfoam-OpenFOAM-v1912*"))
    if found:
        return found[-1]
    log(f"fetching the OpenFOAM source with apt-get source openfoam into {cache}")
    cache.mkdir(parents=True, exist_ok=True)
    run = subprocess.run(
        ["apt-get", "source", "--download-only", "openfoam"],
        cwd=cache,
        capture_output=True,
        text=True,
    )
    tarballs = sorted(cache.glob("openfoam_*.orig.tar.*"))
    if run.returncode or not tarballs:
        print(
            "error: the OpenFOAM source is needed to compile against Debian's OpenFOAM: add a "
            "deb-src line for Debian main (e.g. /etc/apt/sources.list.d/debian-src.sources: "
            "Types: deb-src, URIs: http://deb.debian.org/debian, Suites: bookworm, Components: "
            "main), apt-get update, or pass --openfoam-src DIR",
            file=sys.stderr,
        )
        raise SystemExit(2)
    subprocess.run(["tar", "xf", tarballs[-1].name], cwd=cache, check=True)
    return sorted(cache.glob("openfoam-OpenFOAM-v1912*"))[-1]


def foam(src: Path, command: str, cwd: Path, env_extra: dict | None = None, check=True):
    """``command`` in bash with the source tree's OpenFOAM environment."""
    # the extra variables after the OpenFOAM environment, which would overwrite them
    exports = "".join(f"export {k}={shlex.quote(v)}; " for k, v in (env_extra or {}).items())
    script = f". {src}/etc/bashrc >/dev/null 2>&1; {exports}{command}"
    out = subprocess.run(["bash", "-c", script], cwd=cwd, capture_output=True, text=True)
    if check and out.returncode:
        sys.stderr.write(out.stdout[-4000:] + out.stderr[-4000:])
        raise SystemExit(f"error: `{command}` failed in {cwd} (exit {out.returncode})")
    return out


def prepare_source(src: Path) -> None:
    tools = list((src / "platforms" / "tools").glob("*/wmkdepend"))
    if not tools:
        log("building wmake's tools")
        foam(src, "cd wmake/src && ./Allmake", src)
    missing = [d for d in LN_INCLUDE if not (src / "src" / d / "lnInclude").is_dir()]
    if missing:
        log(f"linking the headers of {len(missing)} source directories (lnInclude)")
        foam(src, "cd src && " + " && ".join(f"wmakeLnInclude -u {d}" for d in missing), src)


HEADER = """FoamFile
{{
    version     2.0;
    format      ascii;
    class       {cls};
    object      {obj};
}}
"""


def write(path: Path, cls: str, obj: str, body: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(HEADER.format(cls=cls, obj=obj) + body)


def impacts():
    """Particles: (speed, angle, azimuth, start position, velocity, hit point, diameter)."""
    out = []
    i = 0
    for radius in RADII:
        for speed in SPEEDS:
            for angle in ANGLES:
                th, phi = math.radians(angle), math.radians(37.0 * i)
                vn, vt = speed * math.cos(th), speed * math.sin(th)
                t_dir = (math.cos(phi), 0.0, math.sin(phi))
                u = (vt * t_dir[0], -vn, vt * t_dir[2])
                hit = (0.01 + 0.02 * (i % 9), 0.0, 0.01 + 0.02 * (i // 9))
                start = tuple(h - c * T_HIT for h, c in zip(hit, u, strict=True))
                # the diameter tags the particle (written with 17 digits)
                d = 2 * radius * (1.0 + i * 1e-10)
                out.append(dict(speed=speed, angle=angle, t_dir=t_dir, u=u, start=start, d=d))
                i += 1
    return out


def write_case(case: Path, lib: Path, particles, on_clamped: str = "clamp") -> None:
    write(
        case / "system" / "blockMeshDict",
        "dictionary",
        "blockMeshDict",
        """
scale 1;
vertices ((0 0 0) (0.2 0 0) (0.2 0.02 0) (0 0.02 0) (0 0 0.2) (0.2 0 0.2) (0.2 0.02 0.2)
          (0 0.02 0.2));
blocks (hex (0 1 2 3 4 5 6 7) (10 2 10) simpleGrading (1 1 1));
boundary
(
    floor { type wall; faces ((0 4 5 1)); }
    others { type wall; faces ((3 2 6 7) (0 3 7 4) (1 5 6 2) (0 1 2 3) (4 7 6 5)); }
);
""",
    )
    write(
        case / "system" / "controlDict",
        "dictionary",
        "controlDict",
        f"""
application icoUncoupledKinematicParcelFoam;
libs ("{lib}");
startFrom startTime; startTime 0; stopAt endTime; endTime {T_END};
deltaT 1e-4; writeControl runTime; writeInterval {T_END};
purgeWrite 0; writeFormat ascii; writePrecision 17; writeCompression off;
timeFormat general; timePrecision 6; runTimeModifiable no;
""",
    )
    write(
        case / "system" / "fvSchemes",
        "dictionary",
        "fvSchemes",
        """
ddtSchemes { default none; } gradSchemes { default none; } divSchemes { default none; }
laplacianSchemes { default none; } interpolationSchemes { default linear; }
""",
    )
    write(case / "system" / "fvSolution", "dictionary", "fvSolution", "\nsolvers {}\n")
    write(
        case / "constant" / "transportProperties",
        "dictionary",
        "transportProperties",
        "\nrhoInf 1.2;\ntransportModel Newtonian;\nnu 1e-05;\n",
    )
    write(
        case / "constant" / "turbulenceProperties",
        "dictionary",
        "turbulenceProperties",
        "\nsimulationType laminar;\n",
    )
    write(
        case / "constant" / "g",
        "uniformDimensionedVectorField",
        "g",
        "\ndimensions [0 1 -2 0 0 0 0];\nvalue (0 0 0);\n",
    )
    write(
        case / "0" / "U",
        "volVectorField",
        "U",
        """
dimensions [0 1 -1 0 0 0 0];
internalField uniform (0 0 0);
boundaryField { floor { type noSlip; } others { type noSlip; } }
""",
    )
    models = []
    for i, p in enumerate(particles):
        name = f"positions{i}"
        write(
            case / "constant" / name,
            "vectorField",
            name,
            f"\n(\n({p['start'][0]:.17g} {p['start'][1]:.17g} {p['start'][2]:.17g})\n)\n",
        )
        models.append(
            f"""        model{i}
        {{
            type manualInjection; massTotal 0; parcelBasisType fixed; nParticle 1; SOI 0;
            positionsFile "{name}";
            U0 ({p["u"][0]:.17g} {p["u"][1]:.17g} {p["u"][2]:.17g});
            sizeDistribution
            {{ type fixedValue; fixedValueDistribution {{ value {p["d"]:.17g}; }} }}
        }}"""
        )
    entry = (lib.parent.parent / "law" / "openfoam" / "cloudProperties.jaximpact").read_text()
    entry = "\n".join(line for line in entry.splitlines() if not line.startswith("//"))
    entry = re.sub(r"onClamped\s+clamp;", f"onClamped {on_clamped};", entry)
    write(
        case / "constant" / "kinematicCloudProperties",
        "dictionary",
        "kinematicCloudProperties",
        f"""
solution
{{
    active true; coupled false; transient yes; cellValueSourceCorrection off; maxCo 0.3;
    interpolationSchemes {{ rho cell; U cellPoint; mu cell; }}
    integrationSchemes {{ U Euler; }}
}}
constantProperties {{ rho0 8000; youngsModulus 2e11; poissonsRatio 0.3; }}
subModels
{{
    particleForces {{}}
    injectionModels
    {{
{chr(10).join(models)}
    }}
    dispersionModel none;
{entry}
    surfaceFilmModel none;
    stochasticCollisionModel none;
    collisionModel none;
}}
cloudFunctions {{}}
""",
    )


def run_case(src: Path, case: Path, lib: Path, particles, on_clamped: str = "clamp"):
    """Write and run the case: ``(U, order, solver output)``: the particles' velocities at the
    end and, for each, its index in ``particles`` (``U`` None if some are missing)."""
    if case.exists():
        shutil.rmtree(case)
    write_case(case, lib, particles, on_clamped)
    foam(src, "blockMesh", case)
    run = foam(src, "icoUncoupledKinematicParcelFoam", case)
    (case / "log.solver").write_text(run.stdout + run.stderr)
    cloud = case / f"{T_END:g}" / "lagrangian" / "kinematicCloud"
    U = read_field(cloud / "U", vector=True)
    d = read_field(cloud / "d", vector=False)
    if len(U) != len(particles):
        print(f"error: {len(U)} particles at the end, {len(particles)} injected", file=sys.stderr)
        return None, None, run
    import numpy as np

    tags = np.array([p["d"] for p in particles])
    # the particle each diameter tags (17 digits written: nearest)
    return U, [int(np.argmin(np.abs(tags - value))) for value in d], run


def read_field(path: Path, vector: bool):
    text = path.read_text()
    body = text[text.index("(", text.index("}")) :]
    if vector:
        rows = re.findall(r"\(([^()]+)\)", body)
        return [tuple(float(v) for v in r.split()) for r in rows]
    inner = body[body.index("(") + 1 : body.rindex(")")]
    return [float(v) for v in inner.split()]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--openfoam-src", help="OpenFOAM v1912 source tree (default: see above)")
    ap.add_argument("--scene", default="table1", help="scene (default table1)")
    ap.add_argument("--work", help="working directory (default: a temporary one, removed)")
    args = ap.parse_args(argv)
    for tool in ("icoUncoupledKinematicParcelFoam", "blockMesh"):
        if not shutil.which(tool):
            print(f"error: {tool} not found: apt-get install openfoam", file=sys.stderr)
            return 2
    started = time.perf_counter()
    src = find_source(args.openfoam_src)
    prepare_source(src)

    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import jaximpact as ji
    from jaximpact.wall_law import wall_law, write_wall_law

    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="jaximpact-of-"))
    work.mkdir(parents=True, exist_ok=True)
    scene = ji.load_scene(args.scene)
    t0 = time.perf_counter()
    law = wall_law(scene, radius=RADIUS_RANGE)
    write_wall_law(law, work / "law", args.scene)
    t_law = time.perf_counter() - t0
    R, A, W, X = law.shape
    log(f"wall law: {R} x {A} x {W} x {X} nodes in {t_law:.1f} s")

    t0 = time.perf_counter()
    built = foam(src, "wmake libso", work / "law" / "openfoam",
                 {"FOAM_USER_LIBBIN": str(work / "lib")})  # fmt: skip
    t_wmake = time.perf_counter() - t0
    lib = work / "lib" / "libjaximpactWallLaw.so"
    warnings = [line for line in (built.stdout + built.stderr).splitlines() if "warning" in line]
    log(f"wmake libso: {t_wmake:.1f} s -> {lib}; {len(warnings)} compiler warnings")
    for line in warnings[:10]:
        log("  " + line)

    particles = impacts()
    t0 = time.perf_counter()
    U, order, run = run_case(src, work / "case", lib, particles)
    t_run = time.perf_counter() - t0
    if U is None:
        return 1
    counts = re.findall(r"jaximpact wall law: captured = (\d+), rebound = (\d+)", run.stdout)
    per_patch = re.findall(r"jaximpact wall law: clamped on patch (\w+) = (\d+)", run.stdout)
    clamped_floor = int(dict(per_patch).get("floor", 0)) if per_patch else 0
    log(f"blockMesh + icoUncoupledKinematicParcelFoam: {t_run:.1f} s; counts {counts[-1:]}, "
        f"clamped per patch {dict(per_patch)}")  # fmt: skip
    worst, worst_sim, mismatched, outside = 0.0, 0.0, 0, set()
    rows = []
    s_lanes = {k: np.full(len(particles), float(v)) for k, v in ji.scene_parameters(scene).items()}
    s_lanes["radius"] = np.array([p["d"] / 2 for p in particles])
    from jaximpact.wall_law._capture import scene_with

    sim = ji.simulate(
        scene_with(scene, s_lanes),
        np.array([p["speed"] for p in particles]),
        np.array([p["angle"] for p in particles]),
        0.0,
    )
    for i, k in enumerate(order):
        p = particles[k]
        got = np.array(U[i])
        th = math.radians(p["angle"])
        vn, vt = p["speed"] * math.cos(th), p["speed"] * math.sin(th)
        code, vn_out, vt_out, _ = law.evaluate(p["d"] / 2, vn, vt, 0.0)
        t_dir = np.array(p["t_dir"])
        captured = bool(int(code) & 1)
        clamped = bool(int(code) & 2)
        if clamped:
            outside.add(k)
        want = np.zeros(3) if captured else float(vt_out) * t_dir + np.array([0, float(vn_out), 0])
        err = float(np.max(np.abs(got - want))) / p["speed"]
        sim_captured = int(sim.status[k]) == 1
        if sim_captured:
            want_sim = np.zeros(3)
        else:
            want_sim = float(sim.vt_out[k]) * t_dir + np.array([0, float(sim.vn_out[k]), 0])
        err_sim = float(np.max(np.abs(got - want_sim))) / p["speed"]
        mismatched += captured != bool(np.all(got == 0))
        worst = max(worst, err)
        if not clamped:  # outside the table, the edge's values: not simulate's
            worst_sim = max(worst_sim, err_sim)
        rows.append((p["d"] / 2, p["speed"], p["angle"], captured, clamped, sim_captured, got,
                     err, err_sim))  # fmt: skip
    log("radius um  speed  angle  table    simulate  OpenFOAM U after the impact (m/s)  "
        "|dU|/speed  sim")  # fmt: skip
    for r, s, a, cap, clamp, scap, got, err, err_sim in rows:
        outcome = ("stick" if cap else "rebound") + ("*" if clamp else "")
        sim_outcome = "stick" if scap else "rebound"
        vec = " ".join(f"{v:+.6f}" for v in got)
        log(f"{r * 1e6:9.2f} {s:5.2f} {a:6.1f}  {outcome:8s} {sim_outcome:8s}  ({vec})  "
            f"{err:.1e}  {err_sim:.1e}")  # fmt: skip
    log("* outside the table: the table's edge values (onClamped clamp)")

    # The same particles with onClamped rebound: those outside the table leave with the
    # fallback coefficients, the others as before.
    U2, order2, _ = run_case(src, work / "case_rebound", lib, particles, "rebound")
    if U2 is None:
        return 1
    worst_fallback = 0.0
    before = {k: np.array(U[i]) for i, k in enumerate(order)}
    for i, k in enumerate(order2):
        p = particles[k]
        th = math.radians(p["angle"])
        vn, vt = p["speed"] * math.cos(th), p["speed"] * math.sin(th)
        if k in outside:
            want = FALLBACK_ET * vt * np.array(p["t_dir"]) + np.array([0, FALLBACK_EN * vn, 0])
        else:
            want = before[k]
        worst_fallback = max(worst_fallback, float(np.max(np.abs(np.array(U2[i]) - want))))
    log(f"onClamped rebound: largest |U - expected| {worst_fallback:.1e} m/s")
    total = time.perf_counter() - started
    log(
        f"{len(particles)} particles of {len(RADII)} radii ({len(outside)} outside the table, "
        f"{clamped_floor} counted as clamped on patch floor): largest |U - wall law| / speed "
        f"{worst:.2e}, inside the table against simulate {worst_sim:.2e}; outcomes differing "
        f"from the table: {mismatched}; compiler warnings: {len(warnings)}; total {total:.0f} s "
        f"(wall law {t_law:.0f} s, wmake {t_wmake:.0f} s, case {t_run:.0f} s)"
    )
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    good = worst < 1e-9 and mismatched == 0 and clamped_floor == len(outside) and not warnings
    good = good and worst_fallback < 1e-9
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main())
