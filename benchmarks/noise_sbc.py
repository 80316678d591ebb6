"""Simulation-based calibration of the posterior with noise factors integrated out (issue 52,
item 1), on a problem where the truth is drawn from the very prior the sampler uses.

The model: two observables without sigmas (12 and 8 rows), residuals linear in ``u = ln p`` of
two parameters (C_A, f0) with the default log-uniform priors (C_A 1e-3..1e2 s/m, f0
1e-1..1e5 N/m) and one noise factor each, log-uniform on 1e-3..1e3: for each replication the
parameters and both factors are drawn from those priors, the data from the model, and
`_posterior._sample` (SMC, 4 x 500, the default ``noise="auto"``: factors integrated out,
then drawn from their exact conditionals) samples the posterior from the least-squares
solution. The share of the 2,000 draws below each truth (parameters and factors) is uniform
on [0, 1] when the sampler is right: chi-square over 10 bins and the mean (0.5 +- 0.0204 at
200 replications). ``--noise sampled`` runs the sampled form instead (the comparison).

Run: ``python benchmarks/noise_sbc.py [--replications 200] [--noise auto|sampled]`` (about
2-4 minutes on 2 cores).
"""

import argparse
import math
import sys
import time
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import machine, measured_line, table, write_result  # noqa: E402

from fitting._bayesian import posterior as _posterior  # noqa: E402
from fitting._bayesian.likelihood import NOISE_FACTOR_RANGE  # noqa: E402
from fitting._bayesian.priors import PRIOR_RANGES, priors_for  # noqa: E402

COMMAND = "python benchmarks/noise_sbc.py"
NAMES = ("C_A", "f0")
ROWS = (12, 8)
BINS = 10


def _design(rng):
    A = rng.standard_normal((sum(ROWS), 2)) * np.array([4.0, 2.0])
    A[:, 1] += 1.5 * A[:, 0]
    return A


def replication(seed, noise):
    """One replication: ``{quantity: share of draws below its truth}`` and the run's facts."""
    rng = np.random.default_rng(seed)
    A = _design(np.random.default_rng(0))
    u = np.array([rng.uniform(*np.log(PRIOR_RANGES[n])) for n in NAMES])
    s = np.exp(rng.uniform(*np.log(NOISE_FACTOR_RANGE), size=2))
    groups = np.repeat([0, 1], ROWS)
    y = A @ u + s[groups] * rng.standard_normal(len(groups))
    # the least-squares solution, kept inside the priors' box (as a fit's values are)
    box = np.log([PRIOR_RANGES[n] for n in NAMES])
    centre = np.clip(np.linalg.lstsq(A, y, rcond=None)[0], box[:, 0] + 1e-6, box[:, 1] - 1e-6)
    r = A @ centre - y
    cov = np.linalg.inv(A.T @ A) * max(float(np.mean(r**2)), 1e-12)
    result = _posterior._sample(
        lambda v: jnp.asarray(A) @ v - jnp.asarray(y), NAMES, centre, cov,
        priors_for(NAMES, None), groups, ("sigma_factor[a]", "sigma_factor[b]"),
        [0.0, 0.0], likelihood="gaussian", nu=4.0, chains=4, draws=500, warmup=1,
        seed=seed, jitter=0.5, target_accept=0.9, progress=False, noise_treatment=noise,
    )  # fmt: skip
    truth = np.concatenate([np.exp(u), s])
    draws = np.concatenate([result.draws.reshape(-1, 2), result.noise_draws.reshape(-1, 2)], axis=1)
    below = np.mean(draws < truth, axis=0)
    return below, result.converged, result.evaluations


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--replications", type=int, default=200)
    parser.add_argument("--noise", choices=("auto", "sampled"), default="auto")
    parser.add_argument("--first-seed", type=int, default=1)
    args = parser.parse_args()
    info = machine()
    t0 = time.perf_counter()
    shares, converged, evaluations = [], 0, []
    for i in range(args.replications):
        below, ok, n = replication(args.first_seed + i, args.noise)
        shares.append(below)
        converged += ok
        evaluations.append(n)
    seconds = time.perf_counter() - t0
    shares = np.array(shares)
    names = [*NAMES, "sigma_factor[a]", "sigma_factor[b]"]
    rows = []
    for j, name in enumerate(names):
        counts = np.histogram(shares[:, j], bins=BINS, range=(0.0, 1.0))[0]
        p = stats.chisquare(counts).pvalue
        se = 1.0 / math.sqrt(12 * len(shares))
        rows.append([name, f"{p:.3f}", f"{shares[:, j].mean():.3f} ± {se:.3f}"])
    print(measured_line(info, f"{COMMAND} --replications {args.replications} --noise {args.noise}"))
    print()
    print(
        f"{args.replications} replications in {seconds:.0f} s, {converged} converged; "
        f"evaluations per posterior median {int(np.median(evaluations))}"
    )
    print()
    print(table(["quantity", "chi-square p (10 bins)", "mean share below truth"], rows))
    figures = {
        "replications": args.replications,
        "noise": args.noise,
        "seconds": seconds,
        "converged": converged,
        "evaluations_median": int(np.median(evaluations)),
        "rows": [dict(zip(["quantity", "chi-square p", "mean share below truth"], r, strict=True))
                 for r in rows],
        "shares_below_truth": shares,
    }  # fmt: skip
    write_result(f"noise_sbc_{args.noise}", figures, info,
                 f"{COMMAND} --replications {args.replications} --noise {args.noise}")  # fmt: skip


if __name__ == "__main__":
    main()
