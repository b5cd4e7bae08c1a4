"""The exit codes of ``skelfuse``, one table in docs/service.md ("Exit codes"); argparse's usage errors are
EXIT_USAGE too. A module of their own so that ``skelfuse --help`` and the error mapping load no config (and so
no numpy)."""

from __future__ import annotations

from skelfuse.service.lifecycle import FORCED_EXIT_CODE

EXIT_OK = 0
EXIT_ERROR = 1
EXIT_USAGE = 2
EXIT_ATTENTION = 3  # the result needs a person's attention: a "bad" calibration verdict, a moved sensor
EXIT_STOP_TIMEOUT = FORCED_EXIT_CODE  # a daemon ended by its stop watchdog (service/lifecycle.py)
EXIT_INTERRUPTED = 130
