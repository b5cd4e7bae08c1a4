"""Fixtures of the live-service tests (helpers in service_helpers.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from service_helpers import Processes

from skelfuse.service.zenoh_io import free_port


@pytest.fixture
def processes(tmp_path: Path) -> Iterator[Processes]:
    """Starts skelfuse subprocesses; kills whatever is still running at teardown."""
    procs = Processes(tmp_path)
    try:
        yield procs
    finally:
        procs.cleanup()


@pytest.fixture
def node_port() -> int:
    return free_port()
