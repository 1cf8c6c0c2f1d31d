"""bench/RESULTS.md: each section says the commit, date and command it was measured with.

bench/sections.py writes a script's section; bench/all.py checks the whole file.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
from bench_scripts import BENCH, load

SECTIONS = load("sections")
ALL = load("all")

MEASURED = re.compile(
    r"Measured at commit [0-9a-f]{7,}( \(with uncommitted changes\))? on \d{4}-\d\d-\d\d "
    r"with `uv run python bench/x\.py --write`\."
)


def test_every_section_of_results_says_where_it_was_measured() -> None:
    assert ALL.problems(SECTIONS.RESULTS) == []


def test_a_section_is_written_under_its_heading_with_the_measured_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(sys, "argv", [str(BENCH / "x.py"), "--write"])
    results = tmp_path / "RESULTS.md"
    results.write_text(
        "# Benchmark results\n\n## Control socket: one\n\nold one\n\n"
        "## Control socket: two\n\nold two\n",
        encoding="utf-8",
    )
    SECTIONS.write("## Control socket: two", "new two\n", results)
    text = results.read_text(encoding="utf-8")
    one, two = text.split("## Control socket: two\n\n")
    assert one == "# Benchmark results\n\n## Control socket: one\n\nold one\n\n"
    measured, body = two.split("\n\n")
    assert MEASURED.fullmatch(measured), measured
    assert body == "new two\n"


def test_a_heading_that_only_begins_like_another_does_not_replace_it(tmp_path: Path) -> None:
    results = tmp_path / "RESULTS.md"
    results.write_text("## Faults on the family: two\n\nkept\n", encoding="utf-8")
    SECTIONS.replace(results, "## Faults on the family", "## Faults on the family\n\nnew\n")
    assert results.read_text(encoding="utf-8") == (
        "## Faults on the family: two\n\nkept\n\n## Faults on the family\n\nnew\n"
    )


def test_a_section_without_its_measured_line_is_found(tmp_path: Path) -> None:
    results = tmp_path / "RESULTS.md"
    results.write_text(
        "## Alerts: what the control loop pays\n\n"
        "Measured by hand at commit 8c45470 on 2026-11-27 with `uv run python bench/alerts.py`."
        "\n\n## Web page\n\n`uv run python bench/web.py` on 2 cores\n",
        encoding="utf-8",
    )
    found = ALL.problems(results)
    assert "'## Web page': its first line does not say where it was measured" in found
    assert not any("Alerts" in problem for problem in found)
