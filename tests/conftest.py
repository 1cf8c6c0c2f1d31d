"""Shared test fixtures."""

from __future__ import annotations

import logging
from collections.abc import Iterator

import pytest


@pytest.fixture(autouse=True)
def _restore_hermsd_logger() -> Iterator[None]:
    """`hermsd.cli.main` points the logger at the stderr of its moment; undo it after a test."""
    logger = logging.getLogger("hermsd")
    saved = (list(logger.handlers), logger.level, logger.propagate)
    yield
    logger.handlers[:], logger.level, logger.propagate = saved


@pytest.fixture(autouse=True)
def _own_runtime_directory(
    tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each test its own $XDG_RUNTIME_DIR: a simulated daemon's socket lives at one fixed
    place per user, which neither the user's own simulated daemon nor another test run of
    the same user may share."""
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path_factory.mktemp("runtime")))
