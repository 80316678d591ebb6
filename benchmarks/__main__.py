"""``python -m benchmarks`` (from the repository root): list the benchmarks, run one, or write
the table of targets.

    python -m benchmarks --list
    python -m benchmarks NAME [--quick] [--dry-run] [ARGS ...]   # ARGS go to the script
    python -m benchmarks targets [--check]                       # BENCHMARKS.md's targets

NAME runs ``python benchmarks/NAME.py ARGS`` in a child process (the script as it runs on its
own: its own argument parsing and output); ``stability`` and ``work_precision`` are sections
of ``run_all.py`` and run as ``run_all.py --only NAME``. ``--quick`` puts the script's small
mode's arguments first (``--list`` shows them, or why a script has none) and sends the result
files to a temporary folder, so that a smoke run never replaces a committed result.
"""

import os
import shlex
import subprocess
import sys
import tempfile

from benchmarks import MODULES, command, describe, scripts


def _list():
    names = list(scripts())
    width = max(len(n) for n in names)
    for name in names:
        d = describe(name)
        print(f"{name:<{width}}  {d['description']}")
        if name in MODULES:
            print(f"{'':<{width}}  {d['quick']}")
        else:
            print(f"{'':<{width}}  run time: {d['run_time']}; {d['quick']}")


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(__doc__)
        return 0
    if argv[0] == "--list":
        _list()
        return 0
    name, rest = argv[0], argv[1:]
    quick, dry = "--quick" in rest, "--dry-run" in rest
    rest = [a for a in rest if a not in ("--quick", "--dry-run")]
    try:
        cmd = [sys.executable, *command(name, quick, rest)]
    except KeyError:
        print(f"no benchmark {name!r}: python -m benchmarks --list", file=sys.stderr)
        return 2
    except ValueError as e:
        print(e, file=sys.stderr)
        return 2
    if dry:
        print(shlex.join(cmd))
        return 0
    env = dict(os.environ)
    if quick:
        env["JAXIMPACT_BENCHMARK_RESULTS"] = tempfile.mkdtemp(prefix="benchmark-results-")
        print(f"[benchmarks] quick run; result files go to {env['JAXIMPACT_BENCHMARK_RESULTS']}",
              file=sys.stderr)  # fmt: skip
    return subprocess.run(cmd, env=env).returncode


if __name__ == "__main__":
    sys.exit(main())
