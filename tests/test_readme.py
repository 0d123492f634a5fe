"""The README and the docs name only commands, options and nox sessions that exist, and every
example command in them parses with evsmap's own parser (its values of the types and choices
the options take).

What is checked, in every code span and code block of README.md and docs/*.md:

* ``evsmap CMD [SUB]``: the command (and a ``datasets``, ``weights`` or ``cache``
  sub-command) exists (code blocks marked as Python, TOML and the like are not read);
* every option written after it (``--weights``, ``-o``, the alternatives of a synopsis such as
  ``[--weights FILE | --allow-random]``) is one of that command's options;
* a concrete example (a line of a code block without placeholders such as FILE, DIR or
  ``...``) parses: ``evsmap eval feagnet-v2 --dataset nyuv2 --weights w.pt`` passes,
  ``--frames 0`` or an unknown choice would not;
* ``nox -s NAME`` names a session of noxfile.py.
"""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

from evsmap.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SHELL_FENCES = {"", "bash", "sh", "shell", "console"}
"""Code blocks read as commands (a Python or TOML block is not)."""
SHELL_BREAKS = {"&&", "||", ";", "|", ">", ">>", "2>&1", "#", "\\"}
PLACEHOLDER = re.compile(r"(^|[^a-z])[A-Z]{2,}([^a-z]|$)|\.\.\.|<|>|\[|\]")
OPTION = re.compile(r"^--?[A-Za-z][A-Za-z0-9-]*$")


def code_snippets(text: str) -> list[tuple[str, bool]]:
    """``(snippet, is_block_line)``: every line of a fenced code block and every inline code
    span outside them."""
    snippets: list[tuple[str, bool]] = []
    in_block, shell = False, False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            in_block = not in_block
            shell = line.strip()[3:] in SHELL_FENCES
            continue
        if in_block:
            if shell:
                snippets.append((line, True))
        else:
            snippets += [(span, False) for span in re.findall(r"`([^`]+)`", line)]
    return snippets


def evsmap_invocations(snippet: str) -> list[list[str]]:
    """The words after each ``evsmap`` (or ``python -m evsmap``) in a snippet, up to the end
    of its shell command."""
    try:
        words = shlex.split(snippet, comments=True)
    except ValueError:  # an unbalanced quote in prose
        words = snippet.split()
    found = []
    for i, word in enumerate(words):
        if word != "evsmap" or (i and words[i - 1] in ("cd", "import", "from")):
            continue
        rest = []
        for w in words[i + 1:]:
            if w in SHELL_BREAKS or w.startswith(("#", ">", "2>")):
                break
            rest.append(w)
        if rest:
            found.append(rest)
    return found


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _options(parser: argparse.ArgumentParser) -> set[str]:
    return {s for a in parser._actions for s in a.option_strings}


def _resolve(words: list[str]) -> tuple[argparse.ArgumentParser, list[str], str] | None:
    """The (sub-)parser the words address, the words after its name, and its name; None for
    words that are not a command (``evsmap --help``, ``evsmap`` in prose)."""
    top = build_parser()
    commands = _subparsers(top)
    if not words or words[0] not in commands:
        return None
    parser, rest, name = commands[words[0]], words[1:], words[0]
    subs = _subparsers(parser)
    if subs and rest and re.match(r"^[a-z][a-z-]*$", rest[0]):
        assert rest[0] in subs, f"`evsmap {name} {rest[0]}`: no such sub-command " \
                                f"(known: {', '.join(subs)})"
        parser, rest, name = subs[rest[0]], rest[1:], f"{name} {rest[0]}"
    return parser, rest, name


def _mentioned_options(words: list[str]) -> list[str]:
    out = []
    for word in words:
        for part in re.split(r"[|\[\](),]", word):
            part = part.split("=", 1)[0] if part.startswith("--") else part
            if OPTION.match(part):
                out.append(part)
    return out


def collect() -> list[tuple[str, str, list[str], bool]]:
    """``(doc, snippet, words, is_block_line)`` of every evsmap invocation in the docs."""
    found = []
    for doc in DOCS:
        for snippet, block in code_snippets(doc.read_text(encoding="utf-8")):
            for words in evsmap_invocations(snippet):
                found.append((str(doc.relative_to(ROOT)), snippet, words, block))
    return found


INVOCATIONS = collect()


def test_the_docs_name_commands():
    assert len(INVOCATIONS) > 50  # the reference documents every command
    names = {words[0] for _, _, words, _ in INVOCATIONS}
    assert {"map", "eval", "predict", "speed", "reproduce", "synth", "info"} <= names


@pytest.mark.parametrize("doc, snippet, words, block", INVOCATIONS,
                         ids=[f"{d}:{' '.join(w)[:60]}" for d, _, w, _ in INVOCATIONS])
def test_every_named_command_and_option_exists(doc, snippet, words, block):
    resolved = _resolve(words)
    if resolved is None:
        first = words[0]
        assert first.startswith("-") or not re.match(r"^[a-z][a-z-]+$", first) or \
            first in ("command", "commands"), \
            f"{doc}: `evsmap {first}` is not a command ({snippet!r})"
        return
    parser, rest, name = resolved
    known = _options(parser)
    unknown = [o for o in _mentioned_options(rest) if o not in known]
    assert not unknown, f"{doc}: `evsmap {name}` has no option {', '.join(unknown)} ({snippet!r})"
    if block and not PLACEHOLDER.search(" ".join(rest)):
        try:
            parser.parse_args(rest)
        except SystemExit:
            pytest.fail(f"{doc}: the example `evsmap {' '.join(words)}` does not parse")


def _nox_sessions() -> set[str]:
    text = (ROOT / "noxfile.py").read_text()
    return set(re.findall(r"@nox\.session[^\n]*\n(?:@[^\n]*\n)*def (\w+)", text))


def test_nox_sessions_named_in_the_docs_exist():
    sessions = _nox_sessions()
    assert {"tests", "reproduce", "gates", "lint"} <= sessions
    named = set()
    for doc in DOCS:
        for snippet, _ in code_snippets(doc.read_text(encoding="utf-8")):
            named |= {(str(doc.relative_to(ROOT)), n)
                      for n in re.findall(r"\bnox -s ([\w-]+)", snippet)}
    missing = sorted(f"{d}: nox -s {n}" for d, n in named if n not in sessions)
    assert not missing, missing


def test_the_readme_starts_with_a_first_map():
    """The first screen (60 lines) takes a new user from clone to a first map."""
    head = "\n".join((ROOT / "README.md").read_text().splitlines()[:60])
    assert "pip install" in head and "evsmap map " in head
