"""The ``lab`` fixture: a :class:`netns_lab.Lab`, skipped with the reason where namespaces cannot be made."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from netns_lab import Lab, netns_unavailable


@pytest.fixture
def lab(tmp_path: Path) -> Iterator[Lab]:
    reason = netns_unavailable()
    if reason is not None:
        pytest.skip(reason)
    the_lab = Lab(tmp_path)
    try:
        yield the_lab
    finally:
        the_lab.cleanup()
