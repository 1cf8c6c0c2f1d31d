"""Every file in config/examples passes `hermsd check-config` as `run` reads it, and the
docs point at each one, so an example a brewer copies is one the daemon takes."""

from __future__ import annotations

from pathlib import Path

import pytest

from hermsd.cli import commands as cli

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = sorted((ROOT / "config" / "examples").glob("*.yaml"))
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_the_examples_are_there() -> None:
    names = {path.name for path in EXAMPLES}
    assert names >= {"web.yaml", "mqtt.yaml", "two-elements.yaml", "relay-board.yaml"}
    assert "herms.yaml" in names


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda path: path.name)
def test_check_config_takes_the_example(example: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["check-config", str(example)]) == 0
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("example", EXAMPLES, ids=lambda path: path.name)
def test_the_docs_link_the_example(example: Path) -> None:
    named = f"config/examples/{example.name}"
    assert any(named in doc.read_text(encoding="utf-8") for doc in DOCS), named
