"""README.md and BENCHMARKS.md are written for users: no project history in them (issue
numbers, numbered sessions or rounds of work, internal loop names); that history lives in
CHANGELOG.md. Reads files only."""

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).parents[1]
USER_DOCS = ("README.md", "BENCHMARKS.md")

# Each pattern is history a user cannot act on. An option name such as `--issue12`
# is not matched: the number must follow "issue" after a space.
HISTORY = {
    "an issue number": r"\bissues?\s+(?:no\.?\s*)?\d+",
    "a tracker reference": r"(?<![\w&/])#\d+\b",
    "a numbered session": r"\b(?:first|second|third|fourth|fifth|sixth|seventh|\d+(?:st|nd|rd|th))"
    r"\s+session\b",
    "a numbered round of work": r"\bround\s+\d+\b|\b(?:first|second|third|fourth|fifth)\s+round\b",
    "an internal loop name": r"\blean\s+(?:step\s+)?loop\b|\b_fast_loop\b|\bpooled\s+loop\b",
}


@pytest.mark.parametrize("name", USER_DOCS)
def test_user_docs_speak_without_project_history(name):
    text = (ROOT / name).read_text(encoding="utf-8")
    found = []
    for what, pattern in HISTORY.items():
        for m in re.finditer(pattern, text, flags=re.IGNORECASE):
            line = text.count("\n", 0, m.start()) + 1
            found.append(f"{name}:{line}: {what}: {m.group(0)!r}")
    assert not found, "history belongs in CHANGELOG.md:\n" + "\n".join(found)


def test_history_patterns_catch_what_they_should():
    history = [
        "BENCHMARKS.md, Throughput (issue 12)",
        "see the issue 10 notes",
        "after issues 11 and 14",
        "fixed in #13",
        "Fifth session (2026-11-24)",
        "round 3 of the work",
        "the lean loop as the default",
    ]
    for text in history:
        assert any(re.search(p, text, flags=re.IGNORECASE) for p in HISTORY.values()), text
    fine = [
        "`python benchmarks/throughput.py --issue12` prints these tables",
        "no host round trip per evaluation",
        "[Accuracy](#accuracy) and ## headings",
        "&#39; in HTML",
    ]
    for text in fine:
        assert not any(re.search(p, text, flags=re.IGNORECASE) for p in HISTORY.values()), text


def test_benchmarks_sections_named_in_the_docs_exist():
    """Pointers such as `BENCHMARKS.md, "Fit time"` in README.md, CHANGELOG.md and docs/ name a
    heading of BENCHMARKS.md."""
    headings = {
        line.lstrip("#").strip()
        for line in (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8").splitlines()
        if line.startswith("#")
    }
    missing = []
    for path in [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]:
        text = path.read_text(encoding="utf-8")
        for m in re.finditer(r'BENCHMARKS\.md[,;:]?\s*\(?"([^"]+)"', text):
            name = " ".join(m.group(1).split())  # a name wrapped over two lines
            if name not in headings:
                missing.append(f"{path.relative_to(ROOT)}: {name!r}")
    assert not missing, "no such section in BENCHMARKS.md: " + ", ".join(missing)


def _readme_scene_table():
    """``{(section, key)}`` named in README's scene reference table."""
    text = (ROOT / "README.md").read_text()
    keys, section = set(), None
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if not line.startswith("|") or len(cells) < 3:
            continue
        if cells[0].startswith("`["):
            section = cells[0].strip("`[]")
        for group in re.findall(r"`([^`]+)`", cells[1]):
            keys.update((section, key.strip()) for key in group.split(","))
    return keys


def test_readme_scene_table_names_every_scene_key():
    """Every key a scene file accepts is in README's reference table (the table missed
    ``[model] tangential``, ``[contact] G_star`` and ``[priors]``)."""
    from jaximpact._io.scene_files import ALLOWED

    documented = _readme_scene_table()
    missing = [
        f"[{section}] {key}"
        for section, keys in ALLOWED.items()
        if section != "priors"
        for key in keys
        if (section, key) not in documented
    ]
    assert not missing, missing
    assert (
        any(section == "priors" for section, _ in documented)
        or "`[priors]`" in (ROOT / "README.md").read_text()
    )


def test_readme_states_the_code_defaults():
    """README's defaults are the code's (it said ring_width 1e-6 where the code used 1e-8)."""
    import jax.numpy as jnp

    import jaximpact as ji
    from jaximpact._engine.solvers import default_slip_width, default_tolerances

    def g(x):  # README's spelling of a small number: 3e-4, not 0.0003 or 3e-04
        return f"{x:.0e}".replace("e-0", "e-")

    text = (ROOT / "README.md").read_text()
    row = next(line for line in text.splitlines() if "`slip_width`, `ring_width`" in line)
    assert f"ring: {g(ji.Solver().ring_width)}" in row
    assert f"slip: {g(default_slip_width(jnp.float64, None))} in float64" in row
    assert f"{g(default_slip_width(jnp.float32, None))} in float32" in row
    row = next(line for line in text.splitlines() if "| `rtol`, `atol` |" in line)
    for dtype, name in ((jnp.float64, "float64"), (jnp.float32, "float32")):
        rtol, atol = default_tolerances(dtype, None, None)
        assert f"{g(rtol)}/{g(atol)} in {name}" in row
    row = next(line for line in text.splitlines() if "`max_steps`, `dt`, `stiffness_limit`" in line)
    s = ji.Solver()
    assert f"({s.max_steps})" in row and f"({s.dt:g})" in row
    assert f"({s.stiffness_limit:g})" in row
