"""Stability catalogue: stiff and extreme cases, each run with default settings.

Each case reports the status, the error against the exact reference (where the reference can
run it), the solver picked by ``method="auto"``, the steps and the time (first call, which
includes compilation, and a second call). The explicit solver is also forced on the stiff
cases: it must rebound or end with a clear ``max_steps`` status, never NaN.

Duration: part of ``run_all.py``'s 20 minutes on 2 cores (``run_all.py --only stability``).
"""

import math
import signal
import time
from dataclasses import dataclass, field

import jax
import numpy as np
from _common import as_dict, fmt, max_error, output_errors, reference_rows, table

import jaximpact as ji
from jaximpact import integration_settings, scene_parameters
from jaximpact import reference as ref

DEG = math.pi / 180.0
W_PAPER = 1e6 * DEG  # rad/s


@dataclass
class Case:
    name: str
    scene: object  # () -> jaximpact Scene (built inside the precision context)
    params: object  # reference Params, or None
    speed: float = 1.66
    angle: float = 40.0
    omega0: float = W_PAPER
    method: str | None = None
    x64: bool = True
    quick: bool = False
    note: str = ""
    ill_conditioned: bool = False  # outcome infinitely sensitive: not counted for the target
    extra: dict = field(default_factory=dict)


def _scene_with(radius=35e-6, zeta_a=400.0, zeta_h=100.0, **replace):
    def build():
        s = ji.table1_scene()
        rho, K = 8000.0, 11.4e10
        if radius != 35e-6 or zeta_a != 400.0 or zeta_h != 100.0:
            s = s.replace(
                particle={"radius": radius},
                contact={
                    "C_A": ji.damping_from_zeta(zeta_a, radius, rho, K, 1.66),
                    "C_H": ji.damping_from_zeta(zeta_h, radius, rho, K, 1.66),
                },
            )
        return s.replace(**replace) if replace else s

    return build


def _params(radius=35e-6, zeta_a=400.0, zeta_h=100.0, **kw):
    rho, K = 8000.0, 11.4e10
    return ref.table1_params(
        radius=radius,
        C_A=ref.zeta_to_c(zeta_a, radius, rho, K, 1.66),
        C_H=ref.zeta_to_c(zeta_h, radius, rho, K, 1.66),
        **kw,
    )


def cases(quick=False):
    lam = lambda v: dict(model={"rolling_moments": "lambda", "lambda_": v})  # noqa: E731
    out = []
    # 1e-2 N m: stiffness estimate 2218 > solver.stiffness_limit (1000), so auto's Kvaerno5
    for v in (1e-4, 1e-3, 1e-2):
        out.append(
            Case(
                f"lambda = {v:g} N m",
                _scene_with(**lam(v)),
                _params(rolling_moments="lambda", lam=v),
                quick=v == 1e-3,
            )
        )
    for w in (1e-4, 1e-5, 1e-6, 1e-7, 1e-8):
        out.append(
            Case(
                f"slip_width {w:g}",
                _scene_with(solver={"slip_width": w}),
                _params(),
                quick=w in (1e-4, 1e-8),
            )
        )
    for v in (1e-3, 1e-2, 10.0, 100.0):
        out.append(
            Case(
                f"speed {v:g} m/s",
                _scene_with(),
                _params(),
                speed=v,
                angle=30.0,
                omega0=1e4,
                quick=v in (1e-3, 100.0),
            )
        )
    for r in (0.5e-6, 5e-6, 5e-4, 5e-3):
        out.append(
            Case(
                f"radius {r * 1e6:g} um",
                _scene_with(radius=r),
                _params(radius=r),
                omega0=W_PAPER * 35e-6 / r,
                quick=r in (0.5e-6, 5e-3),
                note="zeta 400/100 at 1.66 m/s; spin scaled by 35 um / r",
            )
        )
    for z in (1e3, 1e4):
        out.append(
            Case(
                f"zeta_A = zeta_H = {z:g}",
                _scene_with(zeta_a=z, zeta_h=z),
                _params(zeta_a=z, zeta_h=z),
            )
        )
    out.append(Case("grazing 89 deg", _scene_with(), _params(), angle=89.0, quick=True))
    out.append(Case("grazing -89 deg", _scene_with(), _params(), angle=-89.0))
    for w in (1e7, 1e8):
        out.append(
            Case(f"spin {w:g} deg/s", _scene_with(), _params(), omega0=w * DEG, quick=w == 1e8)
        )
    out.append(
        Case("spin 1e8 deg/s, normal", _scene_with(), _params(), angle=0.0, omega0=1e8 * DEG)
    )
    v_c = ref.capture_speed(ref.table1_params(), rel_tol=1e-9)
    for f in (1 - 1e-2, 1 - 1e-3, 1.0, 1 + 1e-3, 1 + 1e-2):
        out.append(
            Case(
                f"capture speed x {f:g}",
                _scene_with(),
                ref.table1_params(),
                ill_conditioned=f == 1.0,
                speed=v_c * f,
                angle=0.0,
                omega0=0.0,
                quick=f in (0.99, 1.01),
                note=f"v_c = {v_c:.7f} m/s (reference)"
                + ("; at v_c itself cor_n -> 0: ill-conditioned, not counted" if f == 1 else ""),
            )
        )
    for angle in (0.0, 40.0, -40.0):
        out.append(
            Case(
                f"float32, paper impact {angle:+g} deg",
                _scene_with(),
                _params(),
                angle=angle,
                x64=False,
                quick=angle == 40.0,
            )
        )
    out.append(
        Case(
            "float32, 10 m/s grazing 85 deg",
            _scene_with(),
            _params(),
            speed=10.0,
            angle=85.0,
            x64=False,
        )
    )
    out.append(
        Case(
            "float32, speed 1 mm/s",
            _scene_with(),
            _params(),
            speed=1e-3,
            angle=30,
            omega0=1e4,
            x64=False,
        )
    )
    # the explicit solver forced on the stiff cases
    for v in (1e-4, 1e-3, 1e-2):
        out.append(
            Case(
                f"tsit5 forced: lambda = {v:g}",
                _scene_with(**lam(v)),
                _params(rolling_moments="lambda", lam=v),
                method="tsit5",
                quick=v == 1e-3,
            )
        )
    out.append(
        Case(
            "tsit5 forced: zeta 1e4",
            _scene_with(zeta_a=1e4, zeta_h=1e4),
            _params(zeta_a=1e4, zeta_h=1e4),
            method="tsit5",
        )
    )
    out.append(
        Case(
            "tsit5 forced: slip_width 1e-8",
            _scene_with(solver={"slip_width": 1e-8}),
            _params(),
            method="tsit5",
        )
    )
    return [c for c in out if c.quick or not quick]


class _Timeout(Exception):
    pass


def _reference(case, seconds=120):
    """The exact reference's result dict, or None if it fails or takes over ``seconds``."""
    if case.params is None:
        return None, "n/a"

    def alarm(*_):
        raise _Timeout

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(seconds)
    try:
        t = time.perf_counter()
        ex = reference_rows(case.params, [case.speed], [case.angle], [case.omega0])
        return ex, f"{time.perf_counter() - t:.2f}"
    except _Timeout:
        return None, f"> {seconds} s"
    except Exception as e:  # noqa: BLE001 - reported in the table
        return None, f"error: {type(e).__name__}"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def run_case(case):
    exact, ref_time = _reference(case)
    with jax.enable_x64(case.x64):
        scene = case.scene()
        dtype = jax.numpy.result_type(float)
        params = {k: np.atleast_1d(np.asarray(v)) for k, v in scene_parameters(scene).items()}
        picked = integration_settings(
            scene, params, np.atleast_1d(case.speed), np.atleast_1d(case.angle), dtype, case.method
        ).method
        call = lambda: jax.block_until_ready(  # noqa: E731
            ji.simulate(scene, case.speed, case.angle, case.omega0, method=case.method)
        )
        t = time.perf_counter()
        res = call()
        first = time.perf_counter() - t
        t = time.perf_counter()
        call()
        second = time.perf_counter() - t
    out = as_dict(res)
    status = str(out["status"][0])
    values = [out[k][0] for k in ("cor_n", "vt_out", "omega_out", "contact_time")]
    finite = bool(np.all(np.isfinite(values)))
    err = None
    if exact is not None and exact["status"][0] != "failed":
        e, _ = output_errors(out, exact, np.array([case.speed]), float(scene.particle.radius))
        err = max_error(e) if status == exact["status"][0] else float("nan")
    return dict(
        name=case.name,
        status=status,
        ref_status=None if exact is None else exact["status"][0],
        error=err,
        steps=int(np.asarray(res.steps)),
        first=first,
        second=second,
        solver=picked,
        finite=finite,
        ref_time=ref_time,
        note=case.note,
        precision="float64" if case.x64 else "float32",
        ill_conditioned=case.ill_conditioned,
    )


TITLE = "Stability catalogue"


def run(quick=False, info=None, note=None, command="python benchmarks/run_all.py --only stability"):
    """The section "Stability catalogue" of BENCHMARKS.md (from its heading), and the cases."""
    from _common import default_settings, machine, measured_line

    info = info or machine()
    rows, results = [], []
    for case in cases(quick):
        r = run_case(case)
        results.append(r)
        ok = (r["status"] in ("rebound", "captured") and r["finite"]) or r["status"] == "max_steps"
        rows.append(
            [
                r["name"],
                r["precision"],
                r["solver"],
                r["status"],
                r["ref_status"] or "–",
                fmt(r["error"]),
                r["steps"],
                f"{r['first']:.1f}",
                f"{r['second'] * 1e3:.1f}",
                r["ref_time"],
                "yes" if ok else "**NO**",
                r["note"],
            ]
        )
    defaults = [
        r
        for r in results
        if r["error"] is not None
        and not r["name"].startswith("tsit5 forced")
        and not r["ill_conditioned"]
    ]
    finite = [r for r in defaults if np.isfinite(r["error"])]
    worst = max(finite, key=lambda r: r["error"]) if finite else None
    bad = [r["name"] for r in defaults if not (np.isfinite(r["error"]) and r["error"] < 1e-3)]
    nonfinite = [r["name"] for r in results if r["status"] == "nonfinite"]
    forced = [r for r in results if r["name"].startswith("tsit5 forced")]
    md = [
        f"## {TITLE}\n",
        measured_line(
            info,
            command,
            settings=default_settings(),
            note=note,
        ),
        "Its fast cases are `tests/test_stability.py`. "
        "Table 1 scene (analytical moments unless stated), 1.66 m/s, +40 deg, 1e6 deg/s unless "
        'stated; default settings (`method="auto"`: Tsit5, or Kvaerno5 when the scene is '
        "estimated stiff or the slip width is below 30 rtol). *error*: max of the four scaled "
        "output errors against the exact reference (NaN when the status differs). *first*: "
        "first call including compilation; *second*: a second call. *ok*: rebound/captured "
        "with finite outputs, or a clear `max_steps`.\n",
        table(
            [
                "case",
                "precision",
                "solver",
                "status",
                "reference",
                "error",
                "steps",
                "first (s)",
                "second (ms)",
                "reference (s)",
                "ok",
                "note",
            ],
            rows,
        ),
        f"\nDefault-setting cases with a reference: {len(defaults)}; error below 1e-3 in "
        f"{len(defaults) - len(bad)}"
        + (f"; largest: {worst['name']} ({fmt(worst['error'])})" if worst else "")
        + (f"; failing: {', '.join(bad)}" if bad else "")
        + (
            f". No case of the {len(results)} ended non-finite."
            if not nonfinite
            else f". **{len(nonfinite)} of the {len(results)} cases ended non-finite**: "
            + ", ".join(nonfinite)
            + "."
        )
        + (
            " With the explicit solver forced on the stiff cases, "
            + (
                "each ends with a rebound, a capture or a clear `max_steps`: "
                if all(r["status"] in ("rebound", "captured", "max_steps") for r in forced)
                else "**not every case ends with a rebound, a capture or `max_steps`**: "
            )
            + "; ".join(
                f"{r['name'].removeprefix('tsit5 forced: ')}: {r['status']}, {r['steps']} steps"
                for r in forced
            )
            + "."
            if forced
            else ""
        )
        + "\n",
    ]
    return "\n".join(md) + "\n", results
