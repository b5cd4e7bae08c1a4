"""The numba types of the kernels' explicit signatures.

Each live kernel is compiled for one signature given up front (``numba.njit(signature)``): it compiles when its
module loads, never again for another array layout or read-only-ness, and refuses arguments of other types
instead of compiling for them in the middle of a fusion. Array arguments are C-contiguous and declared read-only
unless the kernel writes into them: a read-only array type accepts writable arrays as well.
"""

from __future__ import annotations

from typing import Any

import numba
from numba.core import types

FLOAT = numba.float64
INT = numba.int64
INT32 = numba.int32
BOOL = numba.boolean
UINT8 = numba.uint8


KERNEL: dict[str, Any] = {"cache": True, "nogil": True, "error_model": "numpy", "no_cfunc_wrapper": True}
"""numba's options for a kernel (a function the fusion calls): cached on disk, no fastmath, no C-pointer wrapper
(nothing takes a kernel's address)."""

HELPER: dict[str, Any] = {"nogil": True, "error_model": "numpy", "no_cpython_wrapper": True, "no_cfunc_wrapper": True}
"""numba's options for a helper (a function only kernels call): no wrapper for a call from Python or through a C
pointer and no cache file of its own (a kernel's cache holds the helper code linked into it); each was LLVM work
and a disk write at a first start."""


def array(dtype: types.Type, ndim: int, writable: bool = False) -> types.Array:
    """A C-contiguous array argument of ``ndim`` dimensions; read-only unless ``writable`` (the kernel writes it)."""
    return types.Array(dtype, ndim, "C", readonly=not writable)


UINT8 = numba.uint8
INT16 = numba.int16
