"""Which normal law do the data support? Model comparison by PSIS-LOO on synthetic data.

For each generating law (Brach-Dunn, DMT, JKR) and each of ``--sets`` data sets: normal
impacts of the Table 1 sphere at 12 speeds (0.15-8 m/s, log-spaced), ``cor_n`` from that law
at its true parameters plus Gaussian noise (``--sigma``, default 0.01); then every law fitted
and its posterior sampled as a user would (``fitting.sample_posterior``, default SMC) with the
priors below, and the three compared by PSIS-LOO (``fitting.compare_models``). The table counts
how often each law wins (the largest elpd), and how often it wins by more than two standard
errors of the difference.

True parameters: Brach-Dunn at Table 1 (C_A 0.882, C_H 0.220 s/m, f0 325 N/m); DMT and JKR
with the same C_H and w = 7.35 and 2.2 J/m^2 (capture speeds about 0.08 and 0.05 m/s against
Brach-Dunn's 0.1 m/s: the three laws stick in the same range of speeds).

Run: ``python benchmarks/normal_law_comparison.py --sets 10 --out results.jsonl`` (appends; a
rerun continues where the file stops), then ``--report results.jsonl``.

Duration: about 20 minutes on 2 cores for ``--sets 10`` (25 with ``--refits 10``).
"""

import argparse
import json
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

LAWS = ("brach_dunn", "dmt", "jkr")
TRUTH = {
    "brach_dunn": {"C_A": 0.882, "C_H": 0.2197, "f0": 325.0},
    "dmt": {"w": 7.35, "C_H": 0.2197},
    "jkr": {"w": 2.2, "C_H": 0.2197},
}
PRIORS = {
    "brach_dunn": {"C_A": (0.05, 20.0), "C_H": (0.02, 2.0), "f0": (10.0, 3000.0)},
    "dmt": {"w": (0.05, 100.0), "C_H": (0.02, 2.0)},
    "jkr": {"w": (0.05, 100.0), "C_H": (0.02, 2.0)},
}
SPEEDS = np.geomspace(0.15, 8.0, 12)


def law_scene(law):
    return jaximpact.table1_scene().with_normal_law(law)


def clean_data(law):
    scene = law_scene(law)
    section = {k: v for k, v in TRUTH[law].items()}
    res = jaximpact.simulate(scene.replace(contact=section), SPEEDS, 0.0, 0.0)
    if not np.all(np.asarray(res.status) == jaximpact.Status.REBOUND):
        raise RuntimeError(f"{law}: the design's impacts must rebound at the truth")
    return np.asarray(res.cor_n)


def write_data(path, values, sigma):
    rows = ["speed,angle_deg,observable,value,sigma"]
    rows += [
        f"{float(s)!r},0.0,cor_n,{float(v)!r},{sigma}" for s, v in zip(SPEEDS, values, strict=True)
    ]
    Path(path).write_text("\n".join(rows) + "\n")


def one_set(law, seed, sigma, clean):
    """Data set ``seed`` of ``law``: each law's posterior and the LOO comparison."""
    rng = np.random.default_rng(seed)
    values = clean + sigma * rng.standard_normal(SPEEDS.size)
    posteriors, runs = {}, {}
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "data.csv"
        write_data(data, values, sigma)
        for fitted in LAWS:
            names = tuple(PRIORS[fitted])
            priors = {n: f"loguniform:{lo}:{hi}" for n, (lo, hi) in PRIORS[fitted].items()}
            centre = {n: float(np.sqrt(lo * hi)) for n, (lo, hi) in PRIORS[fitted].items()}
            t0 = time.perf_counter()
            post = fitting.sample_posterior(
                law_scene(fitted), data, names, priors=priors, initial=centre,
                seed=seed + 7919, progress=False,
            )  # fmt: skip
            posteriors[fitted] = post
            runs[fitted] = {
                "converged": bool(post.converged),
                "wall_s": time.perf_counter() - t0,
                "mean": {n: float(post.summary[n]["mean"]) for n in names},
            }
    rows = fitting.compare_models(posteriors, refit=REFITS > 0, max_refits=max(REFITS, 1))
    return {
        "generated_by": law,
        "seed": seed,
        "sigma": sigma,
        "ranking": [r["name"] for r in rows],
        "elpd_diff": {r["name"]: r["elpd_diff"] for r in rows},
        "se_diff": {r["name"]: r["se_diff"] for r in rows},
        "max_khat": {r["name"]: r["max_khat"] for r in rows},
        "refitted": {r["name"]: r.get("refitted", 0) for r in rows},
        "unreliable": {r["name"]: r.get("unreliable", 0) for r in rows},
        "runs": runs,
    }


REFITS = 0  # --refits


def run(path, sets, sigma):
    done = set()
    if Path(path).exists():
        for line in Path(path).read_text().splitlines():
            row = json.loads(line)
            done.add((row["generated_by"], row["seed"]))
    for law in LAWS:
        clean = clean_data(law)
        for seed in range(1, sets + 1):
            if (law, seed) in done:
                continue
            t0 = time.perf_counter()
            row = one_set(law, seed, sigma, clean)
            with open(path, "a") as fh:
                fh.write(json.dumps(row) + "\n")
            print(
                f"{law} set {seed}: ranking {row['ranking']} ({time.perf_counter() - t0:.0f} s)",
                flush=True,
            )


def report(paths):
    rows = [json.loads(x) for p in paths for x in Path(p).read_text().splitlines()]
    print("| generated by | data sets | won by " + " | ".join(LAWS) + " | won by > 2 se |")
    print("|---|---|" + "---|" * len(LAWS) + "---|")
    for law in LAWS:
        mine = [r for r in rows if r["generated_by"] == law]
        if not mine:
            continue
        wins = {w: sum(r["ranking"][0] == w for r in mine) for w in LAWS}

        def clear(r):
            second = r["ranking"][1]
            return -r["elpd_diff"][second] > 2 * r["se_diff"][second]

        clear_wins = sum(r["ranking"][0] == law and clear(r) for r in mine)
        cells = " | ".join(str(wins[w]) for w in LAWS)
        print(f"| {law} | {len(mine)} | {cells} | {clear_wins} |")
    unconverged = sum(not v["converged"] for r in rows for v in r["runs"].values())
    khat = sum(max(r["max_khat"].values()) > 0.7 for r in rows)
    refitted = sum(sum(r.get("refitted", {}).values()) for r in rows)
    unreliable = sum(max(r.get("unreliable", {"": 0}).values()) > 0 for r in rows)
    wall = np.median([v["wall_s"] for r in rows for v in r["runs"].values()])
    print(
        f"\n{len(rows)} data sets, {3 * len(rows)} posteriors ({unconverged} not converged), "
        f"{khat} data sets with a Pareto k above 0.7; median {wall:.1f} s per posterior"
    )
    if refitted:
        print(
            f"exact leave-one-out refits: {refitted} terms; data sets with a term still "
            f"unreliable (k > 0.7, not refitted or not converged): {unreliable}"
        )


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", type=int, default=10)
    p.add_argument("--sigma", type=float, default=0.01)
    p.add_argument("--out", default="benchmarks/results/normal_law_comparison.jsonl")
    p.add_argument("--report", nargs="+", metavar="FILE")
    p.add_argument(
        "--refits", type=int, default=0,
        help="exact leave-one-out refits of up to N observations with Pareto k > 0.7 per model",
    )  # fmt: skip
    args = p.parse_args(argv)
    global REFITS
    REFITS = args.refits
    if args.report:
        report(args.report)
        return 0
    run(args.out, args.sets, args.sigma)
    report([args.out])
    return 0


if __name__ == "__main__":
    sys.exit(main())
