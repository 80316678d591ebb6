"""Simulation-based calibration of `fitting.sample_posterior` (Talts et al. 2018).

For each replication: parameters drawn from the prior, data drawn from the model (cor_n of
the Table 1 sphere plus Gaussian noise of sigma 0.003; an impact the model captures gives its
continued cor_n, the likelihood's own model of it), the posterior sampled as a user would
(least-squares fit from the prior's centre, then the default sampler), and the rank of each
true parameter among L = 99 posterior draws picked at random. If the sampler is right, every
rank is uniform on 0..99: the benchmark tests it by chi-square over 10 bins per parameter and
plots the histograms with the 99 % band of a uniform.

Designs: ``weak``: 6 normal impacts, 0.6-8 m/s (C_A and f0 weakly determined, a ridge);
``well``: 12 impacts, 0.3-5 m/s at 0, 30, 45 and 60 degrees.

Run: ``python benchmarks/posterior_sbc.py --design weak --replications 200 --out sbc_weak.jsonl``
(appends; a rerun continues where the file stops), then ``--report sbc_weak.jsonl
sbc_well.jsonl`` for the table and the figure ``benchmarks/figures/posterior_sbc.png``.
``--design weak --draws 1000 --grid-check 3 5 6`` recomputes those replications' data and
compares SMC with the exact posterior on a grid: each parameter's probability below the truth
(the quantity whose uniformity SBC tests), by both.

Duration: not recorded as a whole; hours on 2 cores for 200 replications of a design.
"""

import argparse
import json
import math
import re
import sys
import tempfile
import time
from pathlib import Path

import jaximpact

jaximpact.use_all_cpu_cores()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import fitting  # noqa: E402

NAMES = ("C_A", "C_H", "f0")
#: The calibration's prior (log-uniform; SI): a factor ~4 either side of Table 1's values.
PRIOR = {"C_A": (0.2, 3.0), "C_H": (0.06, 1.0), "f0": (75.0, 1200.0)}
SIGMA = 0.003
RANKS = 99  # draws per rank: ranks 0..99
BINS = 10
DESIGNS = {
    "weak": (np.geomspace(0.6, 8.0, 6), np.zeros(6)),
    "well": (np.geomspace(0.3, 5.0, 12), np.tile([0.0, 30.0, 45.0, 60.0], 3)),
}


def _priors():
    return {n: f"loguniform:{lo}:{hi}" for n, (lo, hi) in PRIOR.items()}


def _write(path, speed, angle, values):
    rows = ["speed,angle_deg,observable,value,sigma"]
    rows += [
        f"{float(s)!r},{float(a)!r},cor_n,{float(v)!r},{SIGMA}"
        for s, a, v in zip(speed, angle, values, strict=True)
    ]
    Path(path).write_text("\n".join(rows) + "\n")


def _sampler_seed(seed):
    """The sampler's seed of replication ``seed``: another stream than the one that drew the
    truth and the noise (replications 1-200 of the weak design and 1-54 of the well one ran
    with the data's own seed: the first three uniforms of the sampler's stream, which decide
    whether its first particles come from the prior, were the truth's)."""
    return seed + 1_000_003


def _draw(seed, n_data):
    """Replication ``seed``'s truth (from the prior) and data noise (``n_data`` values), and
    its random stream, which goes on to pick the draws that rank the truth."""
    rng = np.random.default_rng(seed)
    truth = {n: float(math.exp(rng.uniform(math.log(lo), math.log(hi)))) for n, (lo, hi) in
             PRIOR.items()}  # fmt: skip
    return truth, SIGMA * rng.standard_normal(n_data), rng


def _replication_data(folder, design, seed):
    """Replication ``seed``'s data file in ``folder``: the model's cor_n at the truth
    (continued below zero where it captures, as the likelihood sees it) plus the noise.
    Returns ``(path, truth, clean values, random stream)``."""
    speed, angle = DESIGNS[design]
    truth, noise, rng = _draw(seed, speed.size)
    residuals = _design_objective(folder, design).residuals([truth[n] for n in NAMES])
    clean = 0.5 + SIGMA * np.asarray(residuals)
    data = Path(folder) / f"{design}_{seed}.csv"
    _write(data, speed, angle, clean + noise)
    return data, truth, clean, rng


def replication(folder, design, seed, draws):
    """One calibration replication: the truth, its ranks and the run's diagnostics."""
    data, truth, clean, rng = _replication_data(folder, design, seed)
    centre = {n: math.sqrt(lo * hi) for n, (lo, hi) in PRIOR.items()}
    t0 = time.perf_counter()
    post = fitting.sample_posterior(
        jaximpact.table1_scene(), data, NAMES, priors=_priors(), initial=centre, starts=1,
        draws=draws, seed=_sampler_seed(seed), progress=False,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    flat = post.draws.reshape(-1, len(NAMES))
    pick = rng.choice(len(flat), RANKS, replace=False)
    ranks = {n: int(np.sum(flat[pick, i] < truth[n])) for i, n in enumerate(NAMES)}
    return {
        "design": design,
        "seed": seed,
        "sampler_seed": _sampler_seed(seed),
        "particles": draws,
        "truth": truth,
        "ranks": ranks,
        # the share of all draws below the truth (uniform too; no subsampling of copies)
        "p_below": {n: float(np.mean(flat[:, i] < truth[n])) for i, n in enumerate(NAMES)},
        "captured": int(np.sum(clean < 0)),
        "converged": bool(post.converged),
        "problems": post.problems,
        "fit_status": post.fit.status,
        "rhat": max(post.summary[n]["rhat"] for n in NAMES),
        "ess": min(min(post.summary[n]["ess"], post.summary[n]["ess_tail"]) for n in NAMES),
        "evaluations": post.evaluations,
        # populations that ended as an importance sample (the rest moved until decorrelated)
        "importance_populations": _importance_populations(post),
        "wall_s": wall,
    }


def _importance_populations(post) -> int:
    found = re.search(
        r"(every population|(\d+) of \d+ populations) ended as an importance", post.reason
    )
    if not found:
        return 0
    return post.chains if found.group(2) is None else int(found.group(2))


def grid_check(design, seed, draws, points=36):
    """Replication ``seed``'s data again, its exact posterior on a grid of the same log density
    (``grid_reference(axes="parameters")``) and SMC's (``draws`` particles per population):
    each parameter's posterior probability below the truth, by both."""
    from fitting._bayesian.grid_reference import grid_reference

    with tempfile.TemporaryDirectory() as tmp:
        data, truth, _, _ = _replication_data(tmp, design, seed)
        centre = {n: math.sqrt(lo * hi) for n, (lo, hi) in PRIOR.items()}
        fit = fitting.fit(jaximpact.table1_scene(), data, NAMES, initial=centre, starts=1,
                          progress=False)  # fmt: skip
        grid = grid_reference(fit, _priors(), points=points, axes="parameters")["_grid"]
        post = fitting.sample_posterior(
            jaximpact.table1_scene(), data, NAMES, priors=_priors(), fit_result=fit,
            draws=draws, seed=_sampler_seed(seed), progress=False,
        )  # fmt: skip
    flat = post.draws.reshape(-1, len(NAMES))
    out = {}
    for i, n in enumerate(NAMES):
        centres, mass = grid.marginal(i)  # ln p
        out[n] = (
            float(mass[np.exp(centres) < truth[n]].sum()),
            float(np.mean(flat[:, i] < truth[n])),
        )
    return out


def _design_objective(folder, design):
    """The design's objective (observed values are placeholders: the model's values at any
    parameters are ``0.5 + SIGMA * residuals``)."""
    speed, angle = DESIGNS[design]
    data = Path(folder) / f"{design}_design.csv"
    _write(data, speed, angle, np.full(speed.size, 0.5))
    return fitting.Objective(jaximpact.table1_scene(), data, NAMES)


def prior_bank(design, size, path):
    """``size`` draws of the prior (log parameters ``L``) and the model's values ``M`` there
    (cor_n continued below zero where it captures, as in the data), cached in ``path``."""
    path = Path(path)
    if path.exists():
        bank = np.load(path)
        if bank["L"].shape[0] == size:
            return bank["L"], bank["M"]
    rng = np.random.default_rng(12345)
    L = np.stack([rng.uniform(math.log(lo), math.log(hi), size) for lo, hi in PRIOR.values()], 1)
    with tempfile.TemporaryDirectory() as tmp:
        residuals = jax.jit(jax.vmap(_design_objective(tmp, design).residuals))
        M = np.concatenate(
            [0.5 + SIGMA * np.asarray(residuals(np.exp(L[i : i + 4000])))
             for i in range(0, size, 4000)]
        )  # fmt: skip
    np.savez(path, L=L, M=M)
    return L, M


def _replications(objective, seeds, n_data):
    """Truths ``T`` (replications, parameters) and data ``Y`` (replications, n_data) of
    ``seeds``, as :func:`_replication_data` makes them."""
    draws = [_draw(seed, n_data) for seed in seeds]
    T = np.array([[truth[n] for n in NAMES] for truth, _, _ in draws])
    clean = 0.5 + SIGMA * np.asarray(jax.jit(jax.vmap(objective.residuals))(T))
    return T, clean + np.array([e for _, e, _ in draws])


def _smc_p_below(row) -> list[float]:
    """A recorded SMC run's P(parameter < truth) (``p_below``, else rank / 99; NaN: none)."""
    if row is None:
        return [np.nan] * len(NAMES)
    return [row["p_below"][n] if "p_below" in row else row["ranks"][n] / RANKS for n in NAMES]


def _print_agreement(exact, smc, n_replications) -> None:
    """The table of the exact posterior's mean P(< truth) against SMC's, per parameter."""
    exact, smc = np.asarray(exact), np.asarray(smc)
    have = np.all(np.isfinite(smc), axis=1)
    half = math.sqrt(1 / 12 / n_replications)
    print("| parameter | exact: mean P(< truth) | SMC: mean | mean abs(SMC - exact) | corr |")
    print("|---|---|---|---|---|")
    for i, n in enumerate(NAMES):
        e, m = exact[have, i], smc[have, i]
        print(f"| {n} | {exact[:, i].mean():.3f} (0.5 +- {half:.3f}) | "
              + (f"{m.mean():.3f} | {np.abs(m - e).mean():.3f} | {np.corrcoef(e, m)[0, 1]:.3f} |"
                 if have.any() else "- | - | - |"))  # fmt: skip


def exact_check(design, seeds, bank, sbc_rows):
    """The exact posterior of each replication by importance sampling of the prior bank (the
    model's values at ``size`` prior draws; weights: the likelihood): each parameter's
    probability below the truth, against the SMC run's (``p_below``, or rank / 99), and the
    mean over replications, which is 0.5 in expectation for the exact posterior."""
    L, M = bank
    with tempfile.TemporaryDirectory() as tmp:
        T, Y = _replications(_design_objective(tmp, design), seeds, M.shape[1])
    exact, ess = [], []
    for k in range(len(seeds)):
        log_w = -0.5 * np.sum(((M - Y[k]) / SIGMA) ** 2, axis=1)
        w = np.exp(log_w - log_w.max())
        ess.append(w.sum() ** 2 / np.sum(w * w))
        exact.append([w[L[:, i] < math.log(T[k, i])].sum() / w.sum() for i in range(len(NAMES))])
    exact = np.array(exact)
    print(f"{design}, replications {seeds[0]}-{seeds[-1]}: prior bank of {len(L)} draws, "
          f"importance ESS median {np.median(ess):.0f} (min {min(ess):.0f})")  # fmt: skip
    _print_agreement(exact, [_smc_p_below(sbc_rows.get(seed)) for seed in seeds], len(seeds))
    # Where few bank points carry the weight, the estimate is nearly the indicator of the best
    # point (a mode, not a draw): biased where the posterior is skewed, and more spread than a
    # uniform. Selecting replications by their data (the ESS is a function of the data alone)
    # keeps the exact posterior's P(< truth) uniform, so the well-resolved ones test the data
    # against the likelihood without that bias.
    ess = np.array(ess)
    print("| importance ESS | replications | exact: mean P(< truth) per parameter (+- se) |")
    print("|---|---|---|")
    for lo, hi in ((0, 10), (10, 100), (100, math.inf)):
        sel = (ess >= lo) & (ess < hi)
        if sel.any():
            means = ", ".join(
                f"{exact[sel, i].mean():.3f} +- {exact[sel, i].std() / math.sqrt(sel.sum()):.3f}"
                for i in range(len(NAMES))
            )
            print(f"| {lo}-{hi} | {int(sel.sum())} | {means} |")


def _weighted_moments(L, log_w):
    w = np.exp(log_w - log_w.max())
    w /= w.sum()
    mu = w @ L
    cov = (L - mu).T @ ((L - mu) * w[:, None])
    return mu, cov, 1.0 / np.sum(w * w)


def sharp_exact_check(design, seeds, bank, sbc_rows, size=2000, rounds=3, nu=4.0):
    """The exact posterior of each replication by adaptive importance sampling in ``ln p``:
    a t proposal (``nu`` degrees of freedom, twice the scale of the previous round's weighted
    spread) placed first on the prior bank's weighted points, then on each round's; the last
    round's ``size`` fresh model evaluations give P(parameter < truth) (importance ESS a few
    hundred on the weak design, where the prior bank's was often a handful). Weights: prior
    (uniform in ``ln p``
    over the box) times likelihood over the proposal; no part of the sampler is used. The model
    runs at the sampler's tolerance (rtol 1e-7: within 0.006 sigma of the data's rtol 1e-10 at
    2,000 prior draws; 2.7x fewer steps)."""
    from scipy.stats import multivariate_t

    from fitting._bayesian.programs import SAMPLING_RTOL, _at_tolerance

    L_bank, M_bank = bank
    box = np.log(np.array(list(PRIOR.values())))
    rng = np.random.default_rng(2024)
    with tempfile.TemporaryDirectory() as tmp:
        objective = _design_objective(tmp, design)
        T, Y = _replications(objective, seeds, M_bank.shape[1])
        model = jax.jit(jax.vmap(_at_tolerance(objective, SAMPLING_RTOL).residuals))

        def values(L):  # model values at ln p (n, 3), in blocks of the compiled size
            out = []
            for i in range(0, len(L), size):
                block = L[i : i + size]
                pad = np.concatenate([block, np.repeat(block[-1:], size - len(block), 0)])
                out.append(0.5 + SIGMA * np.asarray(model(np.exp(pad)))[: len(block)])
            return np.concatenate(out)

        rows = []
        for k, seed in enumerate(seeds):
            log_w = -0.5 * np.sum(((M_bank - Y[k]) / SIGMA) ** 2, axis=1)
            mu, cov, ess = _weighted_moments(L_bank, log_w)
            # a floor under the bank's spread, which a handful of points may leave singular
            floor = np.diag(((box[:, 1] - box[:, 0]) / 200.0) ** 2)
            for r in range(rounds):
                proposal = multivariate_t(mu, 4.0 * cov + (floor if r == 0 else 0.0), df=nu)
                L = proposal.rvs(size, random_state=rng)
                inside = np.all((L > box[:, 0]) & (L < box[:, 1]), axis=1)
                log_w = np.full(size, -np.inf)
                M = values(L[inside])
                log_w[inside] = -0.5 * np.sum(((M - Y[k]) / SIGMA) ** 2, axis=1)
                log_w[inside] -= proposal.logpdf(L[inside])
                mu, cov, ess = _weighted_moments(L, log_w)
            w = np.exp(log_w - log_w.max())
            p = [float(w[L[:, i] < math.log(T[k, i])].sum() / w.sum()) for i in range(len(NAMES))]
            smc = _smc_p_below(sbc_rows.get(seed))
            rows.append((seed, ess, p, smc))
            print(json.dumps({"seed": seed, "ess": round(ess, 1), "exact": p, "smc": smc}),
                  flush=True)  # fmt: skip
    ess = np.array([r[1] for r in rows])
    print(f"{design}, replications {seeds[0]}-{seeds[-1]}: adaptive importance sampling, "
          f"{rounds} x {size} evaluations each, final ESS median {np.median(ess):.0f} "
          f"(min {ess.min():.0f})")  # fmt: skip
    _print_agreement([r[2] for r in rows], [r[3] for r in rows], len(seeds))
    return rows


def chi_square(ranks):
    """p-value of the chi-square test of uniform ranks 0..RANKS over BINS equal bins."""
    from scipy.stats import chi2

    counts = np.bincount(np.asarray(ranks) * BINS // (RANKS + 1), minlength=BINS)
    expected = len(ranks) / BINS
    stat = float(np.sum((counts - expected) ** 2 / expected))
    return float(chi2.sf(stat, BINS - 1)), counts


def report(paths, figure):
    rows = [json.loads(line) for p in paths for line in Path(p).read_text().splitlines() if line]
    designs = sorted({r["design"] for r in rows}, key=list(DESIGNS).index)
    print("| design | replications | converged | captured impacts | median s | "
          + " | ".join(f"p({n})" for n in NAMES) + " |")  # fmt: skip
    print("|---" * (5 + len(NAMES)) + "|")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import binom

    fig, axes = plt.subplots(len(designs), len(NAMES), figsize=(10, 3 * len(designs)),
                             squeeze=False)  # fmt: skip
    for row, design in enumerate(designs):
        reps = [r for r in rows if r["design"] == design]
        ps = {}
        for col, n in enumerate(NAMES):
            p, counts = chi_square([r["ranks"][n] for r in reps])
            ps[n] = p
            ax = axes[row, col]
            ax.bar(np.arange(BINS), counts, width=0.9, color="tab:blue")
            lo, hi = binom.ppf([0.005, 0.995], len(reps), 1 / BINS)
            ax.axhspan(lo, hi, color="0.85", zorder=0)
            ax.axhline(len(reps) / BINS, color="0.4", lw=1)
            ax.set_title(f"{design}: {n} (chi-square p = {p:.2f})", fontsize=9)
            ax.set_xticks([])
        conv = sum(r["converged"] for r in reps)
        cap = sum(r["captured"] > 0 for r in reps)
        med = float(np.median([r["wall_s"] for r in reps]))
        print(f"| {design} | {len(reps)} | {conv} | {cap} replications | {med:.1f} | "
              + " | ".join(f"{ps[n]:.3f}" for n in NAMES) + " |")  # fmt: skip
        counted = [r for r in reps if "importance_populations" in r]
        if counted:
            some = sum(r["importance_populations"] > 0 for r in counted)
            ends = sum(r["importance_populations"] for r in counted)
            print(f"  {design}: {some} of {len(counted)} replications had populations that "
                  f"ended as importance samples ({ends} populations in all)")  # fmt: skip
        below = [r for r in reps if "p_below" in r]
        if below:  # the share of all draws below the truth: uniform on (0, 1) too
            line = []
            for n in NAMES:
                as_ranks = [min(int(r["p_below"][n] * (RANKS + 1)), RANKS) for r in below]
                p_all, _ = chi_square(as_ranks)
                mean = np.mean([r["p_below"][n] for r in below])
                line.append(f"{n} p {p_all:.3f}, mean {mean:.3f} (uniform: 0.5 +- "
                            f"{math.sqrt(1 / 12 / len(below)):.3f})")  # fmt: skip
            print(f"  {design}, share of all draws below the truth ({len(below)} replications "
                  "that store it): " + "; ".join(line))  # fmt: skip
    fig.supxlabel("rank of the true value among 99 posterior draws (10 bins); grey: 99 % band")
    fig.tight_layout()
    fig.savefig(figure, dpi=110)
    print(f"figure: {figure}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--design", choices=list(DESIGNS))
    ap.add_argument("--replications", type=int, default=200)
    ap.add_argument(
        "--first-seed", type=int, default=1,
        help="seeds FIRST..FIRST+replications-1 (fresh data for a new sampler: 1)",
    )  # fmt: skip
    ap.add_argument("--draws", type=int, default=500, help="particles per population (500)")
    ap.add_argument("--out", help="JSON lines, appended")
    ap.add_argument("--report", nargs="+", help="JSON lines files: print the table, plot")
    ap.add_argument(
        "--grid-check", type=int, nargs="+", metavar="SEED",
        help="these replications' exact (grid) posterior against SMC: P(parameter < truth)",
    )  # fmt: skip
    ap.add_argument(
        "--figure", default=str(Path(__file__).parent / "figures" / "posterior_sbc.png")
    )
    ap.add_argument(
        "--exact", type=int, nargs=2, metavar=("FIRST", "LAST"),
        help="replications FIRST..LAST: the exact posterior by importance sampling of a prior "
        "bank against SMC's (rows read from --out)",
    )  # fmt: skip
    ap.add_argument(
        "--sharp-exact", type=int, nargs=2, metavar=("FIRST", "LAST"),
        help="as --exact, refined by adaptive importance sampling (3 x 2,000 evaluations each)",
    )  # fmt: skip
    ap.add_argument("--bank", help="the prior bank's cache (.npz; made if missing)")
    ap.add_argument("--bank-size", type=int, default=400_000)
    args = ap.parse_args(argv)
    if args.exact or args.sharp_exact:
        rows = {}
        if args.out and Path(args.out).exists():
            for line in Path(args.out).read_text().splitlines():
                row = json.loads(line)
                rows[row["seed"]] = row
        bank_path = args.bank or Path(tempfile.gettempdir()) / f"sbc_bank_{args.design}.npz"
        bank = prior_bank(args.design, args.bank_size, bank_path)
        if args.sharp_exact:
            first, last = args.sharp_exact
            sharp_exact_check(args.design, list(range(first, last + 1)), bank, rows)
        else:
            exact_check(args.design, list(range(args.exact[0], args.exact[1] + 1)), bank, rows)
        return 0
    if args.report:
        report(args.report, args.figure)
        return 0
    if args.grid_check:
        print("| seed | " + " | ".join(f"{n}: grid / SMC" for n in NAMES) + " |")
        print("|---" * (1 + len(NAMES)) + "|")
        for seed in args.grid_check:
            got = grid_check(args.design, seed, args.draws)
            print(f"| {seed} | " + " | ".join(f"{g:.3f} / {m:.3f}" for g, m in got.values())
                  + " |", flush=True)  # fmt: skip
        return 0
    out = Path(args.out)
    done = len(out.read_text().splitlines()) if out.exists() else 0
    with tempfile.TemporaryDirectory() as tmp:
        first = args.first_seed
        for seed in range(first + done, first + args.replications):
            rep = replication(Path(tmp), args.design, seed, args.draws)
            with out.open("a") as f:
                f.write(json.dumps(rep) + "\n")
            print(json.dumps(rep), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
