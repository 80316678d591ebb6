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


SCENE_REFERENCE = ROOT / "docs" / "scene_files.md"


def _scene_table():
    """``{(section, key)}`` named in the scene reference table (docs/scene_files.md)."""
    text = SCENE_REFERENCE.read_text()
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


def test_scene_table_names_every_scene_key():
    """Every key a scene file accepts is in the reference table of docs/scene_files.md (the
    table missed ``[model] tangential``, ``[contact] G_star`` and ``[priors]``)."""
    from jaximpact._io.scene_files import ALLOWED

    documented = _scene_table()
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
        or "`[priors]`" in SCENE_REFERENCE.read_text()
    )


def test_scene_reference_states_the_code_defaults():
    """The scene reference's defaults are the code's (it said ring_width 1e-6 where the code
    used 1e-8)."""
    import jax.numpy as jnp

    import jaximpact as ji
    from jaximpact._engine.solvers import default_slip_width, default_tolerances

    def g(x):  # the reference's spelling of a small number: 3e-4, not 0.0003 or 3e-04
        return f"{x:.0e}".replace("e-0", "e-")

    text = SCENE_REFERENCE.read_text()
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


README_MAX_LINES = 250


def test_readme_is_a_front_door():
    """README.md stays short (the details live in docs/) and names no dated timings."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= README_MAX_LINES
    dates = re.findall(r"\b20\d\d-\d\d-\d\d\b", text)
    assert not dates, f"dated figures belong in BENCHMARKS.md: {dates}"


def test_readme_test_command_is_what_ci_runs():
    """README's install-and-test command is the one .ci/run runs."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    install = re.search(r"pip install -e (\S+)", re.search(r"python -m pip install -e \S+", ci)[0])
    assert install, "no install line in .ci/run"
    command = f"pip install -e {install[1]} && python -m pytest -q"
    assert command in readme, command
    assert "\npython -m pytest -q\n" in ci


def test_docs_pages_are_in_the_site_nav():
    """Every page under docs/ is in mkdocs.yml's nav (mkdocs also warns, in its strict build)."""
    nav = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    pages = [p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")]
    assert pages
    missing = [p for p in pages if not p.startswith("notebooks/") and p not in nav]
    assert not missing, missing


def test_readme_links_resolve():
    """README's relative links (to docs/ pages, notebooks, figures) name files that exist; the
    site's own links are checked by its strict build."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
    assert targets
    missing = [t for t in targets if "://" not in t and not (ROOT / t).exists()]
    assert not missing, missing
