"""docs/evidence.md from the commands' own ``--json`` results, stored in docs/evidence/.

Every measured figure the README and the guides quote lives on one page, docs/evidence.md, in blocks between
``<!-- generated: NAME -->`` and ``<!-- end generated: NAME -->``. Each block is rendered from the JSON a
skelfuse command printed, stored under docs/evidence/, and stamped with what that command recorded of its own
run (command line, revision, machine, 1-minute load at start and end; skelfuse/cli/stamp.py). Two modes:

    python scripts/update_doc_tables.py record NAME [--quick]   # run NAME's commands, store their JSON
    python scripts/update_doc_tables.py write                   # render every block from the stored JSON
    python scripts/update_doc_tables.py check                   # exit 1 if a block differs from the stored JSON

``record`` runs nothing but the commands listed in RECORDS (NAME: demo, paper, robustness, mirroring, sim-check,
real, tracking, plausibility, smoothing, orientations, retargeting, rear-views, speed, depth, soak; a command is
skelfuse's, or one of scripts/ whose ``--json`` output its own ``format_markdown`` renders); ``write`` and
``check`` run no command. tests/unit/test_evidence_page.py checks the pages as ``check`` does, so a hand edit of
a block fails.
``--quick`` records a tiny configuration under --store (to try the plumbing; never into docs/evidence/). Paths
under the repository root are stored relative to it, so the stored results do not depend on where the checkout
lives.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import re
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "evidence.md"
STORE = ROOT / "docs" / "evidence"
SKELFUSE = (sys.executable, "-m", "skelfuse")
DATA = "../shared/data"
"""The shared real recordings, named relative to the repository root as the commands' defaults find them."""

_SMALL_ROBUSTNESS = ["--seeds", "3", "--duration", "5", "--json", "-q"]
_INSTANT = ["bench", "instant", "--cases", "4x1", "16x6", "--rounds", "3", "--json"]
_LATENCY = ["bench", "latency", "--duration", "10", "--json"]
# A record's arguments are skelfuse's, or a script's (first argument ``scripts/NAME.py``, run by this Python;
# ``{out}``: the file a script writes its JSON to, where it does not print it). Sizes: the two-bases run is
# recorded at 3 seeds of 5 s takes instead of 6 of 10 s (a quarter of the CPU time); plausibility at 3 seeds per
# world and rig size (27 takes of 10 s); smoothing at 6 training and 6 held-out seeds of 10 s (12 takes); the
# per-joint orientation error at its default 4 takes of 4 s; retargeting at 6 gestures of 10 s plus the real
# take; the rear-view signal at 10 seeds (150 takes of 10 s, simulated only, no fusion); the orientation convention
# reads the five real files once; bench depth at 20 frames per case (1, 2, 3 people). Every other run (tracking:
# its four scenarios) has the command's default size.
RECORDS: dict[str, dict[str, list[str]]] = {
    "demo": {"demo": ["demo", "--duration", "10", "--json"]},
    "paper": {"paper": ["eval", "paper", "--json", "--no-files", "-q"]},
    "robustness": {"robustness": ["eval", "robustness", "--json", "-q"]},
    "mirroring": {
        "mirroring-sweep": ["eval", "robustness", "--mirroring-sweep", "--json", "-q"],
        "mirroring-bases": ["eval", "robustness", "--bases", *_SMALL_ROBUSTNESS],
    },
    "sim-check": {"sim-check": ["sim", "check", "--data", DATA, "--json", "-q"]},
    "real": {"real": ["eval", "real", "--json"]},
    "tracking": {"tracking": ["eval", "tracking", "--json"]},
    "plausibility": {"plausibility": ["scripts/plausibility_rates.py", "--seeds", "1000", "1001", "1002", "--json"]},
    "smoothing": {
        "smoothing": [
            "scripts/smoothing_targets.py",
            *("--held-out", "1000", "1001", "1002", "1003", "1004", "1005", "--json"),
        ]
    },
    "orientations": {
        "orientation-convention": ["scripts/measure_orientation_convention.py", "--json"],
        "orientation-views": ["scripts/orientation_to_views.py", "--data", f"{DATA}/azure-kinect-andyj1", "--json"],
        "orientation-joints": [
            "scripts/orientation_error_by_joint.py",
            "--regions",
            "arm",
            "hand",
            "knee",
            "foot",
            "--json",
        ],
    },
    "retargeting": {
        "retargeting": ["scripts/retargeting_error.py", "--data", DATA, "--duration", "10", "--json"],
    },
    "rear-views": {
        "rear-views": [
            "scripts/measure_rear_view_signal.py",
            *("baseline", "side_flips", "close_people", "mixture", "lying", "--seeds", "10", "--json"),
        ],
    },
    "speed": {
        "speed-instant": _INSTANT,
        "speed-instant-paced": [*_INSTANT, "--paced"],
        "speed-instant-positions": [*_INSTANT, "--positions-only"],
        "speed-latency": [*_LATENCY, "--sensors", "4", "8", "16"],
        "speed-latency-people": [*_LATENCY, "--sensors", "8", "--people", "6"],
        "speed-latency-crowd": [*_LATENCY, "--sensors", "8", "--people", "16", "--no-sweep"],  # a classroom: overload
    },
    "depth": {"speed-depth": ["bench", "depth", "--frames", "20", "--json"]},
    "soak": {"soak": ["scripts/soak_hostile.py", "--minutes", "60", "--nice", "-10", "--json", "{out}"]},
}
"""NAME -> stored file stem -> the command's arguments (skelfuse's, or a script's: ``scripts/NAME.py ...``)."""

QUICK: dict[str, dict[str, list[str]]] = {
    "demo": {"demo": ["demo", "--duration", "3", "--json"]},
    "paper": {"paper": ["eval", "paper", "--quick", "--duration", "2", "--json", "--no-files", "-q"]},
    "robustness": {"robustness": ["eval", "robustness", "--quick", "--families", "baseline", "--json", "-q"]},
    "mirroring": {
        "mirroring-sweep": ["eval", "robustness", "--mirroring-sweep", "--quick", "--sensors", "2", "--json", "-q"],
        "mirroring-bases": ["eval", "robustness", "--bases", "--quick", "--families", "baseline", "--json", "-q"],
    },
    "sim-check": {"sim-check": ["sim", "check", "--seeds", "1", "--duration", "3", "--no-real", "--json", "-q"]},
    "real": RECORDS["real"],
    "tracking": {"tracking": ["eval", "tracking", "--quick", "--json"]},
    "speed": {
        "speed-instant": ["bench", "instant", "--cases", "2x1", "--frames", "20", "--rounds", "1", "--json"],
        "speed-latency": ["bench", "latency", "--sensors", "2", "--duration", "1", "--no-sweep", "--json"],
    },
    "depth": {"speed-depth": ["bench", "depth", "--people", "1", "--frames", "3", "--json"]},
    "plausibility": {
        "plausibility": ["scripts/plausibility_rates.py", "--seeds", "1000", "--sensors", "2", "--json"],
    },
    "smoothing": {
        "smoothing": ["scripts/smoothing_targets.py", "--training", "--held-out", "1002", "--duration", "3", "--json"],
    },
    "orientations": {
        "orientation-convention": RECORDS["orientations"]["orientation-convention"],
        "orientation-views": RECORDS["orientations"]["orientation-views"],
        "orientation-joints": ["scripts/orientation_error_by_joint.py", "--duration", "1", "--json"],
    },
    "retargeting": {"retargeting": ["scripts/retargeting_error.py", "--duration", "2", "--json"]},
    "rear-views": {"rear-views": ["scripts/measure_rear_view_signal.py", "baseline", "--seeds", "1", "--json"]},
    "soak": {
        "soak": [
            "scripts/soak_hostile.py",
            *("--minutes", "0.5", "--sensors", "3", "--adversary-hz", "50", "--json"),
            "{out}",
        ],
    },
}
"""Tiny configurations of the same commands, to try ``record`` end to end in seconds."""


# ---------------------------------------------------------------------------------------------- recording


def record(name: str, store: Path, table: dict[str, dict[str, list[str]]] = RECORDS) -> list[Path]:
    """Run ``name``'s commands from the repository root and store each one's JSON as ``store/STEM.json``."""
    store.mkdir(parents=True, exist_ok=True)
    written = []
    for stem, args in table[name].items():
        result = _run_to_file(args) if "{out}" in args else _run_printing(args)
        path = store / f"{stem}.json"
        path.write_text(json.dumps(_relative_paths(result), indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
        print(f"stored {path}", file=sys.stderr)
        written.append(path)
    return written


def stamped_command(args: list[str]) -> list[str]:
    """The command line a record's own stamp names: ``skelfuse ARGS`` or ``python scripts/NAME.py ARGS``."""
    program = ["python"] if _is_script(args) else ["skelfuse"]
    return [*program, *(a.replace("{out}", "OUT.json") for a in args)]


def _is_script(args: list[str]) -> bool:
    return bool(args) and args[0].startswith("scripts/") and args[0].endswith(".py")


def _command(args: list[str]) -> list[str]:
    return [sys.executable, *args] if _is_script(args) else [*SKELFUSE, *args]


def uncommitted_changes() -> list[str]:
    """``git status`` lines of tracked files that differ from the commit (the stamp names only the commit), the
    page and the stored results aside (they are this script's outputs, not the code that measures)."""
    done = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True, cwd=ROOT, check=True
    )
    return [line for line in done.stdout.splitlines() if not line[3:].startswith("docs/evidence")]


def _run_printing(args: list[str]) -> dict[str, Any]:
    """A command that prints its JSON on stdout."""
    command = _command(args)
    print("running: " + " ".join(command), file=sys.stderr)
    done = subprocess.run(command, check=True, stdout=subprocess.PIPE, text=True, cwd=ROOT)
    return json.loads(done.stdout)


def _run_to_file(args: list[str]) -> dict[str, Any]:
    """A command that writes its JSON to the file ``{out}`` names (the soak: exit 1 = instants lost, still a
    result)."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "result.json"
        command = [a.replace("{out}", str(out)) for a in _command(args)]
        print("running: " + " ".join(command), file=sys.stderr)
        subprocess.run(command, check=False, stdout=sys.stderr, cwd=ROOT)
        result = json.loads(out.read_text(encoding="utf-8"))
    result["stamp"]["command"] = result["stamp"]["command"].replace(str(out), "OUT.json")
    result.pop("windows", None)  # the soak's per-10 s detail: in the script's own output, too long to store
    return result


def _relative_paths(value: Any) -> Any:
    """Strings naming a path under the repository root (or the shared data beside it) made relative to it."""
    if isinstance(value, dict):
        return {k: _relative_paths(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_relative_paths(v) for v in value]
    if isinstance(value, str):
        return value.replace(str(ROOT.parent / "shared" / "data"), DATA).replace(str(ROOT) + "/", "")
    return value


# ---------------------------------------------------------------------------------------------- rendering


def load(stem: str, store: Path) -> dict[str, Any] | None:
    path = store / f"{stem}.json"
    return json.loads(path.read_text(encoding="utf-8")) if path.is_file() else None


def stamp_line(result: dict[str, Any]) -> str:
    """Where a result came from, as its command recorded it."""
    s = result["stamp"]
    machine, load_1min = s["machine"], s["load_1min"]
    return (
        f"`{s['command']}` · revision `{s['revision']}` · {machine['cpu_model']}, {machine['cores']} cores · "
        f"1-minute load {load_1min['start']:.2f} at the start, {load_1min['end']:.2f} at the end"
    )


def render_paper(paper: dict[str, Any]) -> str:
    """``skelfuse eval paper``: its settings, experiments 1-3, lag and swaps, the best view's own error."""
    from skelfuse.eval.paper_plan import GROUP_NAMES
    from skelfuse.eval.paper_reference import EPS_SWEEP_PRESET
    from skelfuse.eval.report_files import fmt, pct

    scenarios = paper["scenarios"]
    s = paper["settings"]
    lines = [
        f"{len(scenarios)} scenarios x {s['n_takes']} takes: gestures {', '.join(s['gestures'])}; facing "
        f"{', '.join(f'{d:.0f}°' for d in s['directions_deg'])}; {s['duration_s']:.1f} s at {s['fps']:.0f} Hz each; "
        f"seed {s['seed']}; profile {s.get('profile_path') or 'azure_kinect (packaged)'}. Scenarios:",
        "",
    ]
    for name, result in scenarios.items():
        takes = result["takes"]
        mirrored = sum(sum(t["mirrored_fraction"][:-1]) / (len(t["mirrored_fraction"]) - 1) for t in takes) / len(takes)
        lines.append(
            f"- **{name}**: {paper['scenario_descriptions'][name]}. Capture views mirrored: {pct(mirrored)} of frames."
        )
    lines += ["", "RMSE in mm, torso / upper limb / lower limb (the paper's figure: its mean error).", ""]
    lines += _paper_table(scenarios, "algorithms", "Experiment 1, algorithms, 4 sensors (A3-A5: mean over eps)")
    lines += _paper_table(
        scenarios,
        "eps_sweep",
        f"Experiment 2, DBSCAN radius, {EPS_SWEEP_PRESET}",
        keep=lambda config: config.startswith(EPS_SWEEP_PRESET + "_"),
    )
    lines += _paper_table(scenarios, "n_sensors", "Experiment 3, number of sensors (mean over all combinations)")
    lines += [
        "Experiment 1 against exact truth: left/right pairs the wrong way round (share of frames x limb pairs) and "
        "lag (frames, torso / upper / lower; positive = late).",
        "",
        "| config | " + " | ".join(f"{n}: swapped | {n}: lag" for n in scenarios) + " |",
        "|---|" + "---|---|" * len(scenarios),
    ]
    first = next(iter(scenarios.values()))["experiments"]["algorithms"]["truth"]
    for config in first:
        cells = [config]
        for result in scenarios.values():
            row = result["experiments"]["algorithms"]["truth"].get(config)
            cells += (
                ["—", "—"]
                if row is None
                else [pct(row["swapped_fraction"]), " / ".join(fmt(row["lag_frames"][g], 1) for g in GROUP_NAMES)]
            )
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "The best-view reference sensor's own RMSE against exact truth (mm, torso / upper / lower):", ""]
    for name, result in scenarios.items():
        best = result["best_view_vs_truth"]
        lines.append(f"- {name}: " + " / ".join(fmt(best[g]["rmse_mm"], 0) for g in GROUP_NAMES))
    return "\n".join([*lines, *_paper_orientation_table(scenarios)])


def _paper_orientation_table(scenarios: dict[str, Any]) -> list[str]:
    """The fused orientations' angle to the true ones beside each capture view's (``orientation_error_deg``)."""
    from skelfuse.eval.paper_plan import GROUP_NAMES
    from skelfuse.eval.report_files import fmt

    lines = [
        "",
        "Orientations against the simulator's true ones (angle of the rotation between them, degrees, median / p90, "
        "torso / upper limb / lower limb; the simulated tracker's orientation noise is a model, docs/orientations.md):",
        "",
        "| scenario | output | torso | upper limb | lower limb |",
        "|---|---|---|---|---|",
    ]
    for name, result in scenarios.items():
        for output, groups in result.get("orientation_error_deg", {}).items():
            cells = [f"{fmt(groups[g]['median_deg'], 1)} / {fmt(groups[g]['p90_deg'], 1)}" for g in GROUP_NAMES]
            lines.append(f"| {name} | {output} | " + " | ".join(cells) + " |")
    return lines


def _paper_table(
    scenarios: dict[str, Any], experiment: str, title: str, keep: Callable[[str], bool] = lambda config: True
) -> list[str]:
    """One experiment's RMSE per row: each scenario against exact truth and against the best view."""
    from skelfuse.eval.paper_plan import GROUP_NAMES
    from skelfuse.eval.report_files import by_label, fmt, row_cell

    header = ["config", "by"]
    for name in scenarios:
        header += [f"{name}: vs truth", f"{name}: vs best view"]
    lines = [f"{title}:", "", "| " + " | ".join([*header, "paper's figure"]) + " |", "|" + "---|" * (len(header) + 1)]
    first = next(iter(scenarios.values()))["experiments"][experiment]["truth"]
    for config in filter(keep, first):
        cells = [row_cell(experiment, config), by_label(experiment, config)]
        for result in scenarios.values():
            for protocol in ("truth", "best_view"):
                row = result["experiments"][experiment][protocol].get(config)
                cells.append(
                    "—" if row is None else " / ".join(fmt(row["groups"][g]["rmse_mm"], 0) for g in GROUP_NAMES)
                )
        figure = [first[config]["paper"][g]["ae_mm"] for g in GROUP_NAMES]
        cells.append("—" if all(v is None for v in figure) else " / ".join(fmt(v, 0) for v in figure))
        lines.append("| " + " | ".join(cells) + " |")
    return [*lines, ""]


def render_demo(result: dict[str, Any]) -> str:
    from skelfuse.apps.demo.summary import DemoSummary, format_summary

    return format_summary(DemoSummary(**{k: v for k, v in result.items() if k != "stamp"}))


def render_robustness(result: dict[str, Any]) -> str:
    from skelfuse.eval import robustness

    return robustness.format_markdown(robustness.RobustnessResult.from_dict(result))


def render_mirroring_sweep(result: dict[str, Any]) -> str:
    from skelfuse.eval import mirroring
    from skelfuse.eval.metrics import nan_for_none

    sweep = result["sweep"]
    return mirroring.format_sweep({**sweep, "points": nan_for_none(sweep["points"])})


def render_mirroring_bases(result: dict[str, Any]) -> str:
    from skelfuse.eval import mirroring
    from skelfuse.eval.metrics import nan_for_none

    bases = result["bases"]
    return mirroring.format_bases({**bases, "cells": nan_for_none(bases["cells"])})


def render_sim_check(result: dict[str, Any]) -> str:
    from skelfuse.eval import realism

    return realism.format_markdown(realism.SimCheckResult.from_dict(result))


def render_real(result: dict[str, Any]) -> str:
    """``skelfuse eval real``'s report, its headings moved under the page's section."""
    from skelfuse.eval import rig, rig_report

    fields = {k: v for k, v in result.items() if k != "stamp"}
    text = rig_report.format_markdown(rig.RigEvalResult.from_dict(fields))
    lines = [("#" + line if line.startswith("#") else line) for line in text.splitlines()]
    if lines[:2] == ["## Real-data report", ""]:  # the page's section is its title
        lines = lines[2:]
    return "\n".join(lines)


def render_tracking(result: dict[str, Any]) -> str:
    """``skelfuse eval tracking``'s report, its title left to the page's section."""
    from skelfuse.eval.tracking import TrackingEvalResult

    text = TrackingEvalResult.from_dict({k: v for k, v in result.items() if k != "stamp"}).format_markdown()
    return "\n".join(text.splitlines()[2:])  # the report's own "## Multi-person tracking" heading and blank line


def render_instant(result: dict[str, Any]) -> str:
    from skelfuse.bench.instant import format_instant_bench

    return format_instant_bench(result)


def render_latency(result: dict[str, Any]) -> str:
    from skelfuse.bench import latency

    return latency.format_table(latency.LatencyResult.from_dict({k: v for k, v in result.items() if k != "stamp"}))


def render_script(result: dict[str, Any], script: str) -> str:
    """A script's result, rendered by the script's own ``format_markdown`` (the table it prints without --json)."""
    return _script_module(script).format_markdown({k: v for k, v in result.items() if k != "stamp"})


def _script_module(script: str) -> ModuleType:
    """``scripts/NAME.py`` imported as a module (scripts are not a package)."""
    name = "skelfuse_script_" + Path(script).stem
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, ROOT / script)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    return sys.modules[name]


def _by_script(script: str) -> Callable[[dict[str, Any]], str]:
    return functools.partial(render_script, script=script)


def render_depth(result: dict[str, Any]) -> str:
    """``skelfuse bench depth``'s own table (plain text, so in a code block)."""
    from skelfuse.bench.depth import format_depth_bench

    table = "\n".join(line.rstrip() for line in format_depth_bench(result).splitlines())
    return "```text\n" + table + "\n```"


SOAK_FIGURES = (
    ("sensors", "sensors"),
    ("minutes", "minutes"),
    ("instants published", "instants_published"),
    ("fused frames received", "fused_frames"),
    ("instants lost", "instants_lost"),
    ("instants fused with every sensor", "instants_with_every_sensor"),
    ("hostile payloads sent", "hostile_payloads_sent"),
    ("node RSS at the start, MB", "node_rss_mb_at_start"),
    ("node RSS growth after the warm-up, MB per minute", "node_rss_growth_mb_per_min_after_warmup"),
    ("1-minute load, median / max", None),
)


def render_soak(result: dict[str, Any]) -> str:
    """The soak's headline figures (``scripts/soak_hostile.py --json``)."""
    lines = ["| figure | value |", "|---|---:|"]
    for label, key in SOAK_FIGURES:
        value = f"{result['load_1min_median']:.2f} / {result['load_1min_max']:.2f}" if key is None else result.get(key)
        lines.append(f"| {label} | {'—' if value is None else value} |")
    return "\n".join(lines)


BLOCKS: dict[str, tuple[str, str, Callable[[dict[str, Any]], str]]] = {
    "demo": ("demo", "demo", render_demo),
    "paper": ("paper", "paper", render_paper),
    "robustness": ("robustness", "robustness", render_robustness),
    "mirroring-sweep": ("mirroring", "mirroring-sweep", render_mirroring_sweep),
    "mirroring-bases": ("mirroring", "mirroring-bases", render_mirroring_bases),
    "sim-check": ("sim-check", "sim-check", render_sim_check),
    "real": ("real", "real", render_real),
    "tracking": ("tracking", "tracking", render_tracking),
    "bench-instant": ("speed", "speed-instant", render_instant),
    "bench-instant-paced": ("speed", "speed-instant-paced", render_instant),
    "bench-instant-positions": ("speed", "speed-instant-positions", render_instant),
    "bench-latency": ("speed", "speed-latency", render_latency),
    "bench-latency-people": ("speed", "speed-latency-people", render_latency),
    "bench-latency-crowd": ("speed", "speed-latency-crowd", render_latency),
    "bench-depth": ("depth", "speed-depth", render_depth),
    "plausibility": ("plausibility", "plausibility", _by_script("scripts/plausibility_rates.py")),
    "smoothing": ("smoothing", "smoothing", _by_script("scripts/smoothing_targets.py")),
    "orientation-convention": (
        "orientations",
        "orientation-convention",
        _by_script("scripts/measure_orientation_convention.py"),
    ),
    "orientation-joints": ("orientations", "orientation-joints", _by_script("scripts/orientation_error_by_joint.py")),
    "orientation-views": ("orientations", "orientation-views", _by_script("scripts/orientation_to_views.py")),
    "retargeting": ("retargeting", "retargeting", _by_script("scripts/retargeting_error.py")),
    "rear-views": ("rear-views", "rear-views", _by_script("scripts/measure_rear_view_signal.py")),
    "soak": ("soak", "soak", render_soak),
}
"""Block name on the page -> (record NAME, stored file stem, renderer)."""


def render_demo_accuracy(result: dict[str, Any]) -> str:
    """The README's line of demo figures: the fused error against the best single sensor's, and its command."""
    fused, best = result["error_fused_mm"], result["error_best_single_sensor_mm"]
    return (
        f"**{fused['all16']:.1f} mm** mean error over the 16 evaluation joints, against {best['all16']:.1f} mm for "
        f"the best single sensor (`{result['stamp']['command']}`)."
    )


GUIDE_BLOCKS: dict[str, tuple[str, str, Callable[[dict[str, Any]], str]]] = {
    "demo-accuracy": ("demo", "demo", render_demo_accuracy),
}
"""Blocks inside a guide (README.md): a sentence that names its command; the stamp is on docs/evidence.md."""

PAGES: dict[Path, dict[str, tuple[str, str, Callable[[dict[str, Any]], str]]]] = {
    PAGE: BLOCKS,
    ROOT / "README.md": GUIDE_BLOCKS,
}
"""Every page with generated blocks -> the blocks it holds (each exactly once)."""


def render_block(block: str, store: Path = STORE) -> str:
    """A block's text: the stamp, then the table (a guide's block: its sentence alone), or how to record it where
    nothing is stored."""
    name, stem, render = GUIDE_BLOCKS[block] if block in GUIDE_BLOCKS else BLOCKS[block]
    result = load(stem, store)
    if result is None:
        return f"Not recorded: `python scripts/update_doc_tables.py record {name}` stores {stem}.json."
    if block in GUIDE_BLOCKS:
        return render(result).rstrip()
    return stamp_line(result) + "\n\n" + render(result).rstrip()


MARKERS = re.compile(r"<!-- generated: (?P<name>[\w-]+) -->\n(?P<body>.*?)<!-- end generated: (?P=name) -->\n?", re.S)


def render_page(text: str, store: Path = STORE, page: Path = PAGE) -> str:
    """``text`` (``page``, docs/evidence.md by default) with every generated block rendered from the stored
    results."""
    found = [m.group("name") for m in MARKERS.finditer(text)]
    unknown = sorted(set(found) - set(PAGES[page]))
    missing = sorted(set(PAGES[page]) - set(found))
    if unknown or missing:
        raise ValueError(
            f"{page.relative_to(ROOT)}: blocks without a renderer {unknown}, renderers without a block {missing}"
        )
    return MARKERS.sub(
        lambda m: (
            f"<!-- generated: {m['name']} -->\n{render_block(m['name'], store)}\n<!-- end generated: {m['name']} -->\n"
        ),
        text,
    )


def stale_blocks(text: str, store: Path = STORE, page: Path = PAGE) -> list[str]:
    """Names of the blocks in ``text`` (``page``) that differ from what the stored results render."""
    expected = {m["name"]: m["body"] for m in MARKERS.finditer(render_page(text, store, page))}
    return [m["name"] for m in MARKERS.finditer(text) if m["body"] != expected[m["name"]]]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    modes = parser.add_subparsers(dest="mode", required=True)
    rec = modes.add_parser("record", help="run NAME's commands and store their JSON")
    rec.add_argument("name", choices=list(RECORDS))
    rec.add_argument("--quick", action="store_true", help="a tiny configuration (needs --store outside docs/)")
    rec.add_argument("--store", type=Path, default=STORE, help="where to store the JSON (default: docs/evidence)")
    write = modes.add_parser("write", help="render every block (docs/evidence.md, README.md) from the stored JSON")
    check = modes.add_parser("check", help="exit 1 if a block differs from what the stored JSON renders")
    for sub in (write, check):
        sub.add_argument("--store", type=Path, default=STORE, help="the stored JSON (default: docs/evidence)")
    args = parser.parse_args(argv)
    if args.mode == "record":
        evidence = args.store.resolve() == STORE.resolve()
        if args.quick and evidence:
            parser.error("--quick results are not evidence: pass --store DIR outside docs/evidence")
        if evidence and uncommitted_changes():
            parser.error("commit first: the stamp names the commit, and the tree has uncommitted changes")
        record(args.name, args.store, QUICK if args.quick else RECORDS)
        return 0
    stale = []
    for page in PAGES:
        text = page.read_text(encoding="utf-8")
        if args.mode == "check":
            stale += [f"{page.relative_to(ROOT)}: block {name!r}" for name in stale_blocks(text, args.store, page)]
            continue
        page.write_text(render_page(text, args.store, page), encoding="utf-8")
        print(f"wrote {page.relative_to(ROOT)}", file=sys.stderr)
    for block in stale:
        print(f"{block} differs from its stored result", file=sys.stderr)
    return 1 if stale else 0


if __name__ == "__main__":
    raise SystemExit(main())
