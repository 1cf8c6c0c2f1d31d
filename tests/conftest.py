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
