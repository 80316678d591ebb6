"""Other JAX code with and without the XLA options that ``import jaximpact`` sets.

Run: ``python benchmarks/xla_options.py [--rounds 2]`` (about 2 minutes on 2 cores).

``import jaximpact`` adds loop kernels (``xla_cpu_small_while_loop_byte_threshold`` 8 MiB,
LLVM's loop unrolling off) to ``XLA_FLAGS`` where JAX's backends have not started
(``jaximpact._engine.devices.loop_kernels_at_import``; ``JAXIMPACT_XLA_OPTIONS=off`` leaves
them out). They apply to the whole process, so this measures what they do to JAX code that is
not jaximpact's: a few typical programs, each timed in a fresh process without the options and
with them (the worker never imports jaximpact), alternating, medians of 5 calls after the
first (3 for the ODE).
"""

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

COMMAND = "python benchmarks/xla_options.py"
OPTIONS = (
    "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=8388608,"
    "xla_cpu_disable_loop_unrolling=true"
)
CASES = {
    "loop": "`fori_loop` of 200 `tanh(W @ x)`, W 512 x 512, x 512 x 64 (float32)",
    "elementwise loop": "`fori_loop` of 1,000 elementwise updates of 100,000 float64",
    "no loop": "elementwise and sum of 10 million float32 (no loop)",
    "matmul": "1,000 x 1,000 float64 matrix product (no loop)",
    "ode": "`vmap` of diffrax Tsit5 (PID, rtol 1e-8) on Lotka-Volterra, 1,000 lanes",
}


def worker():
    import jax
    import jax.numpy as jnp
    import numpy as np

    jax.config.update("jax_enable_x64", True)

    def median(f, *args, k=5):
        jax.block_until_ready(f(*args))
        times = []
        for _ in range(k):
            t = time.perf_counter()
            jax.block_until_ready(f(*args))
            times.append(time.perf_counter() - t)
        return float(np.median(times))

    key = jax.random.PRNGKey(0)
    w = jax.random.normal(key, (512, 512), jnp.float32) / 25
    x = jax.random.normal(key, (512, 64), jnp.float32)
    out = {}
    loop = jax.jit(lambda w, x: jax.lax.fori_loop(0, 200, lambda i, y: jnp.tanh(w @ y), x))
    out["loop"] = median(loop, w, x)
    a = jnp.linspace(0.0, 1.0, 100_000)
    update = lambda i, y: jnp.sin(y) * 0.99 + 0.01 * jnp.cos(3 * y)  # noqa: E731
    out["elementwise loop"] = median(jax.jit(lambda a: jax.lax.fori_loop(0, 1000, update, a)), a)
    b = jnp.linspace(0.0, 1.0, 10_000_000, dtype=jnp.float32)
    out["no loop"] = median(jax.jit(lambda b: jnp.sum(jnp.exp(-b) * jnp.sin(b) ** 2)), b)
    m = jax.random.normal(key, (1000, 1000))
    out["matmul"] = median(jax.jit(lambda m: m @ m), m)
    import diffrax

    def solve(y0):
        term = diffrax.ODETerm(
            lambda t, y, args: jnp.stack([y[0] - y[0] * y[1], -y[1] + y[0] * y[1]])
        )
        controller = diffrax.PIDController(rtol=1e-8, atol=1e-10)
        return diffrax.diffeqsolve(
            term, diffrax.Tsit5(), 0.0, 10.0, 0.01, y0,
            stepsize_controller=controller, max_steps=100_000,
        ).ys  # fmt: skip

    y0 = jnp.stack([jnp.linspace(0.5, 2.0, 1000), jnp.ones(1000)], 1)
    out["ode"] = median(jax.jit(jax.vmap(solve)), y0, k=3)
    print("RESULT " + json.dumps(out), flush=True)


def spawn(options: bool) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if options:
        env["XLA_FLAGS"] = OPTIONS
    cmd = [sys.executable, str(HERE / "xla_options.py"), "--worker"]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    lines = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    if not lines:
        raise SystemExit(proc.stderr[-3000:])
    return json.loads(lines[0][7:])


def measure(rounds: int) -> str:
    import numpy as np
    from _common import machine, measured_line, table, write_result

    info = machine()
    runs = {False: [], True: []}
    loads = []
    for _ in range(rounds):
        for options in (False, True):
            loads.append(os.getloadavg()[0])
            runs[options].append(spawn(options))
    rows = []
    for case, about in CASES.items():
        without = float(np.median([r[case] for r in runs[False]]))
        with_ = float(np.median([r[case] for r in runs[True]]))
        rows.append([about, f"{without * 1e3:.1f}", f"{with_ * 1e3:.1f}", f"{with_ / without:.2f}"])
    text = (
        "### Other JAX code with the options `import jaximpact` sets\n\n"
        + measured_line(info, COMMAND + (f" --rounds {rounds}" if rounds != 2 else ""))
        + f"\nEach program in a fresh process that does not import jaximpact, without and with "
        f"`XLA_FLAGS={OPTIONS}` (what `import jaximpact` adds where JAX's backends have not "
        f"started), alternating, {rounds} rounds; medians of the rounds' medians; load "
        f"averages at the start of each process: {', '.join(f'{x:.1f}' for x in loads)}. "
        f"*ratio*: with / without (below 1: faster with them).\n\n"
        + f"**{info['cpu']}, {info['cores']} cores**\n\n"
        + table(["program", "without ms", "with ms", "ratio"], rows)
        + "\n"
    )
    figures = {"rows": rows, "runs": {"without": runs[False], "with": runs[True]}, "loads": loads}
    write_result("xla_options", figures, info, COMMAND)
    return text


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--rounds", type=int, default=2)
    args = ap.parse_args()
    if args.worker:
        worker()
    else:
        print(measure(args.rounds))


if __name__ == "__main__":
    main()
