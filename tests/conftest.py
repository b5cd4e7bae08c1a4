"""Rules the whole suite keeps: tiers that say their cost, time limits, and skips that cannot hide a broken install.

- ``live``: a test whose body starts a process, a zenoh session (a router too) or a network namespace must
  carry the marker; one that does so unmarked fails, naming what it started, so the inner loop
  ``pytest -m "not live and not soak"`` stays free of them.
- Time limits (pytest-timeout): ``timeout`` in pyproject.toml for every test; live tests get
  ``LIVE_TIMEOUT_S`` unless they set their own ``@pytest.mark.timeout``. A limit bounds a hang; it is not a
  claim about speed.
- Longest files first: with ``--dist loadfile`` a test file runs whole on one worker, so the files that take
  longest (``LONGEST_FILES``) start first and the workers end together; the rest follow in pytest-randomly's
  shuffled order.
- Under ``CI=true`` a skip fails unless its reason is a missing optional extra, absent ``../shared/data`` or a
  Blender environment that cannot be built (``skelfuse setup blender``): a required or dev dependency that
  does not import is a broken install, and CI must say so.
"""

from __future__ import annotations

import gc
import multiprocessing.process
import os
import re
import subprocess
import sys
from collections.abc import Callable, Iterator
from typing import Any

# This process caches bytecode in __pycache__ (git ignores it) even where the environment sets
# PYTHONDONTWRITEBYTECODE: without the cache every xdist worker rewrites the asserts of every test module and
# compiles skelfuse again on every run, about half of collection's time. Processes the tests start keep the
# environment as it is.
sys.dont_write_bytecode = False

# One thread per process in native libraries (OpenMP: scikit-learn's DBSCAN in the reference fuser; OpenBLAS),
# set before any of them loads and inherited by the processes tests start. Their threads spin while they wait
# for each other; on a busy machine, or beside a second xdist worker, that made a 4-point DBSCAN take 0.2 s
# instead of 2 ms. Results do not depend on it. A value set in the environment wins.
for _variable in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import pytest  # noqa: E402
import zenoh  # noqa: E402

pytest_plugins = ["pytester"]  # tests/unit/test_suite_rules.py runs these rules on small suites

LIVE_TIMEOUT_S = 600.0

# Reasons a skip may give under CI=true; every such skip names one of these in its reason.
ALLOWED_CI_SKIP = re.compile(r"optional extra|shared/data|skelfuse setup blender", re.IGNORECASE)

# The test files that take longest (seconds of test time each, ``--durations=0`` summed per file on the 2-core
# machine), longest first. Started first, they cannot be the last file a worker picks up while the other idles
# (longest-processing-time-first scheduling; xdist's own order, by number of tests, ignores their cost).
LONGEST_FILES = (
    "tests/service/test_demo_web_view.py",  # 31 s
    "tests/service/test_service_live.py",  # 18 s
    "tests/service/test_demo_sigterm.py",  # 14 s
    "tests/service/test_demo_attach.py",  # 14 s
    "tests/service/test_daemon_stops.py",  # 13 s
    "tests/unit/test_eval_paper.py",  # 12 s, the longest of the inner loop
    "tests/service/test_worker_hang.py",  # 12 s
    "tests/unit/test_calibrate_refine.py",  # 8 s
    "tests/service/test_node_overload.py",  # 8 s
    "tests/unit/test_eval_depth.py",  # 7 s
    "tests/unit/test_calibrate_commands.py",  # 7 s
    "tests/unit/test_calib_skeleton.py",  # 6 s
    "tests/unit/test_realign_rear_view.py",  # 5 s
    "tests/unit/test_inputs.py",  # 5 s
)

_running: dict[str, Any] = {"item": None, "started": []}


def _recording(what: str, function: Callable[..., Any]) -> Callable[..., Any]:
    """Wraps ``function`` to note ``what`` it starts while a test's body runs."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        if _running["item"] is not None:
            _running["started"].append(what)
        return function(*args, **kwargs)

    wrapper.__wrapped__ = function  # type: ignore[attr-defined]
    return wrapper


def pytest_configure(config: pytest.Config) -> None:
    zenoh.open = _recording("a zenoh session", zenoh.open)
    subprocess.Popen.__init__ = _recording("a process", subprocess.Popen.__init__)  # type: ignore[method-assign]
    multiprocessing.process.BaseProcess.start = _recording(  # type: ignore[method-assign]
        "a multiprocessing process", multiprocessing.process.BaseProcess.start
    )


def pytest_collection_finish(session: pytest.Session) -> None:
    """The modules and test items collection made live to the end of the run: moved out of the cyclic garbage
    collector's sight (``gc.freeze``), each full collection no longer walks them again (a few % of a run)."""
    gc.collect()
    gc.freeze()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    rank = {path: i for i, path in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::", 1)[0], len(rank)))  # stable: shuffled within
    for item in items:
        if item.get_closest_marker("live") is not None and item.get_closest_marker("timeout") is None:
            item.add_marker(pytest.mark.timeout(LIVE_TIMEOUT_S))


@pytest.hookimpl(wrapper=True)
def pytest_runtest_call(item: pytest.Item) -> Iterator[None]:
    _running["item"], _running["started"] = item, []
    try:
        result = yield
    finally:
        started, _running["item"] = sorted(set(_running["started"])), None
    if started and item.get_closest_marker("live") is None:
        raise AssertionError(
            f"this test starts {' and '.join(started)} but is not marked live: add @pytest.mark.live "
            '(or a module\'s pytestmark) so `-m "not live"` leaves it out'
        )
    return result


def _skip_reason(report: pytest.TestReport | pytest.CollectReport) -> str:
    longrepr = report.longrepr
    if isinstance(longrepr, tuple) and len(longrepr) == 3:
        return str(longrepr[2])
    return str(longrepr)


def _fail_disallowed_skip(report: pytest.TestReport | pytest.CollectReport) -> None:
    if os.environ.get("CI") != "true" or not report.skipped or hasattr(report, "wasxfail"):
        return
    reason = _skip_reason(report)
    if ALLOWED_CI_SKIP.search(reason):
        return
    report.outcome = "failed"
    report.longrepr = (
        "skipped under CI=true for a reason that is not a missing optional extra, absent ../shared/data "
        f"or Blender that cannot be built (`skelfuse setup blender`): {reason}"
    )


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[pytest.TestReport]:
    report = yield
    _fail_disallowed_skip(report)
    return report


@pytest.hookimpl(wrapper=True)
def pytest_make_collect_report(collector: pytest.Collector) -> Iterator[pytest.CollectReport]:
    report = yield
    _fail_disallowed_skip(report)
    return report
