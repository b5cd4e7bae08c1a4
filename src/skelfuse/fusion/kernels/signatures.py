"""The numba types of the kernels' explicit signatures.

Each live kernel is compiled for one signature given up front (``numba.njit(signature)``): it compiles when its
module loads, never again for another array layout or read-only-ness, and refuses arguments of other types
instead of compiling for them in the middle of a fusion. Array arguments are C-contiguous and declared read-only
unless the kernel writes into them: a read-only array type accepts writable arrays as well.
"""

from __future__ import annotations

import numba
from numba.core import types

FLOAT = numba.float64
INT = numba.int64
INT32 = numba.int32
BOOL = numba.boolean
UINT8 = numba.uint8


def array(dtype: types.Type, ndim: int, writable: bool = False) -> types.Array:
    """A C-contiguous array argument of ``ndim`` dimensions; read-only unless ``writable`` (the kernel writes it)."""
    return types.Array(dtype, ndim, "C", readonly=not writable)


UINT8 = numba.uint8
INT16 = numba.int16
