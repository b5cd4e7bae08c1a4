"""Regenerate the generated tables in README.md and docs/simulator.md from the commands that measure them.

Each table sits between two marker lines, ``<!-- generated: NAME -->`` and ``<!-- end generated: NAME -->``;
this script replaces what lies between them, so a table cannot drift from its command. Usage:

    python scripts/update_doc_tables.py sim-check      # docs/simulator.md: skelfuse sim check (about a minute)
    python scripts/update_doc_tables.py robustness     # docs/simulator.md: skelfuse eval robustness (long)
    python scripts/update_doc_tables.py paper [--report eval_out/paper/report.md]
                                                       # README.md: experiment 1 of skelfuse eval paper's summary
    python scripts/update_doc_tables.py speed          # docs/service.md: skelfuse bench instant (back to back,
                                                       # paced, positions only) and bench latency (x 1 and x 6
                                                       # people), ~12 min;
                                                       # run it on an otherwise idle machine

``paper`` reads the summary an earlier ``skelfuse eval paper`` wrote (run it first; it takes minutes), and
copies its experiment-1 table.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def replace_block(path: Path, name: str, body: str) -> None:
    """Replace the lines between the markers of ``name`` in ``path`` with ``body``."""
    text = path.read_text(encoding="utf-8")
    start, end = f"<!-- generated: {name} -->", f"<!-- end generated: {name} -->"
    pattern = re.compile(re.escape(start) + r"\n.*?" + re.escape(end), re.DOTALL)
    if not pattern.search(text):
        sys.exit(f"{path}: markers {start!r} ... {end!r} not found")
    text = pattern.sub(lambda _: f"{start}\n{body.rstrip()}\n{end}", text)
    path.write_text(text, encoding="utf-8")
    print(f"updated {name} in {path.relative_to(ROOT)}", file=sys.stderr)


def run(command: list[str]) -> str:
    print("running: " + " ".join(command), file=sys.stderr)
    return subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT).stdout


def experiment_one(report: Path) -> str:
    """The experiment-1 table of ``skelfuse eval paper``'s summary, with its heading line dropped."""
    text = report.read_text(encoding="utf-8")
    match = re.search(r"## Experiment 1[^\n]*\n\n(\|.*?)\n\n", text, re.DOTALL)
    if match is None:
        sys.exit(f"{report}: no experiment-1 table (is it the summary report.md of skelfuse eval paper?)")
    return match.group(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("table", choices=["sim-check", "robustness", "paper", "speed"])
    parser.add_argument("--report", type=Path, default=ROOT / "eval_out" / "paper" / "report.md")
    args = parser.parse_args()
    skelfuse = [sys.executable, "-m", "skelfuse"]
    if args.table == "sim-check":
        replace_block(ROOT / "docs" / "simulator.md", "sim-check", run([*skelfuse, "sim", "check", "-q"]))
    elif args.table == "robustness":
        replace_block(ROOT / "docs" / "simulator.md", "robustness", run([*skelfuse, "eval", "robustness", "-q"]))
    elif args.table == "speed":
        service = ROOT / "docs" / "service.md"
        instant = [*skelfuse, "bench", "instant", "--cases", "4x1", "16x6", "--rounds", "3"]
        tables = [run(instant), run([*instant, "--paced"]), run([*instant, "--positions-only"])]
        replace_block(service, "bench-instant", "\n".join(tables))
        latency = [*skelfuse, "bench", "latency", "--duration", "10"]
        one = run([*latency, "--sensors", "4", "8", "16"])
        six = run([*latency, "--sensors", "8", "--people", "6"])
        crowd = run([*latency, "--sensors", "8", "--people", "16", "--no-sweep"])  # a classroom: overload
        replace_block(service, "bench-latency", "\n".join([one, six, crowd]))
    else:
        replace_block(ROOT / "README.md", "eval-paper", experiment_one(args.report))


if __name__ == "__main__":
    main()
