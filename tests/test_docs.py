"""The manual's examples stay true: every code block marked runnable in README.md and docs/
runs, against the shipped policy, from the checkout root."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RUNNABLE = "<!-- runnable -->"
"""The line that marks the fenced Python block right below it as one the tests run."""

README_LINES = 150
"""The README is a first page: what terl-rt is, two commands, what you get, links."""


def runnable_blocks(text: str) -> list[str]:
    """The code of every ```python block that follows a RUNNABLE line, in page order."""
    pattern = r"^" + re.escape(RUNNABLE) + r"\n```python\n(.*?)\n```"
    return re.findall(pattern, text, flags=re.S | re.M)


def pages() -> list[Path]:
    return [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


EXAMPLES = [
    pytest.param(code, id=f"{page.relative_to(ROOT)}-{k}")
    for page in pages()
    for k, code in enumerate(runnable_blocks(page.read_text()))
]


def test_a_runnable_mark_is_always_followed_by_a_python_block():
    for page in pages():
        text = page.read_text()
        marks = sum(line == RUNNABLE for line in text.splitlines())
        assert marks == len(runnable_blocks(text)), page


def test_the_manual_has_runnable_examples():
    assert len(EXAMPLES) >= 3


@pytest.mark.parametrize("code", EXAMPLES)
def test_runnable_example_runs(code, monkeypatch):
    monkeypatch.chdir(ROOT)  # the examples name the shipped policy as exported/terl.onnx
    exec(compile(code, "<example>", "exec"), {"__name__": "__example__"})


def test_the_readme_is_a_first_page():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_LINES, f"README.md has {len(lines)} lines, at most {README_LINES}"


def test_the_findings_are_pages_of_one_subject_none_over_300_lines():
    index = (ROOT / "docs" / "training.md").read_text()
    pages = sorted((ROOT / "docs").glob("training-*.md"))
    assert len(pages) >= 4
    for page in pages:
        assert f"]({page.name})" in index, f"docs/training.md links no {page.name}"
        assert len(page.read_text().splitlines()) <= 300, page.name
    assert len(index.splitlines()) <= 300
