"""The demo's runs, as :mod:`skelfuse.apps.demo` loads them on first use: live (:func:`run_demo`, the real
service on loopback, :mod:`~skelfuse.apps.demo.live`) and offline (:func:`run_demo_offline`,
:mod:`~skelfuse.apps.demo.offline`), their summary (:mod:`~skelfuse.apps.demo.summary`) and the demo rig's
files (:mod:`~skelfuse.apps.demo.rigfile`).
"""

from __future__ import annotations

from skelfuse.apps.demo.live import RESULT_GRACE_S, STARTUP_TIMEOUT_S, TAKE_ORIGIN_DELAY_S, run_demo
from skelfuse.apps.demo.offline import run_demo_offline
from skelfuse.apps.demo.rigfile import sim_sensor_tables, write_calibration, write_demo_rig
from skelfuse.apps.demo.scorer import LiveScorer
from skelfuse.apps.demo.summary import DemoSummary, format_summary, group_errors, scoring_window

__all__ = [
    "RESULT_GRACE_S",
    "STARTUP_TIMEOUT_S",
    "TAKE_ORIGIN_DELAY_S",
    "DemoSummary",
    "LiveScorer",
    "format_summary",
    "group_errors",
    "run_demo",
    "run_demo_offline",
    "scoring_window",
    "sim_sensor_tables",
    "write_calibration",
    "write_demo_rig",
]
