"""benchmarks/README.md is the index of the benchmark scripts and of the pages of figures by area.

The pages are text, but what holds them together is checked here: every page the index links to
exists and every page is linked; each entry is headed with its date and the commit it was measured
at, newest first; figures are dated by date and commit, never by a working sitting; and the
commands the index gives name scripts that exist with options those scripts take.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
INDEX = BENCHMARKS / "README.md"
PAGES = sorted(p for p in BENCHMARKS.glob("*.md") if p.name != "README.md")
ENTRY = re.compile(r"^## (\d{4}-\d\d-\d\d), commit ([0-9a-f]{7})\b", re.MULTILINE)
ORDINAL = re.compile(
    r"\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|\w+teenth|"
    r"twentieth|twenty-\w+|thirtieth|last|this|that|an earlier|a later|the same|earlier)'?s? (sitting|session)s?\b",
    re.IGNORECASE,
)


def test_the_index_links_every_page_and_only_pages_that_exist():
    linked = set(re.findall(r"\]\(([\w-]+\.md)\)", INDEX.read_text()))
    assert linked == {p.name for p in PAGES}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_a_page_links_back_to_the_index_and_heads_its_entries_newest_first(page: Path):
    text = page.read_text()
    assert text.startswith("# "), "a page opens with its area as title"
    assert "(README.md)" in text
    dates = [m.group(1) for m in ENTRY.finditer(text)]
    assert dates, "a page holds at least one dated entry"
    assert dates == sorted(dates, reverse=True)
    headings = [line for line in text.splitlines() if line.startswith("## ")]
    assert len(headings) == len(dates), "every entry heading names its date and commit"
    for heading in re.split(r"^## ", text, flags=re.MULTILINE)[1:]:
        assert re.search(r"^Machine: ", heading, re.MULTILINE), heading.splitlines()[0]


@pytest.mark.parametrize("page", [INDEX, *PAGES], ids=lambda p: p.name)
def test_figures_are_dated_by_date_and_commit_not_by_a_sitting(page: Path):
    text = page.read_text()
    assert not ORDINAL.search(text), ORDINAL.search(text)
    assert not re.search(r"\bsitting", text, re.IGNORECASE)
    assert not re.search(r"\bwe (ran|measured|tried)\b", text, re.IGNORECASE)


def test_the_index_commands_name_scripts_and_options_that_exist():
    block = INDEX.read_text().split("## How to run them", 1)[1].split("```")[1]
    commands = [line.split() for line in block.strip().splitlines()]
    assert commands
    scripts = {c[1] for c in commands}
    assert scripts == {f"benchmarks/{p.name}" for p in BENCHMARKS.glob("*.py")}
    for words in commands:
        source = (BENCHMARKS.parent / words[1]).read_text()
        for option in {w.strip("[]|") for w in words[2:] if w.strip("[]|").startswith("--")}:
            assert f'"{option}"' in source, (words[1], option)
