"""The README stays a product page and the results page a page: the sizes the docs are written to."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_readme_is_a_product_page() -> None:
    text = (ROOT / "README.md").read_text()
    lines = text.splitlines()
    assert len(lines) <= 120, f"README.md has {len(lines)} lines (at most 120; findings belong in docs/)"
    assert len(text.split()) <= 1200, f"README.md has {len(text.split())} words (at most 1,200)"
    long = [number for number, line in enumerate(lines, 1) if len(line) > 300]
    assert not long, f"README.md lines over 300 characters: {long}"


def test_the_results_page_is_at_most_600_lines() -> None:
    lines = (ROOT / "docs" / "results.md").read_text().splitlines()
    assert len(lines) <= 600, f"docs/results.md has {len(lines)} lines (at most 600: details go to their own pages)"
