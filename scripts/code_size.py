#!/usr/bin/env python3
"""Size of the rooms: functions over ~80 lines and modules over ~700 lines in src/skelfuse, and the layers.

docs/architecture.md lists the functions and modules kept over those sizes, each with its reason; this script
finds them, so the list can be checked and kept short. Lines are physical lines (docstrings, comments and
blank lines included), a function from its ``def`` to its last line (nested functions count in their parent
too, and on their own).

Usage::

    python scripts/code_size.py                 # this checkout
    python scripts/code_size.py --root ../other  # another checkout, e.g. to compare before / after
    python scripts/code_size.py --json          # the figures as JSON
"""

from __future__ import annotations

import argparse
import ast
import json
import tomllib
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

FUNCTION_LINES = 80
MODULE_LINES = 700


@dataclass(frozen=True)
class Room:
    """A module or a function, with its size in lines."""

    name: str
    lines: int


def module_sizes(package: Path) -> list[Room]:
    """Every module of ``package`` with its line count, largest first."""
    rooms = [
        Room(str(path.relative_to(package.parent)), len(path.read_text(encoding="utf-8").splitlines()))
        for path in sorted(package.rglob("*.py"))
    ]
    return sorted(rooms, key=lambda r: -r.lines)


def function_sizes(package: Path) -> list[Room]:
    """Every function and method of ``package`` (``module:Class.method``) with its line count, largest first."""
    rooms: list[Room] = []
    for path in sorted(package.rglob("*.py")):
        module = str(path.relative_to(package.parent).with_suffix("")).replace("/", ".")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        rooms += _functions(tree, f"{module}:")
    return sorted(rooms, key=lambda r: -r.lines)


def _functions(node: ast.AST, prefix: str) -> list[Room]:
    found: list[Room] = []
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
            assert child.end_lineno is not None
            found.append(Room(prefix + child.name, child.end_lineno - child.lineno + 1))
            found += _functions(child, f"{prefix}{child.name}.")
        elif isinstance(child, ast.ClassDef):
            found += _functions(child, f"{prefix}{child.name}.")
    return found


def layers(root: Path) -> list[str]:
    """The layers contract of ``[tool.importlinter]`` in pyproject.toml, top layer first."""
    config = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    for contract in config.get("tool", {}).get("importlinter", {}).get("contracts", []):
        if contract.get("type") == "layers":
            return list(contract["layers"])
    return []


def report(root: Path) -> dict[str, object]:
    package = root / "src" / "skelfuse"
    modules, functions = module_sizes(package), function_sizes(package)
    return {
        "modules": len(modules),
        "functions": len(functions),
        "big_modules": [asdict(r) for r in modules if r.lines > MODULE_LINES],
        "long_functions": [asdict(r) for r in functions if r.lines > FUNCTION_LINES],
        "layers": layers(root),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1], help="a checkout")
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    figures = report(args.root)
    if args.json:
        print(json.dumps(figures, indent=1))
        return 0
    big, long = figures["big_modules"], figures["long_functions"]
    assert isinstance(big, list) and isinstance(long, list)
    print(f"{figures['modules']} modules, {len(big)} over {MODULE_LINES} lines:")
    for room in big:
        print(f"  {room['lines']:5d}  {room['name']}")
    print(f"{figures['functions']} functions, {len(long)} over {FUNCTION_LINES} lines:")
    for room in long:
        print(f"  {room['lines']:5d}  {room['name']}")
    print("layers (top first): " + " > ".join(str(layer) for layer in figures["layers"]))  # type: ignore[union-attr]
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
