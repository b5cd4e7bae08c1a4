"""Fixtures shared by the unit tests."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
from recorder_progress import RecorderProgress


@pytest.fixture
def recorder_progress(monkeypatch: pytest.MonkeyPatch) -> RecorderProgress:
    """Counts what ``skelfuse.service.recorder.run_recorder`` hands its writer, by payload kind."""
    from skelfuse.service import recorder

    progress = RecorderProgress()

    def counted(kind: str, method: Callable[..., Any]) -> Callable[..., Any]:
        def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
            try:
                return method(self, *args, **kwargs)
            finally:
                progress.handled[kind] += 1

        return wrapper

    base = recorder.RecordingWriter
    methods = {"write_payload": "sensor", "write_fused_payload": "fused", "write_clouds_payload": "clouds"}
    counting = type(
        "CountingRecordingWriter", (base,), {name: counted(kind, getattr(base, name)) for name, kind in methods.items()}
    )
    monkeypatch.setattr(recorder, "RecordingWriter", counting)
    return progress
