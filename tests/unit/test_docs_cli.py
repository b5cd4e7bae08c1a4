"""Every ``skelfuse`` command and option that README.md and docs/*.md name exists in the command line.

The parser is its own schema (as ``test_config_docs.py`` uses the config parser's): ``build_parser()`` builds
every command, and each ``skelfuse ...`` a page names, in a code span or a code block, is walked down the
subcommands; its options must be options of the command it reaches (or of ``skelfuse`` itself). An option named
on its own (`` `--take-duration` ``) must be an option of some command or script, unless another tool owns it
(:data:`FOREIGN_OPTIONS`). A ``scripts/NAME.py ...`` line must name a script that exists, and options its
parser declares (read from its source: the scripts are not a package).
"""

from __future__ import annotations

import argparse
import re
import shlex
from dataclasses import dataclass
from pathlib import Path

import pytest

from skelfuse.cli import build_parser
from skelfuse.cli.commands import COMMANDS

ROOT = Path(__file__).resolve().parents[2]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: options of other programs that the pages name in code spans of their own; each with whose it is
FOREIGN_OPTIONS: dict[str, str] = {
    "--randomly-seed": "pytest-randomly",
    "--external-sync": "k4arecorder",
}

#: code spans that read as a command line but name something else: rows of ``skelfuse eval real``'s report
NOT_COMMANDS = {"skelfuse lag 3", "skelfuse rts"}

#: the top-level commands, for spans that name one without ``skelfuse`` (`` `fuse --input` ``)
TOP_LEVEL = tuple(COMMANDS)

OPTION = re.compile(r"^--?[A-Za-z][-A-Za-z0-9]*")
COMMAND_WORD = re.compile(r"^[a-z][a-z0-9-]*$")


@dataclass(frozen=True)
class Mention:
    page: str
    line: int
    text: str


def options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {s: action for action in parser._actions for s in action.option_strings}


def option_strings(parser: argparse.ArgumentParser) -> set[str]:
    return set(options(parser))


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def every_parser(parser: argparse.ArgumentParser) -> list[argparse.ArgumentParser]:
    found = [parser]
    for child in subcommands(parser).values():
        found.extend(every_parser(child))
    return found


@pytest.fixture(scope="module")
def parser() -> argparse.ArgumentParser:
    return build_parser()


def code_spans(text: str) -> list[tuple[int, str]]:
    """(line number, content) of each inline code span and each line of a fenced code block."""
    spans: list[tuple[int, str]] = []
    fenced = False
    for number, line in enumerate(text.splitlines(), start=1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            spans.append((number, line.split(" #")[0].strip()))
        else:
            spans.extend((number, span) for span in re.findall(r"`([^`\n]+)`", line))
    return spans


def command_lines(span: str) -> list[str]:
    """Each ``skelfuse ...`` command line in ``span`` (a shell line may hold several, joined by ; && |), and
    each span that starts with a top-level command followed by an option (`` `export --format fbx` ``)."""
    span = span.replace("\\|", "|").removeprefix("$ ")
    found = []
    for part in re.split(r"\s*(?:;|&&|\|\|| \| )\s*", span):
        part = re.sub(r"^(?:python3? -m |uv run |sudo |\S+=\S+ )+", "", part.strip())
        words = part.split()
        if len(words) >= 2 and words[0] in TOP_LEVEL and words[1].startswith("--"):
            part = f"skelfuse {part}"
        if (part == "skelfuse" or part.startswith("skelfuse ")) and part not in NOT_COMMANDS:
            found.append(part)
    return found


def script_lines(span: str) -> list[tuple[Path, list[str]]]:
    """(script, its options) of each ``[python] scripts/NAME.py ...`` line in ``span``."""
    found = []
    for match in re.finditer(r"(?:^|python3? )(scripts/[A-Za-z0-9_]+\.py)((?: [^;&|]*)?)", span):
        found.append((ROOT / match.group(1), re.findall(r"(?<!\S)(--[a-z][-a-z0-9]*)", match.group(2))))
    return found


def declared_options(script: Path) -> set[str]:
    """The options a script's argparse parser declares, read from its source."""
    return set(re.findall(r"[\"'](--[a-z][-a-z0-9]*)[\"']", script.read_text(encoding="utf-8")))


def mentions(kind: str) -> list[Mention]:
    """Every command line (``kind="command"``), script line (``"script"``) or lone option span (``"option"``)."""
    found = []
    for page in PAGES:
        for number, span in code_spans(page.read_text(encoding="utf-8")):
            where = page.relative_to(ROOT).as_posix()
            if kind == "command":
                found.extend(Mention(where, number, line) for line in command_lines(span))
            elif kind == "script":
                found.extend(Mention(where, number, span) for _ in script_lines(span)[:1])
            elif (
                kind == "option" and (option := OPTION.match(span)) and span.startswith("--") and not span.endswith("*")
            ):
                found.append(Mention(where, number, option.group(0)))
    return found


def tokens(line: str) -> list[str]:
    try:
        return shlex.split(line, comments=False)
    except ValueError:  # an unbalanced quote in an excerpt: words are enough here
        return line.split()


def problems_in(line: str, parser: argparse.ArgumentParser) -> list[str]:
    """What ``line`` (``skelfuse ...``) names that the command line lacks."""
    problems = []
    here, path = parser, ["skelfuse"]
    global_options = options(parser)
    takes_value = False
    for word in tokens(line)[1:]:
        if word.startswith("-") and not re.match(r"^-\d", word):
            option = OPTION.match(word)
            action = {**global_options, **options(here)}.get(option.group(0)) if option else None
            if option and action is None:
                problems.append(f"{' '.join(path)} has no option {option.group(0)}")
            takes_value = action is not None and action.nargs != 0 and "=" not in word
            continue
        if takes_value:
            takes_value = False  # the option's value, not a command
            continue
        choices = subcommands(here)
        if not choices:
            continue  # an argument of a leaf command: a file, a value
        alternatives = word.split("|")
        if not all(COMMAND_WORD.match(a) for a in alternatives):
            continue  # a placeholder (CMD, [IN...]) or a value: nothing to check
        unknown = [a for a in alternatives if a not in choices]
        if unknown:
            problems.append(f"{' '.join(path)} has no command {'|'.join(unknown)}")
            break
        here, path = choices[alternatives[0]], [*path, word]
    return problems


def named_commands(line: str, parser: argparse.ArgumentParser) -> set[str]:
    """The commands ``line`` names, as "group sub" paths (``skelfuse bench fusion|people`` names two)."""
    words = tokens(line)[1:3]
    if not words or words[0] not in subcommands(parser):
        return set()
    group = words[0]
    if len(words) < 2 or not subcommands(subcommands(parser)[group]):
        return {group}
    return {f"{group} {sub}" for sub in words[1].split("|")}


def test_the_readme_names_every_command(parser: argparse.ArgumentParser) -> None:
    """The README's commands table names every command and subcommand (and so the walk has work to do)."""
    every = {
        f"{name} {sub}" if sub else name
        for name, command in subcommands(parser).items()
        for sub in (subcommands(command) or {"": None})
    }
    named = set().union(*(named_commands(m.text, parser) for m in mentions("command") if m.page == "README.md"))
    assert every <= named, f"not in the README: {sorted(every - named)}"


def test_every_named_command_and_option_exists(parser: argparse.ArgumentParser) -> None:
    problems = [
        f"{m.page}:{m.line}: `{m.text}`: {problem}"
        for m in mentions("command")
        for problem in problems_in(m.text, parser)
    ]
    assert not problems, "the docs name what the command line lacks:\n" + "\n".join(problems)


def test_every_named_script_and_its_options_exist() -> None:
    problems = []
    for m in mentions("script"):
        for script, named in script_lines(m.text):
            if not script.is_file():
                problems.append(f"{m.page}:{m.line}: {script.relative_to(ROOT)} does not exist")
                continue
            missing = set(named) - declared_options(script) - {"--help"}
            problems.extend(f"{m.page}:{m.line}: {script.name} has no option {o}" for o in sorted(missing))
    assert not problems, "the docs name scripts or script options that do not exist:\n" + "\n".join(problems)


def test_every_lone_option_is_an_option_of_some_command(parser: argparse.ArgumentParser) -> None:
    known = set().union(*(option_strings(p) for p in every_parser(parser)))
    known |= set().union(*(declared_options(script) for script in (ROOT / "scripts").glob("*.py")))
    unknown = [f"{m.page}:{m.line}: {m.text}" for m in mentions("option") if m.text not in known | set(FOREIGN_OPTIONS)]
    assert not unknown, "options no command takes (another tool's? list it in FOREIGN_OPTIONS):\n" + "\n".join(unknown)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        pytest.param("skelfuse demo --duration 10", [], id="known"),
        pytest.param("skelfuse demo --no-such-option", ["skelfuse demo has no option --no-such-option"], id="option"),
        pytest.param("skelfuse frobnicate", ["skelfuse has no command frobnicate"], id="command"),
        pytest.param("skelfuse bench fusion|nope", ["skelfuse bench has no command nope"], id="alternative"),
        pytest.param("skelfuse eval real [IN...] --json", [], id="placeholder"),
        pytest.param("skelfuse -v calibrate skeleton -o cal.toml", [], id="global-option"),
    ],
)
def test_the_walk_catches_what_is_missing(parser: argparse.ArgumentParser, line: str, expected: list[str]) -> None:
    assert problems_in(line, parser) == expected


def test_the_readme_maps_every_guide() -> None:
    """The README's documentation map links every page of docs/."""
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    linked = set(re.findall(r"\]\(docs/([a-z0-9-]+\.md)\)", readme))
    pages = {page.name for page in (ROOT / "docs").glob("*.md")}
    assert pages <= linked, f"docs/ pages the README does not link: {sorted(pages - linked)}"
