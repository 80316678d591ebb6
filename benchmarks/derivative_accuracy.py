"""Derivative error against rtol and slip width: jacfwd of the smooth model vs central finite
differences of the exact reference (Richardson-checked), on the Table 1 scene.

Error of each derivative relative to its column's typical magnitude (outputs scaled to order one:
cor_n, vt/speed, omega r/speed, angle in rad, contact time / its K-sensitivity; inputs as
x d/dx, per radian, per speed/radius), with a floor of 1e-2 of the largest entry of the row.

    python benchmarks/derivative_accuracy.py   # prints a Markdown table (~10 min on 2 cores)
    python benchmarks/derivative_accuracy.py --default   # the default settings only, both programs
"""

import math
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaximpact as ji  # noqa: E402
from jaximpact import reference as ref  # noqa: E402
from jaximpact._engine.sensitivity import INPUTS, OUTPUTS  # noqa: E402
from jaximpact._engine.solvers import default_slip_width, default_tolerances  # noqa: E402

IMPACTS = [(1.0, 30.0, 0.0), (1.5, 0.0, 12000.0), (0.3, -50.0, 3000.0), (5.0, 70.0, -20000.0),
           (2.0, 0.0, 0.0), (0.8, 10.0, 0.0)]  # fmt: skip
INPUTS_USED = tuple(c for c in INPUTS if c != "lambda")


def scaled(params, speed, values, out, c):
    x = {"angle_deg": 180 / math.pi, "omega0": speed / params.radius, "speed": speed}.get(c)
    x = abs(getattr(params, c)) if x is None else x
    y = {"cor_n": 1.0, "vt_out": speed, "omega_out": speed / params.radius,
         "rebound_angle_deg": 180 / math.pi}.get(out)  # fmt: skip
    return values * x / (y if y else 1.0)


def main(default_only=False):
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from _common import machine

    info = machine()
    params = ref.table1_params()
    base = ji.table1_scene()
    exact = []
    for v, a, w in IMPACTS:
        exact.append(ref.output_derivatives(params, v, a, w, inputs=INPUTS_USED)[0])
    rows = []
    settings = [(r, w, "throughput") for r in (1e-8, 1e-9, 1e-10, 1e-11) for w in (3e-4, 1e-3)]
    if default_only:  # the library's defaults (rtol 1e-10, its slip width)
        settings = [(None, None, "throughput"), (None, None, "compact")]
    for rtol, width, program in settings:
        solver = {"rtol": rtol, "atol": rtol / 100, "slip_width": width} if rtol else {}
        scene = base.replace(solver=solver)
        rtol = rtol or default_tolerances(jnp.float64, None, None)[0]
        width = width or default_slip_width(jnp.float64, None, rtol)
        sp, an, om = (np.array(c) for c in zip(*IMPACTS, strict=True))
        t = time.perf_counter()
        jac = ji.output_jacobian(scene, sp, an, om, inputs=INPUTS_USED, program=program)
        seconds = time.perf_counter() - t
        steps = float(np.median(np.asarray(ji.simulate(scene, sp, an, om).steps)))
        errors = []
        for i, (v, _, _) in enumerate(IMPACTS):
            for out in OUTPUTS:
                want = {c: scaled(params, v, exact[i][out][c], out, c) for c in INPUTS_USED}
                typical = max(abs(x) for x in want.values())
                for j, c in enumerate(INPUTS_USED):
                    got = scaled(params, v, float(jac[out][i, j]), out, c)
                    errors.append(abs(got - want[c]) / max(abs(want[c]), 1e-2 * typical))
        errors = np.array(errors)
        rows.append((rtol, width, errors.max(), np.median(errors), (errors > 1e-3).sum(),
                     errors.size, steps, seconds, program))  # fmt: skip
    from _common import measured_line

    command = "python benchmarks/derivative_accuracy.py" + (" --default" if default_only else "")
    print("### Accuracy against finite differences\n")
    print(measured_line(info, command))
    print("| rtol | slip_width | program | max error | median error | > 1e-3 | median steps "
          "| jacfwd s (incl. compile) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(
            f"| {r[0]:.0e} | {r[1]:.0e} | {r[8]} | {r[2]:.1e} | {r[3]:.1e} | {r[4]} of {r[5]} "
            f"| {r[6]:.0f} | {r[7]:.1f} |"
        )
    from _common import write_result

    keys = ("rtol", "slip_width", "max_error", "median_error", "above_1e-3", "derivatives",
            "median_steps", "jacfwd_seconds", "program")  # fmt: skip
    figures = [dict(zip(keys, r, strict=True)) for r in rows]
    write_result("derivative_accuracy" + ("_default" if default_only else ""), figures, info,
                 command)  # fmt: skip


if __name__ == "__main__":
    main(default_only="--default" in sys.argv[1:])
