"""``skelfuse setup blender``: install an optional heavy component where a person asks for it, saying what,
where and how big, with progress; nothing else installs anything (``export --format fbx`` names this)."""

from __future__ import annotations

import argparse
import shutil
import sys

from skelfuse.cli.commands import COMMAND_HELP
from skelfuse.cli.common import EXIT_ERROR, EXIT_OK
from skelfuse.export.blender import (
    BPY_PYTHON,
    BPY_REQUIREMENT,
    BPY_SIZE_MB,
    SETUP_COMMAND,
    bpy_python,
    bpy_venv_dir,
    bpy_version,
    folder_size_bytes,
    install_bpy,
)
from skelfuse.progress import note


def _cmd_setup_blender(args: argparse.Namespace) -> int:
    venv = bpy_venv_dir()
    python = bpy_python()
    if python is not None and not args.reinstall:
        size_mb = folder_size_bytes(venv) / 1e6
        print(f"Blender's bpy {bpy_version(python)} is installed at {venv} ({size_mb:.0f} MB); nothing to do")
        return EXIT_OK
    if args.check:
        print(
            f"Blender's bpy is not installed at {venv}; `{SETUP_COMMAND}` installs {BPY_REQUIREMENT} there "
            f"(about {BPY_SIZE_MB} MB)"
        )
        return EXIT_ERROR
    free_mb = shutil.disk_usage(venv.parent if venv.parent.exists() else venv.anchor).free / 1e6
    note(
        f"{SETUP_COMMAND}: installing Blender as a Python module ({BPY_REQUIREMENT}, for {BPY_PYTHON}) into "
        f"{venv}: about 400 MB to download, about {BPY_SIZE_MB} MB on disk ({free_mb:.0f} MB free there). It lets "
        "`skelfuse export --format fbx` use Blender's own FBX exporter; remove the folder to uninstall."
    )
    python = install_bpy(log=lambda text: note(f"{SETUP_COMMAND}: {text}"), stream=sys.stderr)
    size_mb = folder_size_bytes(venv) / 1e6
    print(f"Blender's bpy {bpy_version(python)} is installed at {venv} ({size_mb:.0f} MB)")
    return EXIT_OK


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Add ``setup`` with its components."""
    setup = commands.add_parser("setup", help=COMMAND_HELP["setup"])
    components = setup.add_subparsers(dest="setup_command", metavar="COMPONENT", required=True)
    blender = components.add_parser(
        "blender",
        help=f"Blender's bpy for FBX export, in its own environment (about {BPY_SIZE_MB} MB)",
        description=f"Install Blender as a Python module ({BPY_REQUIREMENT}) into its own {BPY_PYTHON} "
        "environment at $SKELFUSE_BPY_VENV, else ~/.cache/skelfuse/bpy-venv (bpy pins numpy < 2, skelfuse needs "
        f"numpy >= 2, so they cannot share one): about 400 MB to download, about {BPY_SIZE_MB} MB on disk, pip's "
        "progress shown. An environment already there is recognised and left as it is. `skelfuse export "
        "--format fbx` uses it and never installs it.",
    )
    blender.add_argument("--check", action="store_true", help="only say whether it is installed (exit 1 if not)")
    blender.add_argument("--reinstall", action="store_true", help="build it again even if one is there")
    blender.set_defaults(func=_cmd_setup_blender)
