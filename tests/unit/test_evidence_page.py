"""docs/evidence.md is what its generator renders from the stored results, and each result names its maker.

Every generated block of the page must equal what ``scripts/update_doc_tables.py`` renders from the JSON stored
in docs/evidence/ (no command runs here), so a hand edit of a figure fails; every stored result must carry the
stamp its command wrote (command line, revision, machine, load), and that command must be the one the generator
records it with. The stamp itself (skelfuse/cli/stamp.py) is checked against git and a known cpuinfo text.
"""

from __future__ import annotations

import importlib.util
import json
import re
import shlex
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from skelfuse.cli import main
from skelfuse.cli.common import print_json
from skelfuse.cli.stamp import RunStamp, code_revision, cpu_model

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def generator() -> ModuleType:
    spec = importlib.util.spec_from_file_location("skelfuse_update_doc_tables", ROOT / "scripts/update_doc_tables.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_every_generated_block_equals_its_rendering_from_the_stored_results(generator: ModuleType) -> None:
    for page in generator.PAGES:
        text = page.read_text(encoding="utf-8")
        assert generator.stale_blocks(text, page=page) == [], (
            f"{page.name} differs from the stored results: run `python scripts/update_doc_tables.py write` "
            "(or `record NAME` first, to re-measure)"
        )


def test_a_hand_edited_figure_is_caught_in_every_block(generator: ModuleType) -> None:
    table_row = re.compile(r"^\|[^\n]*?(\d)", re.M)  # a figure in a table row (the evidence page's tables)
    any_figure = re.compile(r"(\d)")  # a guide's block is one sentence
    checked = []
    for page in generator.PAGES:
        text = page.read_text(encoding="utf-8")
        for block in generator.MARKERS.finditer(text):
            figure = (any_figure if block["name"] in generator.GUIDE_BLOCKS else table_row).search(block["body"])
            if figure is None or block["body"].startswith("Not recorded"):
                continue
            at = block.start("body") + figure.start(1)
            edited = text[:at] + str((int(text[at]) + 1) % 10) + text[at + 1 :]
            assert generator.stale_blocks(edited, page=page) == [block["name"]]
            checked.append(block["name"])
    assert {"paper", "robustness", "demo-accuracy"} <= set(checked)


def test_the_accuracy_results_are_stored(generator: ModuleType) -> None:
    """The seeded accuracy figures the guides quote (they reproduce anywhere, so they are always recorded)."""
    for stem in ("paper", "robustness", "sim-check", "real"):
        assert (generator.STORE / f"{stem}.json").is_file(), (
            f"record it: python scripts/update_doc_tables.py record {stem}"
        )


def test_every_stored_result_carries_the_stamp_of_the_command_that_records_it(generator: ModuleType) -> None:
    stored = 0
    for files in generator.RECORDS.values():
        for stem, args in files.items():
            path = generator.STORE / f"{stem}.json"
            if not path.is_file():
                continue  # the page says "Not recorded" for it (the block test checks that)
            stamp = json.loads(path.read_text(encoding="utf-8"))["stamp"]
            assert stamp["command"] == shlex.join(generator.stamped_command(args)), path
            assert re.fullmatch(r"[0-9a-f]{12}(-dirty)?", stamp["revision"]), f"{path}: {stamp['revision']}"
            assert not stamp["revision"].endswith("-dirty"), f"{path}: recorded from an uncommitted tree"
            assert stamp["machine"]["cores"] >= 1 and stamp["machine"]["cpu_model"]
            assert {"start", "end"} <= set(stamp["load_1min"])
            stored += 1
    assert stored >= 4


def test_stored_results_read_back_to_what_they_were(generator: ModuleType) -> None:
    """Each renderer reads a result back into the command's own result type: it must lose nothing."""
    from skelfuse.bench.latency import LatencyResult
    from skelfuse.eval.realism import SimCheckResult
    from skelfuse.eval.rig import RigEvalResult
    from skelfuse.eval.robustness import RobustnessResult
    from skelfuse.eval.tracking import TrackingEvalResult

    kinds = {
        "robustness": RobustnessResult,
        "sim-check": SimCheckResult,
        "real": RigEvalResult,
        "tracking": TrackingEvalResult,
        "speed-latency": LatencyResult,
        "speed-latency-people": LatencyResult,
    }
    for stem, kind in kinds.items():
        result = generator.load(stem, generator.STORE)
        if result is None:
            continue
        result.pop("stamp")
        assert json.loads(json.dumps(kind.from_dict(result).to_dict())) == result, stem


def test_a_json_result_is_stamped_by_the_command_line(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import skelfuse.cli.sim as sim_cli

    def fake_check(args) -> int:
        print_json({"figure": 1}, args)
        return 0

    monkeypatch.setattr(sim_cli, "_cmd_sim_check", fake_check)
    assert main(["sim", "check", "--seeds", "2", "--json"]) == 0
    payload = json.loads(capsys.readouterr().out)
    assert payload["figure"] == 1
    stamp = payload["stamp"]
    assert stamp["command"] == "skelfuse sim check --seeds 2 --json"
    assert stamp["revision"] == code_revision()
    assert stamp["machine"]["cores"] >= 1


def test_without_json_no_stamp_is_taken(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import skelfuse.cli.sim as sim_cli

    seen = []
    monkeypatch.setattr(sim_cli, "_cmd_sim_check", lambda args: seen.append(args.stamp) or 0)
    assert main(["sim", "check"]) == 0
    assert seen == [None]


@pytest.mark.live  # runs git
def test_the_revision_is_gits_and_says_so_outside_a_checkout(tmp_path: Path) -> None:
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        pytest.skip("the tests run outside a git checkout (git rev-parse failed)")
    assert code_revision() == head.stdout.strip()[:12]
    assert code_revision(tmp_path) == "unknown (not a git checkout)"


def test_the_revision_is_read_from_a_worktrees_files_and_packed_refs(tmp_path: Path) -> None:
    """A linked worktree's ``.git`` file points at its git dir, whose ``commondir`` holds the packed refs."""
    common = tmp_path / "repo.git"
    (common / "worktrees" / "wt").mkdir(parents=True)
    (common / "packed-refs").write_text("# pack-refs with: peeled\n" + "ab" * 20 + " refs/heads/topic\n")
    (common / "worktrees" / "wt" / "HEAD").write_text("ref: refs/heads/topic\n")
    (common / "worktrees" / "wt" / "commondir").write_text("../..\n")
    checkout = tmp_path / "wt"
    (checkout / "src" / "pkg").mkdir(parents=True)
    (checkout / ".git").write_text(f"gitdir: {common / 'worktrees' / 'wt'}\n")
    assert code_revision(checkout / "src" / "pkg") == "ab" * 6
    (common / "worktrees" / "wt" / "HEAD").write_text("cd" * 20 + "\n")  # detached
    assert code_revision(checkout / "src" / "pkg") == "cd" * 6


def test_the_cpu_model_is_read_from_cpuinfo(tmp_path: Path) -> None:
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC 7B13\ncores\t: 2\n")
    assert cpu_model(cpuinfo) == "AMD EPYC 7B13"
    assert cpu_model(tmp_path / "missing") != ""


def test_the_stamp_quotes_the_command_line_for_a_shell() -> None:
    stamp = RunStamp.begin(["eval", "real", "--input", "a b.csv"]).finished()
    assert stamp["command"] == "skelfuse eval real --input 'a b.csv'"
    assert stamp["load_1min"]["start"] >= 0 and stamp["load_1min"]["end"] >= 0


@pytest.mark.live  # runs skelfuse sim check in a subprocess
def test_record_stores_the_commands_json_and_write_renders_it_with_its_stamp(
    generator: ModuleType, tmp_path: Path
) -> None:
    (path,) = generator.record("sim-check", tmp_path, generator.QUICK)
    stored = json.loads(path.read_text(encoding="utf-8"))
    assert stored["seeds"] == [0] and stored["duration_s"] == 3.0  # the quick configuration's own output
    quick = shlex.join(["skelfuse", *generator.QUICK["sim-check"]["sim-check"]])
    block = generator.render_block("sim-check", tmp_path)
    assert block.startswith(f"`{quick}` · revision `{stored['stamp']['revision']}`")
    assert f"**{stored['inside']} of {len(stored['rows'])} statistics inside the real range.**" in block
    assert generator.render_block("paper", tmp_path).startswith("Not recorded: ")


@pytest.mark.live  # runs scripts/plausibility_rates.py in a subprocess
def test_a_scripts_json_is_recorded_with_its_stamp_and_rendered_by_its_own_formatter(
    generator: ModuleType, tmp_path: Path
) -> None:
    args = generator.QUICK["plausibility"]["plausibility"]
    (path,) = generator.record("plausibility", tmp_path, generator.QUICK)
    stored = json.loads(path.read_text(encoding="utf-8"))
    assert stored["stamp"]["command"] == shlex.join(["python", *args])
    assert [(r["world"], r["sensors"]) for r in stored["rows"]] == [
        ("clean", 2),
        ("fast gestures", 2),
        ("tracker_loss", 2),
    ]
    block = generator.render_block("plausibility", tmp_path)
    assert block.startswith(f"`{shlex.join(['python', *args])}` · revision")
    loss = stored["rows"][2]
    assert loss["episode_frames_caught"] <= loss["episode_frames"] > 0  # the simulated losses are there
    teleport = 100 * loss["held"]["teleport"] / loss["view_frames"]
    assert f"| tracker_loss | 2 | {loss['view_frames']} | {teleport:.3f} |" in block


def test_quick_results_are_refused_as_evidence(generator: ModuleType) -> None:
    with pytest.raises(SystemExit):
        generator.main(["record", "paper", "--quick"])


def _anchor(heading: str) -> str:
    """GitHub's anchor of a markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_links_into_the_evidence_page_name_its_sections(generator: ModuleType) -> None:
    text = generator.PAGE.read_text(encoding="utf-8")
    anchors = {_anchor(h) for h in re.findall(r"^#{1,6} (.+)$", text, re.M)}
    sections = ("accuracy-against-the-paper", "robustness", "simulator-check", "real-recordings", "speed", "soak")
    assert set(sections) <= anchors
    guides = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").glob("*.md"))]
    broken = [
        f"{path.relative_to(ROOT)}: #{anchor}"
        for path in guides
        if path.is_file()
        for anchor in re.findall(r"evidence\.md#([\w-]+)", path.read_text(encoding="utf-8"))
        if anchor not in anchors
    ]
    assert not broken, f"links to sections docs/evidence.md does not have: {broken}"
