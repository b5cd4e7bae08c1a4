"""scripts/code_size.py measures what it says (a package written here with known sizes), and every function over
~80 lines and module over ~700 in src/skelfuse is listed in docs/architecture.md ("Rooms kept over size")."""

from __future__ import annotations

import importlib.util
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _code_size():  # the script is not a package module: load it from its file
    spec = importlib.util.spec_from_file_location("code_size", ROOT / "scripts" / "code_size.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["code_size"] = module  # its dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def test_sizes_of_a_package_with_known_rooms(tmp_path: Path) -> None:
    package = tmp_path / "src" / "skelfuse"
    package.mkdir(parents=True)
    body = "\n".join(f"    x{i} = {i}" for i in range(3))
    method_body = "\n".join(f"        x{i} = {i}" for i in range(3))
    (package / "a.py").write_text(
        f"def short():\n{body}\n\n\nclass K:\n    def method(self):\n{method_body}\n"
        "        def inner():\n            pass\n",
        encoding="utf-8",
    )
    (package / "b.py").write_text("\n" * 9, encoding="utf-8")
    code_size = _code_size()
    functions = {room.name: room.lines for room in code_size.function_sizes(package)}
    # hand-counted: def line + 3 body lines; method: def + 3 + inner's 2
    assert functions == {"skelfuse.a:short": 4, "skelfuse.a:K.method": 6, "skelfuse.a:K.method.inner": 2}
    modules = {room.name: room.lines for room in code_size.module_sizes(package)}
    assert modules == {"skelfuse/a.py": 13, "skelfuse/b.py": 9}  # short 4 + 2 blank + class + method 6; 9 newlines


def test_every_big_room_is_listed_with_its_reason() -> None:
    figures = _code_size().report(ROOT)
    text = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = text[text.index("## Rooms kept over size") :]
    listed = {
        m[0]: m[1].strip() for m in re.findall(r"^\| (?:module|function) \| \d+ \| `([^`]+)` \|(.*)\|$", section, re.M)
    }
    missing = [r["name"] for r in figures["big_modules"] if r["name"].removeprefix("skelfuse/") not in listed]
    for room in figures["long_functions"]:
        module, function = room["name"].split(":")
        if f"{module.removeprefix('skelfuse.')}.{function}" not in listed:
            missing.append(room["name"])
    assert not missing, f"over size and not in docs/architecture.md's table (split it, or list it with why): {missing}"
    assert all(listed.values()), "every listed room says why"
