"""Regenerate the sections of BENCHMARKS.md that name `run_all.py`, and benchmarks/figures/*.png.

Run: ``python benchmarks/run_all.py [--quick] [--only SECTION ...] [-o FILE] [--note TEXT]``
(full: about 20 minutes on 2 idle cores, more under load; ``--quick``: fewer impacts and
settings, for checking the pipeline).

Sections (name: heading in BENCHMARKS.md):

- ``work_precision``: "Accuracy against cost";
- ``stability``: "Stability catalogue";
- ``throughput``: "By batch size and scene options" (under "Throughput");
- ``gradient``: "Gradient cost" (under "Derivatives");
- ``terms``: "What a scene can leave out" (its impacts/s come from ``throughput`` when both
  run);
- ``fit``: "Fit time" (fit and simulate end to end in fresh processes, cold and warm cache).

Each section replaces only itself in the file: from its heading to the next heading of the
same or a higher level, written atomically; every other section stays as it is. A full run
writes BENCHMARKS.md and the figures; ``--quick`` prints the sections instead unless ``-o FILE``
is given. ``--stdout`` prints without writing. A run that writes no file puts its figures in a
temporary folder, not over the published ones. The rows of the
"At a glance" table for the measured sections are printed at the end: that table is edited by
hand. Timings on a shared machine are noisy: medians of repeats, and ratios measured in the
same run.
"""

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

import _common  # noqa: E402
import fit_benchmark  # noqa: E402
import gradient_cost  # noqa: E402
import stability  # noqa: E402
import term_contributions  # noqa: E402
import throughput  # noqa: E402
import work_precision  # noqa: E402
from _common import ROOT, machine, replace_section, write_result  # noqa: E402
from summary import at_a_glance  # noqa: E402

# name -> the section writer: (quick, info, note, command, data of the sections run before)
# -> (Markdown of the section from its heading, data)
SECTIONS = {
    "work_precision": lambda q, i, n, c, d: work_precision.run(q, i, n, c),
    "stability": lambda q, i, n, c, d: stability.run(q, i, n, c),
    "throughput": lambda q, i, n, c, d: throughput.run(q, i, n, c),
    "gradient": lambda q, i, n, c, d: gradient_cost.run(q, i, n, c),
    "terms": lambda q, i, n, c, d: term_contributions.run(q, i, n, c, d.get("throughput")),
    "fit": lambda q, i, n, c, d: fit_benchmark.run(q, i, n, c),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer impacts and settings")
    ap.add_argument("--only", nargs="+", choices=list(SECTIONS), help="run these sections")
    ap.add_argument(
        "-o",
        "--output",
        help="the file whose sections are replaced (default: BENCHMARKS.md; "
        "with --quick: none, the sections are printed)",
    )
    ap.add_argument("--stdout", action="store_true", help="print the sections, write nothing")
    ap.add_argument("--note", help="a sentence about the run for every section's measured line")
    args = ap.parse_args()
    output = args.output or (None if args.quick else str(ROOT / "BENCHMARKS.md"))
    if args.stdout:
        output = None
    if not output:
        _common.FIGURES = Path(tempfile.mkdtemp(prefix="benchmark-figures-"))
        print(f"[run_all] figures go to {_common.FIGURES}", file=sys.stderr)
        if not os.environ.get("JAXIMPACT_BENCHMARK_RESULTS"):  # nor the result files
            os.environ["JAXIMPACT_BENCHMARK_RESULTS"] = str(_common.FIGURES)
    data = {}
    for name, writer in SECTIONS.items():
        if args.only and name not in args.only:
            continue
        command = "python benchmarks/run_all.py " + ("--quick " if args.quick else "")
        command += f"--only {name}"
        t = time.perf_counter()
        print(
            f"[run_all] {name} ... (load average {os.getloadavg()[0]:.1f})",
            file=sys.stderr,
            flush=True,
        )
        info = machine()
        text, data[name] = writer(args.quick, info, args.note, command, data)
        seconds = time.perf_counter() - t
        write_result(f"run_all_{name}", data[name], info, command)
        if output:
            replace_section(Path(output), text)
            print(
                f"[run_all] {name} done in {seconds:.0f} s: section {text.splitlines()[0]!r} "
                f"of {output} replaced",
                file=sys.stderr,
                flush=True,
            )
        else:
            print(text, flush=True)
            print(f"[run_all] {name} done in {seconds:.0f} s", file=sys.stderr, flush=True)
    glance = at_a_glance(data)
    if glance:
        print(
            '\n[run_all] rows of "At a glance" for the sections measured (edited by hand):\n',
            file=sys.stderr,
        )
        print(glance, file=sys.stderr)


if __name__ == "__main__":
    main()
