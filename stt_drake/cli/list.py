"""`stt-drake list`: the scenarios shipped in the package, by name, each with the first line
of its header comment. `stt-drake run NAME` runs one from any folder."""

from __future__ import annotations

import argparse

from stt_drake.cli.main import DEFAULT_SCENARIO, packaged_scenarios


def first_comment_line(text: str) -> str:
    """The first ``#`` comment line of a scenario file, without the ``#`` ('' if none)."""
    for line in text.splitlines():
        if line.lstrip().startswith("#"):
            return line.lstrip().lstrip("#").strip()
    return ""


def _list(args: argparse.Namespace) -> bool:
    scenarios = packaged_scenarios()
    width = max((len(name) for name in scenarios), default=0)
    for name, path in scenarios.items():
        summary = first_comment_line(path.read_text(encoding="utf-8"))
        print(f"{name:<{width}}  {summary}".rstrip())
    print(f"\nrun one with: stt-drake run NAME (default: {DEFAULT_SCENARIO})")
    return True


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake list`."""
    parser = commands.add_parser(
        "list",
        help="list the packaged scenarios (stt-drake run NAME runs one)",
        description="The scenarios shipped in the package: name and the first line of its "
        "header comment. Exit code 0.",
    )
    parser.set_defaults(handler=_list)
