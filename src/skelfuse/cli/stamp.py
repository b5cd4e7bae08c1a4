"""Where a measurement came from: the command line, the code's revision, the machine and its load.

A command that prints ``--json`` results others quote (``eval paper``, ``eval robustness``, ``eval real``,
``sim check``, ``bench instant``, ``bench latency``) adds this stamp under ``"stamp"``, so that a table built
from the JSON (docs/evidence.md) names what produced it: the producer records it, not whoever renders it. The
1-minute load is taken when the command starts and again when it prints, because on a shared machine a busy
CPU changes speed figures (accuracy figures are seeded and do not depend on it).
"""

from __future__ import annotations

import os
import platform
import shlex
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skelfuse.version import __version__

SOURCE_DIR = Path(__file__).resolve().parents[1]
"""The skelfuse package folder whose revision the stamp names (the code that ran, not the working folder)."""


@dataclass(frozen=True)
class RunStamp:
    """A command's provenance, taken when it starts (the revision too: the tree may change during a long run);
    :meth:`finished` adds the load when it prints."""

    command: str
    revision: str
    load_1min_start: float

    @classmethod
    def begin(cls, argv: Sequence[str], program: Sequence[str] = ("skelfuse",)) -> RunStamp:
        """The stamp of ``PROGRAM ARGV`` (a skelfuse command, or a script such as the soak) starting now."""
        return cls(
            command=shlex.join([*program, *argv]),
            revision=code_revision(),
            load_1min_start=round(os.getloadavg()[0], 2),
        )

    def finished(self) -> dict[str, Any]:
        """The stamp as JSON, with the 1-minute load now, at the end of the run."""
        return {
            "command": self.command,
            "revision": self.revision,
            "version": __version__,
            "machine": {"cpu_model": cpu_model(), "cores": os.cpu_count() or 0},
            "load_1min": {"start": self.load_1min_start, "end": round(os.getloadavg()[0], 2)},
        }


def code_revision(source_dir: Path = SOURCE_DIR) -> str:
    """The commit checked out (12 hex digits) in the git checkout holding ``source_dir``, read from the
    repository's files (asking ``git`` would start a process in every command that prints JSON); ``"unknown
    (...)"`` outside a checkout (an installed wheel). Uncommitted changes are not seen here:
    ``scripts/update_doc_tables.py record`` refuses a tree that has them."""
    git_dir = next((d / ".git" for d in (source_dir, *source_dir.parents) if (d / ".git").exists()), None)
    if git_dir is None:
        return "unknown (not a git checkout)"
    try:
        if git_dir.is_file():  # a worktree or submodule: "gitdir: PATH"
            git_dir = (git_dir.parent / git_dir.read_text(encoding="utf-8").split(":", 1)[1].strip()).resolve()
        head = (git_dir / "HEAD").read_text(encoding="utf-8").strip()
        if not head.startswith("ref: "):
            return head[:12]  # a detached HEAD names its commit
        ref = head.removeprefix("ref: ")
        common = git_dir / "commondir"
        shared = (git_dir / common.read_text(encoding="utf-8").strip()).resolve() if common.is_file() else git_dir
        for base in (git_dir, shared):
            if (base / ref).is_file():
                return (base / ref).read_text(encoding="utf-8").strip()[:12]
        packed = shared / "packed-refs"
        for line in packed.read_text(encoding="utf-8").splitlines() if packed.is_file() else []:
            commit, _, name = line.partition(" ")
            if name == ref:
                return commit[:12]
    except (OSError, IndexError) as exc:
        return f"unknown (git files: {exc})"
    return f"unknown ({ref} not found)"


def cpu_model(cpuinfo: Path = Path("/proc/cpuinfo")) -> str:
    """The CPU's model name (Linux's /proc/cpuinfo), else the machine's architecture (``platform.processor``
    would start a process to ask ``uname``)."""
    try:
        for line in cpuinfo.read_text(encoding="utf-8", errors="replace").splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                return value.strip()
    except OSError:
        pass
    return platform.machine() or "unknown"
