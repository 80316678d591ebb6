"""A fused step, tried: ns per lane-step of the engine's step loop against hand-fused variants.

``python benchmarks/fused_step.py [--lanes 8192] [--repeats 5]`` prints the Markdown of
BENCHMARKS.md, "A fused step, tried" (``--update BENCHMARKS.md`` writes it there).

Every variant integrates the same chunk of oblique spinning Table 1 impacts (float64, default
settings, one XLA device, so XLA splits each operation over the cores) with the same vector
field (``ImpactField``), Tsit5 tableau, error norm and PID controller (including its 24-bit
rounding of the step), and stops each lane at the step in which the event function changes
sign (the event itself is not located: the variants time the stepping):

- *engine*: ``simulate``'s step loop (``step_loop``: diffrax's controller and ``RESULTS``
  bookkeeping, the previous step kept for the event's root find, masked updates of every
  carried pytree);
- *fused*: one ``lax.while_loop`` over per-state arrays ``(lanes,)``, the controller written
  out (no ``RESULTS``, no pytree bookkeeping), the step in which the event happens not taken
  (so no copy of the previous step is carried);
- *fused, stage states materialized*: the same with an optimization barrier on each stage's
  state (XLA may not re-derive the stage sums in each consumer);
- *fused, (states, lanes) array*: the state as one 2-D array; the stage sums and the error are
  then one operation each over all states;
- *fused, field outputs materialized*: a barrier on the forces and moments inside the field;
- *fused, trivial field*: the field replaced by ``n'' = -n`` and a decay of the other states
  (same states, same events): what the loop costs without the physics.

ns per lane-step = time / (lanes x the chunk's largest step count); *same steps*: the share of
impacts whose step count is the engine's (the variants' arithmetic is the same, the fusion of
it by XLA, and so the last bits, can differ).

Duration: not recorded (six variants of one chunk compiled and timed in one process).
"""

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from jaximpact._engine.tsit5 import _combine  # the engine's term-by-term stage sum

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

VARIANTS = {
    "engine": "engine's step loop (`simulate`)",
    "fused": "fused: per-state arrays, controller written out",
    "stages": "fused, stage states materialized",
    "stacked": "fused, (states, lanes) array",
    "forces": "fused, field outputs materialized",
    "trivial": "fused, trivial field (the loop alone)",
}


def fused_loop(field, event, y0, p, *, rtol, atol, dt0, max_steps, controlled, variant):
    """Step every lane until its event function changes sign; returns the step counts."""
    import diffrax
    import jax
    import jax.numpy as jnp

    tableau = diffrax.Tsit5.tableau
    a_rows = [[float(a) for a in row] for row in tableau.a_lower]
    b_error = [float(b) for b in tableau.b_error]
    names = list(y0)
    lanes, dtype = y0["n"].shape[0], y0["n"].dtype

    def vf(y):
        if variant == "trivial":
            return {
                s: -y["n"] if s == "ndot" else y["ndot"] if s == "n" else -1e-3 * y[s] for s in y
            }
        return field(y, p)

    def stages_per_state(h, y, k0):
        ks = [k0]
        for row in a_rows:
            stage = {s: y[s] + h * _combine(row, [k[s] for k in ks]) for s in names}
            if variant == "stages":
                stage = jax.lax.optimization_barrier(stage)
            ks.append(vf(stage))
        return stage, {s: h * _combine(b_error, [k[s] for k in ks]) for s in names}, ks[-1]

    def stages_stacked(h, y, k0):
        rows = lambda d: jnp.stack([d[s] for s in names])  # noqa: E731
        back = lambda a: {s: a[i] for i, s in enumerate(names)}  # noqa: E731
        y2, ks = rows(y), [rows(k0)]
        for row in a_rows:
            stage = y2 + h * _combine(row, ks)
            ks.append(rows(vf(back(stage))))
        return back(stage), back(h * _combine(b_error, ks)), back(ks[-1])

    step = stages_stacked if variant == "stacked" else stages_per_state

    def body(c):
        t, h, y, k0, steps, done = c
        y1, error, k_last = step(h, y, k0)
        ratio = None
        for s in names:
            if s in controlled:
                scale = atol + rtol * jnp.maximum(jnp.abs(y[s]), jnp.abs(y1[s]))
                r = jnp.abs(error[s]) / scale
                ratio = r if ratio is None else jnp.maximum(ratio, r)
        ratio = jnp.where(jnp.isnan(ratio), jnp.inf, ratio)
        keep = ratio < 1
        factor = jnp.clip(
            0.9 * (1 / ratio) ** 0.2, jnp.where(keep, 1.0, 0.2), jnp.where(keep, 10.0, 0.9)
        )
        mantissa, exponent = jnp.frexp(h * factor)
        h_next = jnp.ldexp(jnp.round(mantissa * 2.0**24) / 2.0**24, exponent)
        crossed = keep & (event(y1, p) <= 0)
        go = ~done
        accept = go & keep & ~crossed
        y = {s: jnp.where(accept, y1[s], y[s]) for s in names}
        k0 = {s: jnp.where(accept, k_last[s], k0[s]) for s in names}
        t = jnp.where(accept, t + h, t)
        h = jnp.where(go & ~crossed, h_next, h)
        steps = steps + go.astype(steps.dtype)
        return t, h, y, k0, steps, done | crossed | (steps >= max_steps)

    zero = jnp.zeros(lanes, dtype)
    start = (zero, jnp.full(lanes, dt0, dtype), y0, vf(y0), jnp.zeros(lanes, jnp.int32))
    start = start + (jnp.zeros(lanes, bool),)
    return jax.lax.while_loop(lambda c: jnp.any(~c[5]), body, start)[4]


def worker(cfg):
    """In a subprocess with one XLA device: compile every variant, then time them in turn
    (``repeats`` rounds, each variant once per round), so that a change in the machine's load
    affects them alike."""
    import time

    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    from throughput import impacts

    import jaximpact as ji
    from jaximpact._engine import simulate as sim
    from jaximpact._model import dynamics as dyn

    scene = ji.table1_scene()
    lanes = cfg["lanes"]
    speed, angle, omega0 = impacts("full", lanes)
    params = {k: jnp.full(lanes, v) for k, v in sim.scene_parameters(scene).items()}
    terms = sim.required_terms(scene, params, angle, omega0)
    settings = sim.integration_settings(scene, params, speed, angle, jnp.float64)
    first = sim._problem(terms, settings, {k: v[0] for k, v in params.items()}, 1.0, 30.0, 0.0)

    def setup(prm, s, a, w):
        prob = sim._problem(terms, settings, prm, s, a, w)
        return prob.y0, prob.p

    def field(y, p):
        return dyn.ImpactField(terms)(0.0, y, p)

    def event(y, p):
        return first.event.cond_fn(0.0, y, p)

    def fused(variant):
        @jax.jit
        def run(s, a, w):
            y0, p = jax.vmap(setup)(params, s, a, w)
            return fused_loop(
                field,
                event,
                y0,
                p,
                rtol=settings.rtol,
                atol=settings.atol,
                dt0=float(first.dt0),
                max_steps=settings.max_steps,
                controlled=sim.CONTROLLED_STATES,
                variant=variant,
            )

        return lambda: run(speed, angle, omega0)

    calls = {"engine": lambda: sim._simulate(scene, speed, angle, omega0, chunk=0).steps}
    steps = {}
    for variant in VARIANTS:
        call = calls.get(variant) or fused(variant)
        loads = dyn.contact_loads
        if variant == "forces":  # traced (at the first call) with the loads materialized
            dyn.contact_loads = lambda *a, loads=loads: jax.lax.optimization_barrier(loads(*a))
        steps[variant] = np.asarray(call()).tolist()
        dyn.contact_loads = loads
        calls[variant] = call
    times = {v: [] for v in VARIANTS}
    for _ in range(cfg["repeats"]):
        for variant, call in calls.items():
            t = time.perf_counter()
            jax.block_until_ready(call())
            times[variant].append(time.perf_counter() - t)
    out = {v: dict(seconds=float(np.median(times[v])), steps=steps[v]) for v in VARIANTS}
    print("RESULT " + json.dumps(out), flush=True)


def measure(lanes=8192, repeats=5):
    from _common import machine, measured_line, table

    info = machine()
    cmd = [sys.executable, __file__, "--worker", json.dumps(dict(lanes=lanes, repeats=repeats))]
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1")
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=3600)
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    if not lines:
        raise SystemExit(proc.stderr[-3000:])
    results = json.loads(lines[0][7:])
    engine_steps = np.asarray(results["engine"]["steps"])
    engine_ns = None
    rows = []
    for variant, label in VARIANTS.items():
        r = results[variant]
        steps = np.asarray(r["steps"])
        ns = r["seconds"] / (lanes * steps.max()) * 1e9
        engine_ns = engine_ns or ns
        same = "-" if variant == "trivial" else f"{np.mean(steps == engine_steps):.0%}"
        ratio = "-" if variant == "trivial" else f"{engine_ns / ns:.2f}"
        rows.append([label, f"{ns:.0f}", ratio, f"{r['seconds']:.2f}", f"{steps.max()}", same])
    md = [
        "### A fused step, tried\n",
        measured_line(info, "python benchmarks/fused_step.py"),
        f"One chunk of {lanes} oblique spinning Table 1 impacts, float64, default settings, one "
        f"XLA device; all variants compiled in one process and timed in turn, medians of "
        f"{repeats} rounds; the variants are described in the script's docstring. ns per "
        "lane-step = time / (lanes x the chunk's largest step count); *speed-up*: the engine's "
        "ns per lane-step over the variant's.\n",
        table(
            ["variant", "ns per lane-step", "speed-up", "run (s)", "steps max", "same steps"],
            rows,
        ),
    ]
    from _common import write_result

    keys = ("variant", "ns per lane-step", "speed-up", "run (s)", "steps max", "same steps")
    figures = {"lanes": lanes, "repeats": repeats,
               "rows": [dict(zip(keys, r, strict=True)) for r in rows],
               "seconds": {v: results[v]["seconds"] for v in VARIANTS}}  # fmt: skip
    write_result("fused_step", figures, info, "python benchmarks/fused_step.py")
    return "\n".join(md)


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--lanes", type=int, default=8192)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--update", metavar="BENCHMARKS.md", help="write the section there")
    args = ap.parse_args()
    if args.worker:
        worker(json.loads(args.worker))
    else:
        md = measure(args.lanes, args.repeats)
        print(md)
        if args.update:
            from _common import replace_section

            replace_section(args.update, md)
