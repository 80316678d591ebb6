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
