"""Compiled kernels of the per-instant path (numba), loaded on first use.

The stages whose numpy form spends most of its time in numpy's per-call overhead (dozens of small array calls
per instant) run as plain loops compiled by numba: the candidate selection and the DBSCAN merge (:mod:`.merge`),
the per-joint filters and their one-step prediction (:mod:`.filters`), the plausibility stage (:mod:`.plausibility`),
the temporal left/right realignment (:mod:`.realign`), the seen tracks' motion update (:mod:`.tracks`), the
orientation stage (:mod:`.orientation`), the association's costs and Hungarian assignment (:mod:`.association`),
the position uncertainty (:mod:`.uncertainty`) and the rig's stacking of an instant's bodies in the world frame
(:mod:`.stacking`). Their numpy
forms live on in :mod:`skelfuse.fusion.reference` as the test reference, which the live path never imports.

How the kernels are built, and why:

* Loaded lazily: importing :mod:`skelfuse.fusion` (or running ``skelfuse --help``, or any command that does not
  fuse) imports no numba. The first :func:`load` imports numba and the kernel modules.
* Compiled once, cached on disk (``cache=True``) in a user cache directory, so a read-only install works:
  ``$NUMBA_CACHE_DIR`` when the user set it, else ``$XDG_CACHE_HOME/skelfuse/numba`` (``~/.cache/skelfuse/numba``;
  ``%LOCALAPPDATA%\\skelfuse\\numba`` on Windows). numba writes its cache files atomically, so processes that
  compile at once (test workers, two nodes) share the directory safely.
* One explicit signature per live kernel (:mod:`.signatures`): float64 / int64 / bool arrays, C-contiguous,
  read-only where the kernel only reads them. Each compiles once, when its module loads; a call with other types
  is refused, never compiled in the middle of a fusion.
* A first start (no cache, on two cores or more) compiles the kernel modules in two child processes at once
  (:func:`compile_in_processes`): a cold compile is numba's typing and LLVM on one core, so that halves the wait.
* Few compiled functions, and helpers over scalars: numba types, lowers and optimizes every helper on its own and
  again inside each caller, so the first start's compile time grows with their number and depth, not with the
  loops' length.
* Helpers (the functions only kernels call) are built without the wrappers a call from Python or through a C
  pointer needs and without a cache of their own (:data:`.signatures.HELPER`): a kernel's cache holds the helpers'
  code linked into it, so each helper's wrappers and cache files were only LLVM work and disk writes at a first
  start. The kernels themselves have no C-pointer wrapper either (:data:`.signatures.KERNEL`).
* No ``np.zeros`` in a kernel: each distinct (shape, dtype) of it compiles an implementation and a fill of its own
  on top of ``np.empty``'s; the kernels take ``np.empty`` and write every element (clearing it where needed).
* Single-threaded (the capture PC's cores belong to the body trackers) and no fastmath: NaN joints are data, and
  fastmath may assume they never occur.
* Debugging: ``NUMBA_DISABLE_JIT=1`` runs the same kernels as plain Python (slow, but a debugger steps into them).
"""

from __future__ import annotations

import hashlib
import logging
import os
import subprocess
import sys
from functools import cache
from pathlib import Path
from types import ModuleType
from typing import NamedTuple

import numpy as np

KERNEL_MODULES = (
    "merge",
    "filters",
    "plausibility",
    "realign",
    "tracks",
    "orientation",
    "association",
    "uncertainty",
    "stacking",
)
"""The kernel modules of this package (one per compiled stage)."""

log = logging.getLogger(__name__)


class Kernels(NamedTuple):
    """The loaded kernel modules."""

    merge: ModuleType
    filters: ModuleType
    plausibility: ModuleType
    realign: ModuleType
    tracks: ModuleType
    orientation: ModuleType
    association: ModuleType
    uncertainty: ModuleType
    stacking: ModuleType


def kernel_array(values: np.ndarray, dtype: type, shape: tuple[int, ...], name: str) -> np.ndarray:
    """An argument as a kernel reads it (C order, its dtype), its shape checked: compiled code does not check its
    indices."""
    out: np.ndarray = np.ascontiguousarray(values, dtype=dtype)
    if out.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {out.shape}")
    return out


def cache_dir() -> Path:
    """Where numba keeps the compiled kernels: ``$NUMBA_CACHE_DIR``, else the user's cache directory."""
    configured = os.environ.get("NUMBA_CACHE_DIR")
    if configured:
        return Path(configured)
    if sys.platform == "win32" and os.environ.get("LOCALAPPDATA"):
        return Path(os.environ["LOCALAPPDATA"]) / "skelfuse" / "numba"
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "skelfuse" / "numba"


def is_cached() -> bool:
    """Whether every kernel module has compiled code in :func:`cache_dir` (else the next :func:`warm_up` compiles).

    numba keeps a source folder's kernels in ``<folder name>_<sha1 of its absolute path>`` and names the index files
    ``<module>.<function>-<line>.pyXY.nbi``; a kernel module counts as cached when one such file of it exists. (A
    cache of an older numba or source is still rebuilt by numba on load; this answers "is this the first start".)
    """
    folder = os.path.dirname(os.path.abspath(__file__))  # as numba spells it
    cached = cache_dir() / f"{os.path.basename(folder)}_{hashlib.sha1(folder.encode()).hexdigest()}"
    if not cached.is_dir():
        return False
    return all(any(cached.glob(f"{name}.*.nbi")) for name in KERNEL_MODULES)


def use_user_cache_dir() -> None:
    """Point numba's cache at :func:`cache_dir`: ``NUMBA_CACHE_DIR`` unless the user set it, and numba's own
    setting where numba was imported before (it reads the environment once, into a module attribute).

    Runs when this package is imported, so before any kernel module is (a kernel's cache location is fixed when
    its module defines it), and again in :func:`load`. Loads no numba.
    """
    os.environ.setdefault("NUMBA_CACHE_DIR", str(cache_dir()))
    config = sys.modules.get("numba.core.config")
    if config is not None and not getattr(config, "CACHE_DIR", ""):
        config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]  # type: ignore[attr-defined]  # numba's run-time setting


@cache
def load() -> Kernels:
    """Import numba (its cache directory set first) and the kernel modules; the kernels compile on first call."""
    use_user_cache_dir()
    import_numba_without_blas()
    import skelfuse.fusion.kernels.association
    import skelfuse.fusion.kernels.filters
    import skelfuse.fusion.kernels.merge
    import skelfuse.fusion.kernels.orientation
    import skelfuse.fusion.kernels.plausibility
    import skelfuse.fusion.kernels.realign
    import skelfuse.fusion.kernels.stacking
    import skelfuse.fusion.kernels.tracks
    import skelfuse.fusion.kernels.uncertainty

    return Kernels(
        merge=skelfuse.fusion.kernels.merge,
        filters=skelfuse.fusion.kernels.filters,
        plausibility=skelfuse.fusion.kernels.plausibility,
        realign=skelfuse.fusion.kernels.realign,
        tracks=skelfuse.fusion.kernels.tracks,
        orientation=skelfuse.fusion.kernels.orientation,
        association=skelfuse.fusion.kernels.association,
        uncertainty=skelfuse.fusion.kernels.uncertainty,
        stacking=skelfuse.fusion.kernels.stacking,
    )


def import_numba_without_blas() -> None:
    """Import numba's array-math implementations without letting them import scipy.linalg (a third of a later
    start).

    numba loads its implementations (``numba.np.arraymath`` among them) when its first function compiles or loads
    from the cache, and that module probes for BLAS at import by importing ``scipy.linalg``, whatever the
    functions use. The kernels use no BLAS (no ``np.dot``, ``@`` or ``np.linalg``; a test checks their source),
    so the probe is answered "no scipy" here: the import of scipy is refused while that module loads, and allowed
    again right after (numba then computes a 1-D ``np.dot`` with its own loop; ``np.linalg`` and 2-D products
    still import scipy when they compile). Where scipy.linalg is already imported, it costs nothing and numba
    imports as usual.
    """
    if "numba.np.arraymath" in sys.modules or "scipy.linalg" in sys.modules:
        return
    refused = "scipy" if "scipy" not in sys.modules else "scipy.linalg"
    sys.modules[refused] = None  # type: ignore[assignment]  # importlib's "refuse this import" marker
    try:
        import numba.np.arraymath  # noqa: F401  # the BLAS probe runs now, and finds no scipy
    finally:
        del sys.modules[refused]


COMPILE_GROUPS = (
    ("orientation", "merge", "tracks", "plausibility", "uncertainty"),
    ("association", "filters", "realign", "stacking"),
)
"""The kernel modules a first start compiles in two processes at once, about half the compile time each (a cold
compile is numba's typing and LLVM, one core per process)."""

_COMPILE_GROUP = (
    "import importlib, sys; [importlib.import_module(f'{sys.argv[1]}.{m}').warm_up() for m in sys.argv[2:]]"
)


def compile_in_processes(groups: tuple[tuple[str, ...], ...] = COMPILE_GROUPS) -> None:
    """Compile the kernel modules into :func:`cache_dir`, each group in a child process, all at once.

    What a first start runs on a machine of two cores or more: it takes about half the time of compiling them
    here, and :func:`load` then reads their caches. A child that fails is reported and its modules compile in
    this process when loaded, where their error is raised.
    """
    use_user_cache_dir()
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # this process's skelfuse
    children = [
        subprocess.Popen(
            [sys.executable, "-c", _COMPILE_GROUP, __name__, *group], env=env, stderr=subprocess.PIPE, text=True
        )
        for group in groups
    ]
    for group, child in zip(groups, children, strict=True):
        _, errors = child.communicate()
        if child.returncode != 0:
            log.warning(
                "compiling the kernels %s in a child process failed (exit %s): %s", group, child.returncode, errors
            )


def warm_up() -> None:
    """Compile (or load from the cache) every kernel now, and run each on tiny inputs of its signature.

    With no cache and no kernel loaded yet, on two cores or more, the modules compile in two processes at once
    (:func:`compile_in_processes`)."""
    if not is_cached() and not load.cache_info().currsize and (os.cpu_count() or 1) > 1:
        compile_in_processes()
    kernels = load()
    for module in kernels:
        module.warm_up()


use_user_cache_dir()
