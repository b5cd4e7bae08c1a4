"""A stand-in for what a zenoh subscriber callback receives, as far as skelfuse reads it (``key_expr``,
``payload`` with ``len()`` and ``to_bytes()``): feeds ``SampleQueue`` and the node's loop without a network.
Importable from every test folder (``pythonpath`` in pyproject.toml's pytest settings)."""

from __future__ import annotations


class FakePayload:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def __len__(self) -> int:
        return len(self.data)

    def to_bytes(self) -> bytes:
        return self.data


class FakeSample:
    def __init__(self, key_expr: str, data: bytes) -> None:
        self.key_expr = key_expr
        self.payload = FakePayload(data)
