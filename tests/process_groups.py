"""Ending the process groups a test started: one definition for the service and network-namespace tests.
Importable from every test folder (``pythonpath`` in pyproject.toml's pytest settings)."""

from __future__ import annotations

import os
import signal
import subprocess
import time


def kill_group(process: subprocess.Popen[bytes], wait_s: float = 5.0) -> None:
    """SIGKILL the process group of ``process`` (started with ``start_new_session=True``) if it still runs,
    and reap it; a group that is already gone is fine."""
    if process.poll() is None:
        try:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        process.wait(wait_s)


def stop_group(
    process: subprocess.Popen[bytes], sig: int = signal.SIGTERM, timeout_s: float = 15.0, dump_stacks: bool = False
) -> bool:
    """Send ``sig`` to the process group of ``process`` and wait up to ``timeout_s``; True if it ended in time
    (or was already gone). Past the time: SIGUSR1 first when ``dump_stacks`` (skelfuse writes every thread's
    stack to its log on it), then SIGKILL and reap, and False."""
    if process.poll() is not None:
        return True
    try:
        os.killpg(process.pid, sig)
        process.wait(timeout_s)
    except ProcessLookupError:
        pass
    except subprocess.TimeoutExpired:
        if dump_stacks:
            os.killpg(process.pid, signal.SIGUSR1)
            time.sleep(0.5)
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(5.0)
        return False
    return True
