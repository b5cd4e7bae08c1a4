"""The numba types of the kernels' explicit signatures.

Each public kernel is compiled for one signature given up front (``numba.njit(signature)``): it compiles when its
module loads, never again for another array layout or read-only-ness, and refuses arguments of other types
instead of compiling for them. Array arguments are C-contiguous; a table the wrappers keep read-only is declared
read-only, which accepts writable arrays too.
"""

from __future__ import annotations

import numba
from numba.core import types

FLOAT = numba.float64
INT = numba.int64
BOOL = numba.boolean


def array(dtype: types.Type, ndim: int, readonly: bool = False) -> types.Array:
    """A C-contiguous array type of ``ndim`` dimensions (read-only: accepts writable arrays as well)."""
    return types.Array(dtype, ndim, "C", readonly=readonly)
