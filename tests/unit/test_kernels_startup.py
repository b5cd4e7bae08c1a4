"""What loading the compiled kernels brings into a process: numba, but neither scipy nor BLAS."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

from skelfuse.fusion import kernels

BLAS_NAMES = {"dot", "vdot", "inner", "outer", "matmul", "linalg", "tensordot", "einsum", "kron"}
"""numpy functions numba computes with BLAS (scipy's), or that reach np.linalg."""


def test_no_kernel_uses_blas():
    """The kernels load numba without scipy (:func:`kernels.import_numba_without_blas`) only because none of them
    calls BLAS: no ``@``, ``np.dot``, ``np.linalg`` and the like."""
    folder = Path(kernels.__file__).parent
    for name in kernels.KERNEL_MODULES:
        tree = ast.parse((folder / f"{name}.py").read_text())
        matmuls = [node.lineno for node in ast.walk(tree) if isinstance(node, ast.MatMult)]
        calls = [
            (node.lineno, node.attr)
            for node in ast.walk(tree)
            if isinstance(node, ast.Attribute) and node.attr in BLAS_NAMES
        ]
        assert not matmuls and not calls, f"kernels/{name}.py uses BLAS: @ at lines {matmuls}, calls {calls}"


NODE_START_PROBE = """
import sys
import skelfuse.service.node as node
node.prepare_kernels("probe")
print("scipy" in sys.modules, "numba" in sys.modules)
import scipy.linalg  # refused only while numba's array math loaded
print(scipy.linalg.__name__)
"""


@pytest.mark.live  # a fresh interpreter
def test_preparing_the_kernels_imports_numba_but_not_scipy():
    done = subprocess.run(
        [sys.executable, "-c", NODE_START_PROBE], capture_output=True, text=True, timeout=600, check=True
    )
    assert done.stdout.split() == ["False", "True", "scipy.linalg"]
