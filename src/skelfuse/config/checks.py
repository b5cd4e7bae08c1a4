"""The validation primitives of the rig config: typed access to one TOML table with messages that name the
file, the key path, what was expected and what was found (and a "did you mean" for a misspelt key)."""

from __future__ import annotations

import difflib
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skelfuse.schema.errors import ConfigError

REQUIRED = object()


def describe(value: Any) -> str:
    if value is None:
        return "nothing"
    text = repr(value)
    if len(text) > 60:
        text = text[:57] + "..."
    return f"{text} ({type(value).__name__})"


def did_you_mean(word: str, candidates: Sequence[str]) -> str:
    by_lower = {c.lower(): c for c in candidates}
    close = difflib.get_close_matches(word.lower(), list(by_lower), n=1, cutoff=0.6)
    return f"; did you mean {by_lower[close[0]]!r}?" if close else ""


class Table:
    """One TOML table being read: remembers which keys were consumed so leftovers are reported."""

    def __init__(self, data: Any, path: str, source: str, base_dir: Path | None) -> None:
        self.path, self.source, self.base_dir = path, source, base_dir
        if not isinstance(data, dict):
            raise self.error(path or "<top level>", "a table", data)
        self.data: dict[str, Any] = data
        self.used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.path}.{name}" if self.path else name

    def error(self, key: str, expected: str, found: Any, hint: str = "") -> ConfigError:
        return ConfigError(f"{self.source}: key {key}: expected {expected}, found {describe(found)}{hint}")

    def raw(self, name: str, default: Any, expected: str) -> Any:
        self.used.add(name)
        if name in self.data:
            return self.data[name]
        if default is REQUIRED:
            raise ConfigError(f"{self.source}: key {self.key(name)} is required ({expected}) but missing")
        return default

    def string(
        self,
        name: str,
        default: Any = REQUIRED,
        *,
        choices: Sequence[str] | None = None,
        check: Callable[[str], str] | None = None,
    ) -> Any:
        expected = f"one of {', '.join(repr(c) for c in choices)}" if choices else "a string"
        value = self.raw(name, default, expected)
        if value is default and name not in self.data:
            return value
        if not isinstance(value, str):
            raise self.error(self.key(name), expected, value)
        if choices is not None and value not in choices:
            raise self.error(self.key(name), expected, value, did_you_mean(value, choices))
        if check is not None:
            try:
                check(value)
            except (TypeError, ValueError) as exc:
                raise ConfigError(f"{self.source}: key {self.key(name)}: {exc}") from None
        return value

    def integer(
        self, name: str, default: Any = REQUIRED, *, lo: int | None = None, hi: int | None = None, unit: str = ""
    ) -> Any:
        expected = range_text("an integer", lo, hi, unit)
        value = self.raw(name, default, expected)
        if value is default and name not in self.data:
            return value
        if (
            isinstance(value, bool)
            or not isinstance(value, int)
            or (lo is not None and value < lo)
            or (hi is not None and value > hi)
        ):
            raise self.error(self.key(name), expected, value)
        return value

    def number(
        self,
        name: str,
        default: Any = REQUIRED,
        *,
        lo: float | None = None,
        hi: float | None = None,
        lo_open: bool = False,
        unit: str = "",
    ) -> Any:
        expected = range_text("a number", lo, hi, unit, lo_open=lo_open)
        value = self.raw(name, default, expected)
        if value is default and name not in self.data:
            return value
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        if ok and lo is not None:
            ok = value > lo if lo_open else value >= lo
        if ok and hi is not None:
            ok = value <= hi
        if not ok:
            raise self.error(self.key(name), expected, value)
        return float(value)

    def boolean(self, name: str, default: Any = REQUIRED) -> Any:
        value = self.raw(name, default, "true or false")
        if not isinstance(value, bool):
            raise self.error(self.key(name), "true or false", value)
        return value

    def strings(self, name: str, default: Any = REQUIRED) -> Any:
        value = self.raw(name, default, "a list of strings")
        if value is default and name not in self.data:
            return value
        if not isinstance(value, list) or not all(isinstance(v, str) and v for v in value):
            raise self.error(self.key(name), "a list of non-empty strings", value)
        return tuple(value)

    def path_value(self, name: str, default: Any = REQUIRED) -> Any:
        value = self.string(name, default)
        if value is default and name not in self.data:
            return value
        if not value.strip():
            raise self.error(self.key(name), "a non-empty path", value)
        path = Path(value).expanduser()
        if not path.is_absolute() and self.base_dir is not None:
            path = self.base_dir / path
        return path

    def table(self, name: str, *, required: bool = False) -> Table | None:
        self.used.add(name)
        if name not in self.data:
            if required:
                raise ConfigError(f"{self.source}: table [{self.key(name)}] is required but missing")
            return None
        return Table(self.data[name], self.key(name), self.source, self.base_dir)

    def done(self) -> None:
        """Raise on the first key nobody asked for."""
        for name in self.data:
            if name not in self.used:
                known = sorted(self.used)
                where = f"[{self.path}]" if self.path else "the top level"
                raise ConfigError(
                    f"{self.source}: unknown key {self.key(name)}{did_you_mean(name, known)}; "
                    f"keys allowed in {where}: {', '.join(known)}"
                )


def range_text(what: str, lo: float | None, hi: float | None, unit: str, *, lo_open: bool = False) -> str:
    unit = f" {unit}" if unit else ""
    if lo is not None and hi is not None:
        return f"{what} in {'(' if lo_open else '['}{lo:g}, {hi:g}]{unit}"
    if lo is not None:
        return f"{what} {'>' if lo_open else '>='} {lo:g}{unit}"
    if hi is not None:
        return f"{what} <= {hi:g}{unit}"
    return what + unit


def rigid_4x4(value: Any, key: str, source: str) -> tuple[tuple[float, ...], ...]:
    expected = "a 4x4 list of numbers (rigid transform: rotation, translation in mm, last row 0 0 0 1)"
    if not (
        isinstance(value, list)
        and len(value) == 4
        and all(isinstance(r, list) and len(r) == 4 for r in value)
        and all(isinstance(v, int | float) and not isinstance(v, bool) for r in value for v in r)
    ):
        raise ConfigError(f"{source}: key {key}: expected {expected}, found {describe(value)}")
    matrix = np.array(value, dtype=np.float64)
    if not np.isfinite(matrix).all():
        raise ConfigError(f"{source}: key {key}: expected finite numbers, found NaN or inf")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise ConfigError(f"{source}: key {key}: expected last row [0, 0, 0, 1], found {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    error = float(np.abs(rotation @ rotation.T - np.eye(3)).max())
    if error > 1e-4 or np.linalg.det(rotation) < 0:
        raise ConfigError(
            f"{source}: key {key}: expected a rotation in the upper-left 3x3 (orthonormal, det +1, "
            f"to 1e-4), found max |R R^T - I| = {error:.3g}, det = {np.linalg.det(rotation):.4f}; "
            f"write at least 6 decimals, or re-run `skelfuse calibrate ...`"
        )
    return tuple(tuple(float(v) for v in row) for row in value)
