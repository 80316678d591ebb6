"""Rows of BENCHMARKS.md's "At a glance" table for the sections ``run_all.py`` just measured.

"At a glance" also draws on sections that ``run_all.py`` does not measure (accuracy,
throughput's default path, the scipy comparison, posterior, sweeps, test suite), so it is
edited by hand; ``run_all.py`` prints these rows for that.
"""

import numpy as np
from _common import fmt, table


def at_a_glance(data):
    """Markdown table (question, answer, section) from the data of ``run_all``'s sections."""
    rows = []
    fit = data.get("fit")
    if fit:
        med = {k: float(np.median(v)) for k, v in fit.items() if k not in ("same", "json")}
        rows.append(
            [
                "How long does a fit take?",
                f"3 parameters, 25 impacts: {med['fit cold']:.1f} s from a cold cache, "
                f"{med['fit warm']:.1f} s warm",
                "[Fit time](#fit-time)",
            ]
        )
    grad = data.get("gradient")
    if grad and grad["rows"]:
        ratios = [r["grad"] / r["values"] for r in grad["rows"] if r["sets"] > 1]
        ratios = ratios or [r["grad"] / r["values"] for r in grad["rows"]]
        rows.append(
            [
                "What does a gradient cost?",
                f"{min(ratios):.1f}-{max(ratios):.1f}x a value (`jax.grad`), in one flat batch",
                "[Gradient cost](#gradient-cost)",
            ]
        )
    stab = data.get("stability")
    if stab:
        defaults = [
            r
            for r in stab
            if r["error"] is not None
            and not r["name"].startswith("tsit5 forced")
            and not r.get("ill_conditioned")
        ]
        good = [r for r in defaults if np.isfinite(r["error"]) and r["error"] < 1e-3]
        nonfinite = [r for r in stab if r["status"] == "nonfinite"]
        worst = max((r["error"] for r in good), default=float("nan"))
        rows.append(
            [
                "Do stiff and extreme cases work?",
                f"{len(stab)} catalogue cases, "
                + ("no NaN" if not nonfinite else f"**{len(nonfinite)} non-finite**")
                + f"; {len(good)} of {len(defaults)} cases with a reference within 1e-3 "
                f"(largest error {fmt(worst)})",
                "[Stability catalogue](#stability-catalogue)",
            ]
        )
    if not rows:
        return ""
    return table(["question", "answer", "section"], rows) + "\n"
