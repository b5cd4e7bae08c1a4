"""One way to close a zenoh session: ``service/zenoh_io.py`` ``close_session`` (bounded), never a raw close.

zenoh's ``Session.close()`` has no timeout and waits on the session's links: towards a peer that stopped reading
it can take seconds (2.5 s measured on loopback), so a raw close makes a process's stop depend on its peers.
"""

from __future__ import annotations

import ast
from pathlib import Path

import skelfuse

PACKAGE = Path(skelfuse.__file__).resolve().parent
THE_CLOSE = PACKAGE / "service" / "zenoh_io.py"


def _raw_closes(source: str) -> list[int]:
    """Lines that close a session directly: ``<...session...>.close()`` or ``with zenoh.open(...)``."""
    lines: list[int] = []
    if ".close(" not in source and "zenoh.open" not in source:  # most modules: nothing to parse
        return lines
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "close":
            receiver = ast.unparse(node.func.value)
            if "session" in receiver.lower():
                lines.append(node.lineno)
        elif isinstance(node, ast.With | ast.AsyncWith):
            for item in node.items:
                if "zenoh.open" in ast.unparse(item.context_expr):
                    lines.append(node.lineno)
    return sorted(lines)


def test_sessions_are_closed_through_close_session_only() -> None:
    offenders = {
        str(path.relative_to(PACKAGE)): lines
        for path in sorted(PACKAGE.rglob("*.py"))
        if path != THE_CLOSE and (lines := _raw_closes(path.read_text(encoding="utf-8")))
    }
    assert offenders == {}, "close zenoh sessions with skelfuse.service.zenoh_io.close_session"


def test_the_rule_catches_both_forms_of_a_raw_close() -> None:
    source = "import zenoh\nsession.close()\nwith zenoh.open(conf) as s:\n    pass\nself._session.close()\nf.close()\n"
    assert _raw_closes(source) == [2, 3, 5]
