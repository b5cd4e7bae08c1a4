"""The product speaks of itself only: no text in the repository tells how it was made.

Code, tests, docs, configs, scripts and the simulator profiles give reasons as facts about the code, the
sensors or the data. Words about numbered work periods, stops, issue numbers, people or roles on the team,
branches or paths outside the repository belong in git history and CHANGELOG.md. A zenoh session, a stop
signal or another project's issue (the Azure Kinect SDK's, a GitHub issue) stay allowed.

``ALLOWED`` lists the files that still carry such words, with how many; it may only shrink: a file with more
hits than listed fails, and so does a listing larger than the file's hits (lower the count as text is fixed).
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SCANNED = ("src", "tests", "docs", "config", "scripts", "README.md", "CHANGELOG.md")
SUFFIXES = {".py", ".md", ".toml", ".txt", ".cfg", ".ini", ".yaml", ".yml", ".json", ".service", ".sh", ".c", ".h"}

PATTERNS: dict[str, re.Pattern[str]] = {
    "numbered work period": re.compile(r"\bsessions?[- _]?\d+", re.IGNORECASE),
    "numbered stop": re.compile(r"\bstops? \d+\b(?!\s*(?:s|ms|seconds?|minutes?|of)\b)", re.IGNORECASE),
    "issue number": re.compile(r"\bissues?[- _]?\d+[a-z]?\b", re.IGNORECASE),
    "role on the team": re.compile(
        r"\bthe (?:lead|CEO|maintainers' decision)\b|\banother engineer\b|\bmy own (?:tests?|runs?)\b", re.IGNORECASE
    ),
    "branch name": re.compile(r"\bthis branch(?:'s)?\b|\bits branch\b|\bs\d{2}-\d+\b", re.IGNORECASE),
    "path outside the repository": re.compile(r"/work/|\.\./shared/(?!data\b)|/notes/"),
}

# Another project's issue tracker, named as such, is a fact about that project.
OTHER_PROJECT_ISSUE = re.compile(
    r"(?:SDK|GitHub|upstream|zenoh|rerun|numba|k4a|Kinect-Samples)['’s]* issues?[- ]?\d", re.I
)

# file (relative to the repository root) -> hits it may still carry; may only shrink
ALLOWED: dict[str, int] = {
    "scripts/node_memory_probe.py": 1,
    "src/skelfuse/calibration/rigid.py": 1,
    "src/skelfuse/eval/realism.py": 3,
    "src/skelfuse/fusion/orientation.py": 1,
    "src/skelfuse/profiles/azure_kinect.toml": 7,
    "src/skelfuse/rig/grouping.py": 1,
    "src/skelfuse/service/zenoh_io.py": 1,
    "src/skelfuse/service/zenoh_log.py": 1,
    "tests/export/test_export_armature.py": 1,
    "tests/golden/test_golden_outputs.py": 1,
    "tests/service/test_depth_service.py": 1,
    "tests/service/test_fused_congestion.py": 1,
    "tests/service/test_node_stop_budget.py": 1,
    "tests/service/test_node_stop_full_link.py": 1,
    "tests/service/test_service_live.py": 1,
    "tests/unit/test_demo_live_score.py": 2,
    "tests/unit/test_grouping.py": 5,
    "tests/unit/test_inputs.py": 1,
    "tests/unit/test_node_intake.py": 1,
    "tests/unit/test_node_loop.py": 2,
    "tests/unit/test_realism.py": 1,
    "tests/unit/test_session_close.py": 1,
}


def scanned_files() -> list[Path]:
    files: list[Path] = []
    for name in SCANNED:
        path = ROOT / name
        if path.is_file():
            files.append(path)
        elif path.is_dir():
            files.extend(
                p
                for p in sorted(path.rglob("*"))
                if p.is_file() and p.suffix in SUFFIXES and "egg-info" not in str(p) and "__pycache__" not in p.parts
            )
    return [f for f in files if f != Path(__file__).resolve()]


def history_hits(text: str) -> list[tuple[int, str, str]]:
    """(line number, kind, the line) of each phrase about how the product was made."""
    hits = []
    for number, line in enumerate(text.splitlines(), start=1):
        for kind, pattern in PATTERNS.items():
            for match in pattern.finditer(line):
                context = line[max(0, match.start() - 24) : match.end()]
                if kind == "issue number" and OTHER_PROJECT_ISSUE.search(context):
                    continue
                hits.append((number, kind, line.strip()))
    return hits


def test_patterns_catch_history_and_spare_facts() -> None:
    caught = [
        "measured in session 21 on this machine",
        "the soak of stop 22 lost nothing",
        "issue 11 measured the real range",
        "shared with the lead's matrix",
        "not in this branch's tree",
        "raw: /work/notes/s22-issue-12-soak60.json",
        "see ../shared/DESIGN.md",
        "merged s22-12",
    ]
    spared = [
        "the zenoh session closes within the drain timeout",
        "a stop 2 s after SIGTERM",
        "SDK issue 1935 says merging is for users to write",
        "real recordings in ../shared/data",
        "the branch of the kinematic tree",
    ]
    assert all(history_hits(text) for text in caught), [t for t in caught if not history_hits(t)]
    assert not any(history_hits(text) for text in spared), [history_hits(t) for t in spared]


def test_no_new_team_history_and_the_allow_list_only_shrinks() -> None:
    problems = []
    seen = set()
    for path in scanned_files():
        rel = path.relative_to(ROOT).as_posix()
        hits = history_hits(path.read_text(encoding="utf-8", errors="replace"))
        allowed = ALLOWED.get(rel, 0)
        if hits:
            seen.add(rel)
        if len(hits) > allowed:
            shown = "\n".join(f"    {rel}:{n}: [{kind}] {line[:140]}" for n, kind, line in hits)
            problems.append(f"{rel}: {len(hits)} history phrase(s), {allowed} allowed:\n{shown}")
        elif len(hits) < allowed:
            problems.append(f"{rel}: {len(hits)} history phrase(s) left; lower ALLOWED[{rel!r}] to {len(hits)}")
    stale = sorted(set(ALLOWED) - seen)
    problems.extend(f"{rel}: listed in ALLOWED but clean (or gone); remove it" for rel in stale)
    assert not problems, "State reasons as facts about the code, sensors or data:\n" + "\n".join(problems)
