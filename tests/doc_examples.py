"""The runnable examples of a guide: each ```python block right after an ``<!-- example: NAME -->`` line.

A guide's examples are tests (docs/python-api.md): the tests write each one to a file and run it as a user
would, so an example that drifts from the code fails the suite.
"""

from __future__ import annotations

import re
from pathlib import Path

DOCS = Path(__file__).resolve().parents[1] / "docs"

_EXAMPLE = re.compile(r"<!-- example: (?P<name>[\w.-]+) -->\n```python\n(?P<code>.*?)\n```", re.DOTALL)


def doc_examples(guide: str) -> dict[str, str]:
    """NAME -> source of every example of ``docs/<guide>``; ValueError if it has none or a name twice."""
    text = (DOCS / guide).read_text(encoding="utf-8")
    found: dict[str, str] = {}
    for match in _EXAMPLE.finditer(text):
        if match["name"] in found:
            raise ValueError(f"docs/{guide}: example {match['name']} appears twice")
        found[match["name"]] = match["code"] + "\n"
    if not found:
        raise ValueError(f"docs/{guide} holds no <!-- example: NAME --> python block")
    return found


def write_example(guide: str, name: str, directory: Path) -> Path:
    """Write example ``name`` of ``docs/<guide>`` to ``directory/name`` and return its path."""
    path = directory / name
    path.write_text(doc_examples(guide)[name], encoding="utf-8")
    return path
