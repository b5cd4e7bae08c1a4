"""The suite's own rules (tests/conftest.py), run on small suites of their own in a subprocess each."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

RULES = Path(__file__).resolve().parents[1] / "conftest.py"

SKIPS = """
import pytest

def test_broken_install():
    pytest.skip("gcc is not on PATH")

def test_optional_extra():
    pytest.importorskip("no_such_module_here", reason="the optional extra `kinect` is not installed")

def test_no_data():
    pytest.skip("recordings not found at ../shared/data/somewhere")

@pytest.mark.xfail(strict=True, reason="a known gap")
def test_known_gap():
    assert False
"""

STARTS = """
import subprocess, sys
import pytest

def test_unmarked():
    subprocess.run([sys.executable, "-c", "pass"], check=True)

@pytest.mark.live
def test_marked():
    subprocess.run([sys.executable, "-c", "pass"], check=True)

def test_pure():
    assert sum([1, 2]) == 3
"""


def _run(pytester: pytest.Pytester, source: str, *args: str) -> pytest.RunResult:
    pytester.makeconftest(RULES.read_text(encoding="utf-8"))
    pytester.makeini("[pytest]\nmarkers =\n    live: starts a process\n")
    pytester.makepyfile(source)
    return pytester.runpytest_subprocess("-p", "no:randomly", "-p", "no:cacheprovider", "-rA", *args)


@pytest.mark.live
def test_under_ci_a_skip_fails_unless_it_names_an_optional_extra_or_absent_data(
    pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CI", "true")
    result = _run(pytester, SKIPS)
    result.assert_outcomes(failed=1, skipped=2, xfailed=1)
    result.stdout.fnmatch_lines(["*skipped under CI=true for a reason that is not*gcc is not on PATH*"])


@pytest.mark.live
def test_outside_ci_a_skip_stays_a_skip(pytester: pytest.Pytester, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("CI", raising=False)
    _run(pytester, SKIPS).assert_outcomes(skipped=3, xfailed=1)


@pytest.mark.live
def test_a_test_that_starts_a_process_must_be_marked_live(pytester: pytest.Pytester) -> None:
    result = _run(pytester, STARTS)
    result.assert_outcomes(failed=1, passed=2)
    result.stdout.fnmatch_lines(
        ["*_ test_unmarked _*", "*AssertionError: this test starts a process but is not marked live*"]
    )


def test_the_longest_files_listed_to_start_first_exist() -> None:
    """A renamed or removed file in the list would silently fall back to the shuffled order."""
    tree = ast.parse(RULES.read_text(encoding="utf-8"))
    listed = next(
        ast.literal_eval(node.value)
        for node in tree.body
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "LONGEST_FILES" for t in node.targets)
    )
    assert len(listed) >= 10
    missing = [path for path in listed if not (RULES.parents[1] / path).is_file()]
    assert missing == [], f"LONGEST_FILES in tests/conftest.py names files that do not exist: {missing}"
