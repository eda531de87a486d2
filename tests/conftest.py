"""Every test leaves the ``iem`` logger as it found it: a command run in a test
(``deploy.cli.main``) routes it to that test's captured stderr and stops its propagation,
which would otherwise write later tests' logs to a closed stream and hide them from caplog."""

from __future__ import annotations

import logging

import pytest


@pytest.fixture(autouse=True)
def _restore_iem_logger():
    logger = logging.getLogger("iem")
    saved = (list(logger.handlers), logger.level, logger.propagate)
    yield
    logger.handlers[:], logger.level, logger.propagate = saved
