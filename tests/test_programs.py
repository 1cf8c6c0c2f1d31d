"""A test that needs a program from outside Python: skipped with the package named outside
CI, failed in CI (which installs it), never passed unseen."""

from __future__ import annotations

from pathlib import Path

import pytest
from programs import require_program


def test_a_missing_program_is_a_skip_that_names_the_package(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.delenv("CI", raising=False)
    missing = tmp_path / "mosquitto"
    with pytest.raises(pytest.skip.Exception) as skipped:
        require_program(missing, "mosquitto", what="the MQTT bridge's tests")
    assert str(skipped.value) == (
        f"the MQTT bridge's tests need mosquitto ({missing} is missing: "
        "`sudo apt-get install mosquitto`)"
    )


def test_in_ci_a_missing_program_fails_instead(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match=r"\.ci/run installs it \(CI skips nothing\)"):
        require_program(None, "systemd", what="the unit checks")


def test_a_program_that_is_there_is_neither(tmp_path: Path) -> None:
    present = tmp_path / "chromium"
    present.touch()
    require_program(present, "chromium", what="the browser tests")
