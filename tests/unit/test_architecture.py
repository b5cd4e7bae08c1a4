"""The import rules of docs/architecture.md that import-linter cannot state (it checks the layers in CI).

Imports inside functions are kept for heavy or optional third-party packages, which only the command that
needs them should load, and for our own modules that load them (the simulator, the evaluation, the fusion
pipeline's scipy, Rerun): each command imports what it runs, so that every ``--help`` and every daemon
starts at once. Any other import of our own modules or of the standard library inside a function is
either hiding a cycle or hiding a dependency, and belongs at the top of the module; a test below checks
that each of our modules imported lazily really does load something heavy.
"""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

import skelfuse

PACKAGE = Path(skelfuse.__file__).resolve().parent

#: Third-party packages a function may import lazily: heavy to load, or optional (an extra).
LAZY_ALLOWED = {
    "numba",  # only the fusion path compiles kernels (skelfuse.fusion.kernels.load)
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
    "scipy",  # its optimize / signal / stats take most of a daemon's start-up to import; loaded where used
}
#: Our modules a function may import lazily beyond the heavy ones (test_our_lazy_imports_are_heavy): none (a
#: module that wraps an optional package imports the package in a function, as skelfuse.bench.reference does).
LAZY_OURS_ALLOWED: set[str] = set()
#: What makes one of our modules heavy enough to import lazily: loading one of these.
HEAVY = ("scipy", "rerun", "cv2", "matplotlib", "numba", "skelfuse.sim", "skelfuse.eval", "skelfuse.bench")


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
    if module.startswith("."):
        return True
    if top == "skelfuse":
        return False  # checked by test_our_lazy_imports_are_heavy
    return top in sys.stdlib_module_names or top not in LAZY_ALLOWED


#: An indented import of one of our modules: a file without one has no function-local import of ours. Every
#: test process computes the parameters below while it collects, so only the files that match are parsed.
_INDENTED_OWN_IMPORT = re.compile(r"^[ \t]+(?:from[ \t]+skelfuse\b|import[ \t][^\n]*\bskelfuse\b)", re.MULTILINE)


def _our_lazy_imports() -> list[str]:
    return sorted(
        {
            module
            for path in PACKAGE.rglob("*.py")
            if _INDENTED_OWN_IMPORT.search(path.read_text(encoding="utf-8"))
            for _, module in _function_local_imports(path)
            if module.split(".")[0] == "skelfuse" and module not in LAZY_OURS_ALLOWED
        }
    )


@pytest.mark.parametrize("path", sorted(PACKAGE.rglob("*.py")), ids=lambda p: str(p.relative_to(PACKAGE)))
def test_no_function_local_imports_but_heavy_optional_packages(path: Path) -> None:
    bad = [f"line {line}: {module}" for line, module in _function_local_imports(path) if _offending(module)]
    assert not bad, f"{path.relative_to(PACKAGE)} imports inside functions (move to the top): {bad}"


@pytest.mark.live  # starts an interpreter to see what the module loads
def test_the_rule_catches_a_hidden_import(tmp_path: Path) -> None:
    sample = tmp_path / "sample.py"
    sample.write_text("def f():\n    from skelfuse.wire import keys\n    import rerun\n    import json\n")
    assert [m for _, m in _function_local_imports(sample) if _offending(m)] == ["json"]
    assert not _loads_heavy("skelfuse.wire")  # ... and test_our_lazy_imports_are_heavy refuses skelfuse.wire


def _loads_heavy(module: str) -> list[str]:
    """The heavy packages a fresh interpreter loads to import ``module``."""
    probe = (
        f"import sys, importlib; importlib.import_module({module!r}); "
        f"print(sorted({{h for h in {HEAVY!r} for m in sys.modules if m == h or m.startswith(h + '.')}}))"
    )
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True)
    return ast.literal_eval(done.stdout.strip().splitlines()[-1])


@pytest.mark.live  # starts an interpreter per module
@pytest.mark.parametrize("module", _our_lazy_imports())
def test_our_lazy_imports_are_heavy(module: str) -> None:
    """An own module imported inside a function must be one that loads something heavy; else: at the top."""
    assert _loads_heavy(module), f"{module} loads nothing heavy: import it at the top of the module"
