"""The table of targets at the top of BENCHMARKS.md, from the result files and targets.toml.

Run: ``python -m benchmarks targets`` (or ``python benchmarks/targets.py``) writes the table
between ``<!-- targets:begin -->`` and ``<!-- targets:end -->`` in BENCHMARKS.md; ``--check``
writes nothing and exits 1 when the committed table differs from the one the files give;
``--stdout`` prints the table.

Each row is a ``[[target]]`` of ``benchmarks/targets.toml`` (its comments say the fields): the
figure is read from a result file under ``benchmarks/results/`` (with the machine and date
that file records) or, where no result file holds it, kept by hand in targets.toml. Reads
files only: nothing is measured.

Duration: seconds.
"""

import argparse
import json
import re
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "benchmarks" / "results"
TARGETS = ROOT / "benchmarks" / "targets.toml"
DOC = ROOT / "BENCHMARKS.md"
BEGIN, END = "<!-- targets:begin -->", "<!-- targets:end -->"
HEADER = ["figure", "target", "measured", "met", "CPU", "date", "where"]


def load_targets(path=TARGETS):
    """The ``[[target]]`` entries of targets.toml, in order."""
    with open(path, "rb") as f:
        return tomllib.load(f)["target"]


def lookup(data, path):
    """The values at ``path`` in ``data``: keys joined by ".", "*" for every item of a list or
    dict, a number for one item of a list, ``[key=value,key=value]`` for the items of a list
    of dicts whose fields have those values (as text), e.g.
    ``figures.[entry point=simulate 3,cache=cold].wall``."""
    values = [data]
    for key in re.findall(r"\[[^\]]*\]|[^.]+", path):
        nxt = []
        for v in values:
            if key.startswith("["):
                want = dict(kv.split("=", 1) for kv in key[1:-1].split(","))
                nxt.extend(
                    item for item in v if all(str(item.get(k)) == x for k, x in want.items())
                )
            elif key == "*":
                nxt.extend(v.values() if isinstance(v, dict) else v)
            elif isinstance(v, list):
                nxt.append(v[int(key)])
            else:
                nxt.append(v[key])
        values = nxt
    return values


def short_cpu(cpu):
    """'Intel(R) Xeon(R) Processor (AVX-512)' -> 'Intel Xeon (AVX-512)'."""
    cpu = cpu.replace("(R)", "").replace("(TM)", "")
    cpu = re.sub(r"\s+(?:\d+-Core\s+)?Processor\b", "", cpu)
    cpu = re.sub(r"\s+CPU\s+@\s+[\d.]+GHz", "", cpu)
    return " ".join(cpu.split())


def machine_of(data):
    """``(cpu, date)`` a result file records, or ``(None, None)``."""
    info = data.get("info") or data.get("machine") if isinstance(data, dict) else None
    if isinstance(info, dict) and "cpu" in info:
        cores = f", {info['cores']} cores" if info.get("cores") else ""
        return short_cpu(info["cpu"]) + cores, str(info.get("date", ""))[:10] or None
    measured = data.get("measured") if isinstance(data, dict) else None
    if isinstance(measured, str):
        m = re.search(
            r"Measured (\d{4}-\d\d-\d\d)[^,]*, commit [^,]*, (.*?), (\d+) cores", measured
        )
        if m:
            return f"{short_cpu(m.group(2))}, {m.group(3)} cores", m.group(1)
    return None, None


def row(entry, results=RESULTS):
    """``{"figure", "target", "measured", "met", "cpu", "date", "section", "source"}``."""
    out = {k: entry[k] for k in ("figure", "target", "section")}
    if "result" in entry:
        path = Path(results) / entry["result"]
        data = json.loads(path.read_text(encoding="utf-8"))
        values = [float(v) for v in lookup(data, entry["value"])]
        reduce = entry.get("reduce")
        if len(values) != 1 and reduce not in ("max", "min"):
            raise ValueError(f"{entry['result']}: {entry['value']} gives {len(values)} numbers")
        value = max(values) if reduce == "max" else min(values) if reduce == "min" else values[0]
        ok = ("at_most" not in entry or value <= entry["at_most"]) and (
            "at_least" not in entry or value >= entry["at_least"]
        )
        cpu, date = machine_of(data)
        out.update(
            measured=entry.get("format", "{:g}").format(value),
            met="yes" if ok else "no",
            cpu=cpu or entry.get("cpu", "not recorded"),
            date=date or entry.get("date", "not recorded"),
            source=f"benchmarks/results/{entry['result']}",
        )
    else:
        out.update({k: entry[k] for k in ("measured", "met", "cpu", "date")})
        out["source"] = "benchmarks/targets.toml"
    if entry.get("note"):
        out["measured"] += f" ({entry['note']})"
    return out


def anchor(heading):
    """The link target GitHub and mkdocs give a heading (lower case, punctuation dropped)."""
    slug = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return "#" + slug.replace(" ", "-")


def table(entries=None, results=RESULTS):
    """The Markdown of the targets table (with a line that counts them), from targets.toml."""
    rows = [row(e, results) for e in (load_targets() if entries is None else entries)]
    n_met = sum(r["met"] == "yes" for r in rows)
    lines = [
        "| " + " | ".join(HEADER) + " |",
        "|" + "---|" * len(HEADER),
    ]
    for r in rows:
        where = f"[{r['section']}]({anchor(r['section'])})"
        if r["source"] != "benchmarks/targets.toml":
            where += f", `{r['source']}`"
        met = r["met"] if r["met"] == "yes" else f"**{r['met']}**"
        cells = [r["figure"], r["target"], r["measured"], met, r["cpu"], r["date"], where]
        lines.append("| " + " | ".join(cells) + " |")
    intro = (
        f"{len(rows)} targets, {n_met} met. Generated by `python -m benchmarks targets` from "
        "`benchmarks/results/` and `benchmarks/targets.toml` (figures without a result file, "
        "kept by hand); each row's section says how it was measured. Timings are of 2-core "
        "machines: a row's CPU and date say which run."
    )
    return intro + "\n\n" + "\n".join(lines) + "\n"


def replace_between(text, body):
    """``text`` with what lies between the markers replaced by ``body``."""
    start, end = text.index(BEGIN) + len(BEGIN), text.index(END)
    return text[:start] + "\n" + body + text[end:]


def committed(text):
    """The table between the markers of ``text``."""
    return text[text.index(BEGIN) + len(BEGIN) : text.index(END)].lstrip("\n")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if BENCHMARKS.md's table differs")
    ap.add_argument("--stdout", action="store_true", help="print the table, write nothing")
    ap.add_argument("-o", "--output", default=str(DOC), help="the file (default BENCHMARKS.md)")
    args = ap.parse_args(argv)
    body = table()
    if args.stdout:
        print(body, end="")
        return 0
    path = Path(args.output)
    text = path.read_text(encoding="utf-8")
    if args.check:
        same = committed(text) == body
        print("the targets table is up to date" if same else f"{path}: the targets table differs")
        return 0 if same else 1
    new = replace_between(text, body)
    if new != text:
        sys.path.insert(0, str(Path(__file__).resolve().parent))
        from _common import write_atomic

        write_atomic(path, new)
    print(f"{path}: {body.splitlines()[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
