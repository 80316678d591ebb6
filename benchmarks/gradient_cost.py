"""Gradient cost: a log density's values against its values with derivatives, through
``jaximpact.simulate`` with ``jax.jacfwd`` and ``jax.grad``.

Run: ``python benchmarks/gradient_cost.py [--sets 1 16 64] [--params 1 2 3] [--repeats 5]
[--rtol R] [--vmap] [--update BENCHMARKS.md] [--note TEXT]`` (about 15 minutes on 2 cores with
the defaults, most of it compiling). ``--update`` replaces only the "Gradient cost" section of
that file. Also a section of ``run_all.py`` (``gradient``).

What is measured, in float64:

- the data: the posterior benchmark's 25 impacts of the Table 1 microsphere (0.3-5 m/s,
  0/0/30/45/60 degrees), cor_n at C_A = 0.75, C_H = 0.25, f0 = 300 with noise of sigma 0.003;
- C parameter sets (each parameter drawn within 10 % of those values), every set shared by
  the 25 impacts: the Gaussian log density of each set, with the impacts of all C sets in one
  flat batch of C x 25 lanes (one ``simulate`` call, the parameters broadcast against the
  impacts), for the first 1, 2 or 3 of C_A, C_H, f0 as parameters;
- *values*: ``jax.jit`` of the C log densities;
- *values + jax.jacfwd*: ``jax.jacfwd`` of their sum in the C x k parameters (``has_aux``:
  the values come with it), which is every set's gradient since the sets are independent;
- *values + jax.grad*: ``jax.value_and_grad`` of the same sum (``has_aux``: the values);
- run times: medians of the repeats after a first call, the three computations' repeats
  interleaved; compile: that first call less the median (tracing and XLA compiling);
- ``--vmap``: the same sets under ``jax.vmap`` (one 25-impact ``simulate`` per set) instead of
  one flat batch, values and ``jax.grad``, for the most parameters asked.

Derivatives come from ``simulate``'s own forward-mode rule (one tangent integration per moved
parameter through the simulator's step loop, whatever the number of sets), which ``jax.grad``
transposes; no ``adjoint`` argument is involved.
"""

import argparse
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import (  # noqa: E402
    interleaved_timings,
    machine,
    measured_line,
    replace_section,
    table,
    write_result,
)

import jaximpact as ji  # noqa: E402

TITLE = "Gradient cost"
COMMAND = "python benchmarks/gradient_cost.py"
NAMES = ("C_A", "C_H", "f0")
TRUTH = {"C_A": 0.75, "C_H": 0.25, "f0": 300.0}
SIGMA = 0.003
SPEED = np.geomspace(0.3, 5.0, 25)
ANGLE = np.tile([0.0, 0.0, 30.0, 45.0, 60.0], 5)


def problem(rtol=None):
    """(scene, observed cor_n): the posterior benchmark's data, made with the simulator."""
    scene = ji.table1_scene()
    if rtol is not None:
        scene = scene.replace(solver={"rtol": rtol, "atol": rtol / 100})
    clean = np.asarray(ji.simulate(scene.replace(contact=TRUTH), SPEED, ANGLE, 0.0).cor_n)
    observed = clean + SIGMA * np.random.default_rng(1).standard_normal(clean.size)
    return scene, jnp.asarray(observed)


def parameter_sets(n_sets, k, seed=0):
    """(n_sets, k) values within 10 % of the truth, the first k of C_A, C_H, f0."""
    rng = np.random.default_rng(seed)
    truth = np.array([TRUTH[name] for name in NAMES[:k]])
    return jnp.asarray(truth * (1.0 + 0.1 * rng.uniform(-1.0, 1.0, (n_sets, k))))


def log_densities(scene, observed, k):
    """x (C, k) -> the C sets' Gaussian log densities, all impacts in one flat batch."""

    def f(x):
        contact = {name: x[:, j : j + 1] for j, name in enumerate(NAMES[:k])}  # (C, 1)
        res = ji.simulate(scene.replace(contact=contact), SPEED, ANGLE, 0.0)  # (C, 25)
        r = (res.cor_n - observed) / SIGMA
        return -0.5 * jnp.sum(r * r, axis=-1)

    return f


def log_density_one(scene, observed, k):
    """theta (k,) -> one set's log density (25 impacts): the function ``--vmap`` maps."""

    def f(theta):
        contact = {name: theta[j] for j, name in enumerate(NAMES[:k])}
        res = ji.simulate(scene.replace(contact=contact), SPEED, ANGLE, 0.0)
        r = (res.cor_n - observed) / SIGMA
        return -0.5 * jnp.sum(r * r)

    return f


def with_sum(f):
    """x -> (sum of f(x), f(x)): the objective whose derivative is every set's gradient."""

    def g(x):
        v = f(x)
        return jnp.sum(v), v

    return g


def timed(fns, x, repeats):
    """{name: (compile s, median run s, result)} of each ``fns[name](x)``: a first call each,
    then the repeats interleaved (a shared machine's load moves all alike); compile: the first
    call less the median."""
    calls = {name: (lambda fn=fn: jax.block_until_ready(fn(x))) for name, fn in fns.items()}
    runs = interleaved_timings(calls, repeats)
    return {name: (r["compile"], r["median"], r["result"]) for name, r in runs.items()}


def measure(sets=(1, 16, 64), params=(1, 2, 3), repeats=5, rtol=None, vmap=False, log=None):
    """One dict per (C, k): run and compile seconds of each computation, and how far
    ``jax.jacfwd``'s and ``jax.grad``'s gradients are apart."""
    scene, observed = problem(rtol)
    rows, vrows = [], []
    for n_sets in sets:
        for k in params:
            x = parameter_sets(n_sets, k)
            g = with_sum(log_densities(scene, observed, k))
            fns = {
                "values": jax.jit(log_densities(scene, observed, k)),
                "jacfwd": jax.jit(jax.jacfwd(g, has_aux=True)),
                "grad": jax.jit(jax.value_and_grad(g, has_aux=True)),
            }
            r = dict(sets=n_sets, lanes=n_sets * SPEED.size, k=k)
            outs = {}
            for name, (compile_s, run_s, out) in timed(fns, x, repeats).items():
                r[f"{name} compile"], r[name], outs[name] = compile_s, run_s, out
            g_fwd = np.asarray(outs["jacfwd"][0])
            g_rev = np.asarray(outs["grad"][1])
            scale = np.maximum(np.abs(g_rev), 1e-12 * np.max(np.abs(g_rev)) + 1e-300)
            r["agree"] = float(np.max(np.abs(g_fwd - g_rev) / scale))
            r["finite"] = bool(np.all(np.isfinite(np.asarray(outs["values"]))))
            rows.append(r)
            if log:
                log(r)
        if vmap:
            k = max(params)
            x = parameter_sets(n_sets, k)
            one = log_density_one(scene, observed, k)
            fns = {
                "values": jax.jit(jax.vmap(one)),
                "grad": jax.jit(jax.vmap(jax.value_and_grad(one))),
            }
            r = dict(sets=n_sets, lanes=n_sets * SPEED.size, k=k)
            for name, (compile_s, run_s, _) in timed(fns, x, repeats).items():
                r[f"{name} compile"], r[name] = compile_s, run_s
            vrows.append(r)
            if log:
                log(dict(r, vmap=True))
    return dict(rows=rows, vmap=vrows, rtol=rtol, repeats=repeats)


def report(data, info=None, command=COMMAND, note=None):
    """The "Gradient cost" section of BENCHMARKS.md (from its heading)."""
    ms = lambda s: f"{s * 1e3:,.1f}" if s < 0.1 else f"{s * 1e3:,.0f}"  # noqa: E731
    rows = [
        [
            f"{r['sets']} ({r['lanes']:,})",
            ", ".join(NAMES[: r["k"]]),
            ms(r["values"]),
            ms(r["jacfwd"]),
            f"{r['jacfwd'] / r['values']:.1f}",
            ms(r["grad"]),
            f"{r['grad'] / r['values']:.1f}",
            f"{r['values compile']:.1f} / {r['jacfwd compile']:.1f} / {r['grad compile']:.1f}",
        ]
        for r in data["rows"]
    ]
    tolerance = (
        f"rtol {data['rtol']:g} (atol rtol/100)"
        if data["rtol"] is not None
        else "the default tolerances"
    )
    lines = [f"### {TITLE}\n"]
    if info:
        lines.append(measured_line(info, command, note=note))
    lines += [
        "Cost of a log density and its gradient through `jaximpact.simulate`, float64, "
        f"{tolerance}: Table 1 scene, the posterior benchmark's 25 impacts (cor_n, sigma "
        "0.003); C parameter sets, each shared by the 25 impacts, with the impacts of all sets "
        "in one flat batch (C x 25 lanes, the parameters broadcast against the impacts). "
        "*values + `jax.jacfwd`*: `jax.jacfwd` of the sum of the C log densities in the "
        "C x k parameters, the values as its aux output; *values + `jax.grad`*: "
        "`jax.value_and_grad` of the same sum; *ratio*: over the values alone. Under "
        f"`jax.jit`, medians of {data['repeats']} interleaved calls after a first one; compile: "
        "that first call less the median.\n",
        table(
            [
                "C (lanes)",
                "parameters",
                "values (ms)",
                "values + `jax.jacfwd` (ms)",
                "ratio",
                "values + `jax.grad` (ms)",
                "ratio",
                "compile values / jacfwd / grad (s)",
            ],
            rows,
        ),
        "",
    ]
    agree = max((r["agree"] for r in data["rows"]), default=float("nan"))
    lines.append(
        f"`jax.jacfwd` and `jax.grad` give the same gradients (largest relative difference "
        f"{agree:.1e}): both take `simulate`'s forward-mode rule, one tangent integration per "
        "parameter whatever the number of sets, which `jax.grad` transposes."
        + ("" if all(r["finite"] for r in data["rows"]) else " **Some values were not finite.**")
    )
    if data["vmap"]:
        flat = {(r["sets"], r["k"]): r for r in data["rows"]}
        vrows = [
            [
                f"{r['sets']} ({r['lanes']:,})",
                ", ".join(NAMES[: r["k"]]),
                f"{ms(flat[r['sets'], r['k']]['values'])} / {ms(r['values'])}",
                f"{ms(flat[r['sets'], r['k']]['grad'])} / {ms(r['grad'])}",
                f"{r['values'] / flat[r['sets'], r['k']]['values']:.2f} / "
                f"{r['grad'] / flat[r['sets'], r['k']]['grad']:.2f}",
            ]
            for r in data["vmap"]
        ]
        lines += [
            "",
            "The same sets under `jax.vmap` (one 25-impact `simulate` per set) against one "
            "flat batch:\n",
            table(
                [
                    "C (lanes)",
                    "parameters",
                    "values flat / vmap (ms)",
                    "values + `jax.grad` flat / vmap (ms)",
                    "vmap over flat: values / grad",
                ],
                vrows,
            ),
        ]
    return "\n".join(lines) + "\n"


def run(quick=False, info=None, note=None, command="python benchmarks/run_all.py --only gradient"):
    """The section for ``run_all.py``: (Markdown from the heading, measurements)."""
    info = info or machine()
    if quick:
        data = measure(sets=(1, 16), params=(1, 3), repeats=2)
    else:
        data = measure()
    return report(data, info, command, note), data


def _progress(r):
    what = "vmap" if r.get("vmap") else "flat"
    times = ", ".join(f"{k} {r[k] * 1e3:.1f} ms" for k in ("values", "jacfwd", "grad") if k in r)
    print(f"[gradient_cost] C {r['sets']}, k {r['k']}, {what}: {times}", file=sys.stderr)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", type=int, nargs="+", default=[1, 16, 64], help="values of C")
    ap.add_argument(
        "--params", type=int, nargs="+", default=[1, 2, 3], help="k: the first k of C_A C_H f0"
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rtol", type=float, help="solver rtol (atol rtol/100); default: defaults")
    ap.add_argument("--vmap", action="store_true", help="also the sets under jax.vmap")
    ap.add_argument(
        "--update",
        metavar="BENCHMARKS.md",
        help='replace the "Gradient cost" section of this file',
    )
    ap.add_argument("--note", help="a sentence about the run for the measured line")
    args = ap.parse_args()
    if not all(1 <= k <= len(NAMES) for k in args.params):
        ap.error(f"--params: each k in 1..{len(NAMES)}")
    info = machine()
    data = measure(args.sets, args.params, args.repeats, args.rtol, args.vmap, log=_progress)
    command = COMMAND
    if args.sets != [1, 16, 64]:
        command += " --sets " + " ".join(map(str, args.sets))
    if args.params != [1, 2, 3]:
        command += " --params " + " ".join(map(str, args.params))
    if args.repeats != 5:
        command += f" --repeats {args.repeats}"
    if args.rtol is not None:
        command += f" --rtol {args.rtol:g}"
    if args.vmap:
        command += " --vmap"
    text = report(data, info, command, args.note)
    print(text)
    write_result("gradient_cost", data, info, command)
    if args.update:
        replace_section(Path(args.update), text)
        print(f"replaced the section {TITLE!r} of {args.update}", file=sys.stderr)


if __name__ == "__main__":
    main()
