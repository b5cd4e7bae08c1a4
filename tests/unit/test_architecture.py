"""The import rules of docs/architecture.md that import-linter cannot state (it checks the layers in CI).

Imports inside functions are kept for heavy or optional third-party packages, which only the command that
needs them should load; an import of our own modules or of the standard library inside a function is
either hiding a cycle or hiding a dependency, and belongs at the top of the module.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

import skelfuse

PACKAGE = Path(skelfuse.__file__).resolve().parent

#: Third-party packages a function may import lazily: heavy to load, or optional (an extra).
LAZY_ALLOWED = {
    "zenoh",
    "rerun",
    "cv2",
    "matplotlib",
    "pyarrow",
    "pyk4a",
    "bpy",
    "sklearn",
    "filterpy",
    "ezc3d",
    "pylsl",
    "cryptography",  # only `skelfuse certs` needs it
}
#: Our modules a function may import lazily: none (a module that wraps an optional package imports the package
#: in a function, as skelfuse.bench.reference does with the dev extra's scikit-learn and filterpy).
LAZY_OURS_ALLOWED: set[str] = set()


def _function_local_imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for func in ast.walk(tree):
        if not isinstance(func, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(func):
            if isinstance(node, ast.ImportFrom):
                found.append((node.lineno, "." * node.level + (node.module or "")))
            elif isinstance(node, ast.Import):
                found += [(node.lineno, alias.name) for alias in node.names]
    return found


def _offending(module: str) -> bool:
    top = module.split(".")[0]
    if module.startswith(".") or top == "skelfuse":
        return module not in LAZY_OURS_ALLOWED
    return top in sys.stdlib_module_names or top not in LAZY_ALLOWED


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_function_local_imports_but_heavy_optional_packages(path: Path) -> None:
    bad = [f"line {line}: {module}" for line, module in _function_local_imports(path) if _offending(module)]
    assert not bad, f"{path.relative_to(PACKAGE)} imports inside functions (move to the top): {bad}"


def test_the_rule_catches_a_hidden_import(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("def f():\n    from skelfuse.wire import keys\n    import rerun\n    import json\n")
    assert [m for _, m in _function_local_imports(sample) if _offending(m)] == ["skelfuse.wire", "json"]
