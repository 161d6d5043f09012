"""The `stt-drake` command: its argument parser, the dispatch to a subcommand and exit codes.

Each subcommand is a module of this package (:data:`SUBCOMMAND_MODULES`) with
``add_parser(commands)``, which declares its arguments and sets ``handler``: a function of
the parsed arguments that returns whether the run succeeded, or raises
:class:`CommandError` (:class:`BadInputError` for bad input). :func:`main` is the one place
that turns those into messages and exit codes: 0 success, 1 a guarantee failed, the goal
was missed or the run stopped early (its metrics say why), 2 bad input.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import os
import platform
import re
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from stt_drake.diagrams import packaged_scenarios as packaged_scenarios  # `list`'s
from stt_drake.diagrams import scenario_file

if TYPE_CHECKING:
    from stt_drake.config import Scenario

#: The packaged scenario `stt-drake run` and `stt-drake diagram` use when none is given.
DEFAULT_SCENARIO = "omni_hardware_case1"

EXIT_SUCCESS, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2

#: The one table from a library parameter to the command-line argument that sets it: the
#: library's errors name their parameters in backticks (```runs```), the command's
#: messages the flag (:func:`flag_message`).
PARAMETER_FLAGS = {
    "chunk_size": "--chunk-size",
    "comfort_distance": "--comfort-distance",
    "controllers": "--controllers",
    "dask_timeout": "--dask-timeout",
    "draws": "--draws",
    "kind": "--kind",
    "model_error": "--model-error",
    "motion": "--true-obstacle-motion",
    "out_dir": "--out",
    "resume": "--resume",
    "runs": "--runs",
    "scenario_path": "SCENARIO",
    "scheduler": "--scheduler",
    "seed": "--seed",
    "solver": "--solver",
    "tau": "--ou-tau",
    "workers": "--workers",
}
_PARAMETER = re.compile(r"`(" + "|".join(PARAMETER_FLAGS) + r")`")

#: Modules that add a subcommand (each defines ``add_parser(commands)``), in help order.
SUBCOMMAND_MODULES: tuple[str, ...] = (
    "stt_drake.cli.run",
    "stt_drake.cli.campaign",
    "stt_drake.cli.compare",
    "stt_drake.cli.diagram",
    "stt_drake.cli.bench",
    "stt_drake.cli.crowd",
    "stt_drake.cli.list",
    "stt_drake.cli.robot",
)


class CommandError(Exception):
    """A subcommand could not finish: :func:`main` prints the message to stderr (no
    traceback) and exits with :attr:`exit_code`."""

    exit_code = EXIT_FAILURE


class BadInputError(CommandError):
    """The command line, or a file it names, is invalid (exit code 2)."""

    exit_code = EXIT_BAD_INPUT


def flag_message(message: object) -> str:
    """A library error's message as the command says it: each parameter named in
    backticks (:data:`PARAMETER_FLAGS`) replaced by its flag."""
    return _PARAMETER.sub(lambda match: PARAMETER_FLAGS[match.group(1)], str(message))


def resolve_scenario(scenario: str | Path) -> Path:
    """The scenario file `scenario` names: an existing file, or a packaged scenario's name
    (:func:`stt_drake.diagrams.scenario_file`, the library's resolver).

    Raises:
        BadInputError: neither an existing file nor a packaged name; the message lists the
            packaged names closest to it.
    """
    try:
        return scenario_file(scenario, listed_by="`stt-drake list`")
    except FileNotFoundError as error:
        raise BadInputError(f"stt-drake: {error}") from None


def add_scenario_arguments(
    parser: argparse.ArgumentParser, scenario_help: str | None = None
) -> None:
    """Declare the optional positional scenario (a path or a packaged scenario's name,
    default :data:`DEFAULT_SCENARIO`) and ``--out``; read them back with
    :func:`load_scenario_arguments`."""
    parser.add_argument("scenario", nargs="?", default=DEFAULT_SCENARIO, help=scenario_help)
    parser.add_argument(
        "--out", type=Path, default=None, help="output folder (default: results/<scenario name>/)"
    )


def load_scenario_arguments(
    args: argparse.Namespace, seed: int | None = None, strict: bool = False
) -> tuple[Scenario, Path]:
    """The scenario named by ``args.scenario`` (a path or a packaged name, see
    :func:`resolve_scenario`; replaced by the file's path; loaded with `seed`, and with
    `strict` refusing a scenario that breaks Assumption 3 for the whole run) and the
    output folder (``args.out``, default results/<scenario name>/), checked writable
    before any work.

    Raises:
        BadInputError: if the scenario is not found, cannot be read or breaks a rule, its
            name cannot name a folder inside results/, or the output folder cannot be
            written.
    """
    from stt_drake.assembly import load_scenario
    from stt_drake.config import ScenarioError

    args.scenario = resolve_scenario(args.scenario)
    try:
        scenario = load_scenario(args.scenario, seed=seed, strict=strict)
    except ScenarioError as error:
        raise BadInputError(f"stt-drake: bad scenario {args.scenario}: {error}") from error
    out_dir = args.out if args.out is not None else results_folder(scenario.name, "name")
    check_out_folder(out_dir, "--out" if args.out is not None else "the output folder")
    return scenario, out_dir


def results_folder(name: str, what: str) -> Path:
    """``results/<name>``, the default output folder; `name` (described by `what` in the
    error) must be one plain folder name, so the folder stays inside ``results/``.

    Raises:
        BadInputError: for an empty name, ``.``, ``..``, an absolute path or a name with a
            path separator.
    """
    part = Path(name)
    plain = len(part.parts) == 1 and not part.is_absolute() and not set(name) & {"\\", "\0"}
    if name in ("", ".", "..") or not plain:
        raise BadInputError(
            f"stt-drake: {what} {name!r} cannot name a folder inside results/ (one plain "
            "folder name, no path separator, not . or ..); pass --out"
        )
    return Path("results") / name


def default_out_folder(scenario_path: Path, suffix: str = "") -> Path:
    """``results/<scenario name><suffix>``: the output folder a subcommand uses without
    ``--out`` (the name `stt-drake run` uses: the file's `name` field, else its file name),
    read from the file without drawing its random obstacles or checking its assumptions.

    Raises:
        BadInputError: the file cannot be read or parsed, or its name cannot name a folder
            inside results/ (:func:`results_folder`).
    """
    from stt_drake.config import ScenarioError, ScenarioText, read_scenario_file

    try:
        text = read_scenario_file(scenario_path)
        folder = str(scenario_path.resolve().parent)
        name = ScenarioText(text, scenario_path.stem, folder).parse().name
    except ScenarioError as error:
        raise BadInputError(f"stt-drake: bad scenario {scenario_path}: {error}") from error
    return results_folder(name + suffix, "the scenario's name")


def check_out_folder(folder: Path, option: str = "--out") -> None:
    """Refuse an output folder that cannot be written, before any work is done.

    Raises:
        BadInputError: naming `option` and the reason (:func:`stt_drake.runlog.unwritable_reason`).
    """
    from stt_drake.runlog import unwritable_reason

    reason = unwritable_reason(folder)
    if reason is not None:
        raise BadInputError(f"stt-drake: {option}: {folder} {reason}")


def announce_compilation() -> None:
    """Say so on stderr before a command compiles the kernels (an empty numba cache: the
    first run after installing or changing a compiled source), which takes a while."""
    from stt_drake.core.backend import kernels_cached

    if not kernels_cached():
        print(
            "stt-drake: compiling the numba kernels (first run only, 20-90 s)...",
            file=sys.stderr,
            flush=True,
        )


def version_line() -> str:
    """``stt-drake X (drake Y, numba Z, Python W)``: the installed versions, read from the
    package metadata (what `--version` prints)."""
    from importlib.metadata import PackageNotFoundError, version

    def installed(name: str) -> str:
        try:
            return version(name)
        except PackageNotFoundError:
            return "not installed"

    return (
        f"stt-drake {installed('stt-drake')} (drake {installed('drake')}, numba "
        f"{installed('numba')}, Python {platform.python_version()})"
    )


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="stt-drake",
        description="Spatiotemporal Tube control among uncertain moving obstacles (Drake).",
    )
    parser.add_argument(
        "--version",
        action="version",
        version=version_line(),
        help="print stt-drake's version and those of Drake, numba and Python, and exit",
    )
    commands = parser.add_subparsers(dest="command", required=True)
    for module in SUBCOMMAND_MODULES:
        importlib.import_module(module).add_parser(commands)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `stt-drake` console script: run the subcommand, return its exit
    code.

    A closed output pipe (``stt-drake list | head -3``) ends the command quietly with
    exit code 1, whichever subcommand it is (the recipe of Python's documentation of
    SIGPIPE: the rest of the output goes to ``os.devnull``, so the interpreter's final
    flush raises nothing either).
    """
    try:
        try:
            args = _parser().parse_args(argv)
        except SystemExit:  # --help, or a usage error: flushed here, where a closed pipe
            sys.stdout.flush()  # is caught
            raise
        try:
            succeeded = args.handler(args)
        except CommandError as error:
            print(error, file=sys.stderr)
            return error.exit_code
        sys.stdout.flush()  # inside the try: a pipe closed on the last lines is caught
    except BrokenPipeError:
        _discard_output()
        return EXIT_FAILURE
    return EXIT_SUCCESS if succeeded else EXIT_FAILURE


def _discard_output() -> None:
    """Point stdout and stderr at os.devnull (a closed pipe: nothing more can be said)."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # not a real file (a test's capture)
            os.dup2(devnull, stream.fileno())
    os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
