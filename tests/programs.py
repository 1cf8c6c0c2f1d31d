"""Tests that need a program from outside Python (Debian's chromium, mosquitto, systemd's
systemd-analyze): skipped without it, the reason naming the package, and `uv run pytest`
lists every skip with its reason; in CI (CI set, as `.ci/run` sets it, which installs them)
a missing one fails the test instead, so CI never passes with a test skipped for want of it."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


def require_program(path: Path | None, package: str, *, what: str) -> None:
    """Skip (or fail in CI) unless `path` exists; `what` says which tests need it, `package`
    is the Debian package that installs it."""
    if path is not None and path.exists():
        return
    missing = f"{path} is missing" if path is not None else "it is not on PATH"
    if os.environ.get("CI"):
        pytest.fail(
            f"{what} need {package} and {missing}: .ci/run installs it (CI skips nothing)",
            pytrace=False,
        )
    pytest.skip(
        f"{what} need {package} ({missing}: `sudo apt-get install {package}`)",
        allow_module_level=True,
    )
