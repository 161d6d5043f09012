"""`stt-drake list`: the scenarios shipped in the package, by name, each with the first
sentence of its header comment: wrapped to the terminal's width on a terminal, one line per
scenario otherwise (for grep). `stt-drake run NAME` runs one from any folder."""

from __future__ import annotations

import argparse
import re
import shutil
import sys
import textwrap

from stt_drake.cli.main import DEFAULT_SCENARIO, packaged_scenarios

#: Where a sentence ends: ., ! or ? then white space and a capital letter (so "Sec. 6.1",
#: "e.g. balls" and "main3D.m in" do not end one).
_SENTENCE_END = re.compile(r"(?<=[.!?])\s+(?=[A-Z])")


def header_paragraph(text: str) -> str:
    """The first paragraph of a scenario file's header comment: its ``#`` lines up to the
    first empty comment line or line that is not a comment, joined with single spaces ('' if
    the file does not start with a comment)."""
    words = []
    for line in text.splitlines():
        stripped = line.strip()
        if not stripped.startswith("#"):
            break
        content = stripped.lstrip("#").strip()
        if not content:
            break
        words.append(content)
    return " ".join(words)


def first_sentence(paragraph: str) -> str:
    """The first whole sentence of `paragraph` (all of it if it has one sentence)."""
    return _SENTENCE_END.split(paragraph, maxsplit=1)[0]


def _list(args: argparse.Namespace) -> bool:
    scenarios = packaged_scenarios()
    width = max((len(name) for name in scenarios), default=0)
    terminal = sys.stdout.isatty()
    columns = max(shutil.get_terminal_size().columns, width + 40)
    for name, path in scenarios.items():
        summary = first_sentence(header_paragraph(path.read_text(encoding="utf-8")))
        line = f"{name:<{width}}  {summary}".rstrip()
        if terminal:
            indent = " " * (width + 2)
            line = textwrap.fill(
                line,
                columns - 1,
                subsequent_indent=indent,
                break_long_words=False,  # a file or folder name stays whole
                break_on_hyphens=False,
            )
        print(line)
    print(f"\nrun one with: stt-drake run NAME (default: {DEFAULT_SCENARIO})")
    return True


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake list`."""
    parser = commands.add_parser(
        "list",
        help="list the packaged scenarios (stt-drake run NAME runs one)",
        description="The scenarios shipped in the package: each name and the first sentence "
        "of its header comment.",
        epilog="Exit code 0.",
    )
    parser.set_defaults(handler=_list)
