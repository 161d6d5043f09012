"""`stt-drake diagram [SCENARIO]`: the scenario's Drake Diagram as a Graphviz picture.

Writes ``diagram.dot`` (Drake's ``GetGraphvizString``) and renders it to SVG and PNG with
Graphviz's ``dot`` program (Debian package ``graphviz``), so a user sees how the systems
are wired.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
from pathlib import Path

from stt_drake.cli.main import (
    BadInputError,
    CommandError,
    add_scenario_arguments,
    load_scenario_arguments,
)


def write_diagram_pictures(dot_text: str, out_dir: Path, formats: tuple[str, ...]) -> list[Path]:
    """Write `dot_text` to out_dir/diagram.dot and render it to each format with `dot`.

    Raises:
        FileNotFoundError: if Graphviz's `dot` is not installed (the .dot file is written).
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    dot_path = out_dir / "diagram.dot"
    dot_path.write_text(dot_text)
    written = [dot_path]
    dot = shutil.which("dot")
    if dot is None:
        raise FileNotFoundError(
            f"Graphviz's `dot` program is not installed, so only {dot_path} was written "
            "(install the graphviz package: `sudo apt-get install graphviz`)"
        )
    for fmt in formats:
        picture = out_dir / f"diagram.{fmt}"
        subprocess.run([dot, f"-T{fmt}", str(dot_path), "-o", str(picture)], check=True)
        written.append(picture)
    return written


def _diagram(args: argparse.Namespace) -> bool:
    from stt_drake.assembly.diagram import build_diagram

    if args.depth < 0:
        raise BadInputError(
            "stt-drake: --depth: must be ≥ 0 (how many levels of nested diagrams to expand) "
            f"(got {args.depth})"
        )
    scenario, out_dir = load_scenario_arguments(args)
    diagram = build_diagram(scenario).diagram
    try:
        written = write_diagram_pictures(
            diagram.GetGraphvizString(max_depth=args.depth), out_dir, tuple(args.format)
        )
    except FileNotFoundError as error:
        raise CommandError(f"stt-drake: {error}") from error
    print(f"wrote {', '.join(str(p) for p in written)}")
    return True


def add_parser(commands: argparse._SubParsersAction) -> None:
    """Declare `stt-drake diagram`."""
    parser = commands.add_parser(
        "diagram",
        help="draw the scenario's Drake Diagram (Graphviz SVG/PNG)",
        description="Writes diagram.dot, diagram.svg and diagram.png into the out folder.",
        epilog="Exit code 0: written; 1: Graphviz's dot program is missing (only diagram.dot "
        "is written); 2: bad input.",
    )
    add_scenario_arguments(parser)
    parser.add_argument(
        "--format",
        nargs="+",
        choices=["svg", "png"],
        default=["svg", "png"],
        help="picture formats (default: svg png)",
    )
    parser.add_argument(
        "--depth",
        type=int,
        default=1,
        help="how many levels of nested diagrams to expand (default 1)",
    )
    parser.set_defaults(handler=_diagram)
