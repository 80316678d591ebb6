"""float32 near capture: failures and status disagreements with float64.

``python benchmarks/near_capture_band.py [--n 1000000] [--block 100000]`` prints BENCHMARKS.md's
"float32 near capture" (under "Throughput"); ``--compare-loops`` prints its rate of the float32
default against the same step loop without lane refill.

Slow impacts on the Table 1 scene, where adhesion decides between rebound and capture: speeds
uniform in 0.02-0.3 m/s, incidence -89.9..89.9 deg, spin uniform in +-2e4 rad/s (seed 2026).
Each block is simulated in float32 and float64 (``ji.simulate``, default settings). Counts the
impacts that fail in each precision, and for every impact whose float32 status differs from
float64's, how far its speed is from float64's capture speed at that angle and spin (found by
bisection in float64): expected are zero float32 failures, and equal statuses except within
0.5 % of the capture speed. Prints markdown. ``--compare-loops``: the float32 rate of the
default (lanes refilled as impacts finish) against the same step loop without refill (a fixed
number of lanes at a time) on 100,000 of these impacts.

Duration: about 2 minutes on 2 cores (the million impacts: 66 s of simulating).
"""

import argparse
import time

import jax
import numpy as np
from _common import default_settings, machine, measured_line, median_time, write_result

jax.config.update("jax_enable_x64", True)

import jaximpact as ji  # noqa: E402

TITLE = "float32 near capture"


def band(n, seed=2026):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.02, 0.3, n), rng.uniform(-89.9, 89.9, n), rng.uniform(-2e4, 2e4, n)


def capture_speed(scene, angle, omega0, lo=1e-4, hi=1.0, iters=40):
    """float64 capture speed at each (angle, spin): the largest speed that is captured (the
    band's rebound/capture boundary), by bisection on all impacts at once."""
    lo, hi = np.full(angle.shape, lo), np.full(angle.shape, hi)
    for _ in range(iters):
        mid = np.sqrt(lo * hi)
        captured = np.asarray(ji.simulate(scene, mid, angle, omega0).status) == ji.Status.CAPTURED
        lo, hi = np.where(captured, mid, lo), np.where(captured, hi, mid)
    return np.sqrt(lo * hi)


def slowest_lane_factor(steps, lanes):
    """Lane-steps a chunked batch runs (each chunk as long as its slowest impact) over the
    lane-steps its impacts need: what refilling finished lanes could save at most."""
    chunks = [steps[i : i + lanes] for i in range(0, steps.size, lanes)]
    return sum(c.size * c.max() for c in chunks) / steps.sum()


def main(n, block):
    info = machine()
    command = "python benchmarks/near_capture_band.py"
    command += (f" --n {n}" if n != 1_000_000 else "") + (
        f" --block {block}" if block != 100_000 else ""
    )
    scene = ji.table1_scene()
    speed, angle, omega0 = band(n)
    status, steps, seconds = {}, {}, {}
    for x64 in (True, False):
        parts, step_parts = [], []
        with jax.enable_x64(x64):
            ji.simulate(scene, speed[:block], angle[:block], omega0[:block])  # compile
            t = time.perf_counter()
            for i in range(0, n, block):
                s = slice(i, i + block)
                res = ji.simulate(scene, speed[s], angle[s], omega0[s])
                parts.append(np.asarray(res.status))
                step_parts.append(np.asarray(res.steps))
            seconds[x64] = time.perf_counter() - t
        status[x64], steps[x64] = np.concatenate(parts), np.concatenate(step_parts)
    failed = {x64: int((s >= ji.Status.MAX_STEPS).sum()) for x64, s in status.items()}
    differ = np.flatnonzero(status[True] != status[False])
    rows = []
    if differ.size:
        v_c = capture_speed(scene, angle[differ], omega0[differ])
        for k, i in enumerate(differ):
            rows.append(
                f"| {speed[i]:.5f} | {angle[i]:.2f} | {omega0[i]:.0f} | "
                f"{ji.Status.NAMES[int(status[True][i])]} | "
                f"{ji.Status.NAMES[int(status[False][i])]} | "
                f"{(speed[i] / v_c[k] - 1) * 100:+.4f} % |"
            )
    within = sum(abs(float(r.split("|")[6].strip(" %+"))) <= 0.5 for r in rows)
    print(f"### {TITLE}\n")
    print(measured_line(info, command, settings=default_settings()))
    print(
        f"{n:,} impacts, 0.02-0.3 m/s, -89.9..89.9 deg, |omega0| <= 2e4 rad/s (seed 2026), "
        f"blocks of {block:,}: float64 {seconds[True]:.0f} s, float32 {seconds[False]:.0f} s.\n"
    )
    print("| | float64 | float32 |\n|---|---|---|")
    print(f"| failed impacts | {failed[True]} | {failed[False]} |")
    rebounds = {x64: int((s == ji.Status.REBOUND).sum()) for x64, s in status.items()}
    print(f"| rebounds | {rebounds[True]:,} | {rebounds[False]:,} |")
    lanes = {True: 8192, False: 16384}  # simulate's chunks on one CPU device
    factor = {x64: slowest_lane_factor(steps[x64], lanes[x64]) for x64 in steps}
    print(
        f"| steps median / max | {np.median(steps[True]):.0f} / {steps[True].max()} | "
        f"{np.median(steps[False]):.0f} / {steps[False].max()} |"
    )
    print(
        f"| slowest-lane factor (chunks of {lanes[True]} / {lanes[False]}) | "
        f"{factor[True]:.2f} | {factor[False]:.2f} |"
    )
    print(
        f"\n{differ.size} statuses differ; {within} of them within 0.5 % of float64's capture "
        "speed.\n"
    )
    if rows:
        print("| speed (m/s) | angle (deg) | omega0 (rad/s) | float64 | float32 | from v_c |")
        print("|---|---|---|---|---|---|")
        print("\n".join(rows))
    precision = {True: "float64", False: "float32"}
    figures = {
        "n": n,
        "block": block,
        "seconds": {precision[k]: v for k, v in seconds.items()},
        "failed": {precision[k]: v for k, v in failed.items()},
        "rebounds": {precision[k]: v for k, v in rebounds.items()},
        "steps_median": {precision[k]: float(np.median(v)) for k, v in steps.items()},
        "steps_max": {precision[k]: int(v.max()) for k, v in steps.items()},
        "slowest_lane_factor": {precision[k]: v for k, v in factor.items()},
        "statuses_differ": int(differ.size),
        "within_0.5%_of_capture": int(within),
        "differing_rows": rows,
    }
    write_result("near_capture_band", figures, info, command)


def compare_loops(n, repeats=3):
    """float32 rate of the default (lanes refilled as impacts finish) against the same step
    loop without refill (a fixed number of lanes at a time) on the band."""
    from jaximpact._engine import simulate as sim

    info = machine()

    scene = ji.table1_scene()
    speed, angle, omega0 = band(n)
    rates = {}
    with jax.enable_x64(False):
        for loop in ("lean", None):
            call = lambda loop=loop: jax.block_until_ready(  # noqa: E731
                sim._simulate(scene, speed, angle, omega0, loop=loop)
            )
            call()  # compile
            rates[loop] = n / median_time(call, repeats)
    print(
        measured_line(
            info,
            "python benchmarks/near_capture_band.py --compare-loops"
            + (f" --n {n}" if n != 100_000 else ""),
            settings=default_settings(),
        )
    )
    print(
        f"float32, {n:,} band impacts, {len(jax.local_devices())} device(s), medians of "
        f"{repeats}: the default (lanes refilled as impacts finish) {rates[None]:,.0f}/s, "
        f"without refill (a fixed number of lanes at a time) {rates['lean']:,.0f}/s "
        f"({rates[None] / rates['lean']:.1f}x)"
    )


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--block", type=int, default=100_000)
    ap.add_argument(
        "--compare-loops",
        action="store_true",
        help="float32: the default (lane refill) against the same loop without refill",
    )
    args = ap.parse_args()
    if args.compare_loops:
        compare_loops(min(args.n, 100_000))
    else:
        main(args.n, args.block)
