"""What the README and the documentation pages show works as written: every Python block
runs, every `stt-drake` line of a shell block is accepted by the command-line parser,
every `make` line names a target of the Makefile, and the README's case-study table lists
every packaged scenario."""

import json
import os
import re
import shlex
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from io import StringIO
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PAGES = sorted(
    [ROOT / "README.md", *(p for p in (ROOT / "docs").rglob("*.md") if "_build" not in p.parts)]
)
#: Fences whose lines are commands: each `stt-drake` and `make` line is checked.
SHELL = {"bash", "console", "sh", "shell"}
#: Fences shown, not run: output samples, usage synopses, data (yaml/json are checked where
#: they are loaded, in test_docs_site.py).
SHOWN = {"text", "yaml", "json"}
FENCE = re.compile(r"^```([^\n`]*)\n(.*?)^```[ \t]*$", re.M | re.S)


def _blocks(page: Path) -> list[tuple[str, int, str]]:
    """(language, first line number, text) of every fenced block of `page`."""
    text = page.read_text(encoding="utf-8")
    return [
        (match[1].strip(), text.count("\n", 0, match.start()) + 2, match[2])
        for match in FENCE.finditer(text)
    ]


def _name(page: Path) -> str:
    return str(page.relative_to(ROOT))


def _python_pages() -> list[Path]:
    return [page for page in PAGES if any(lang == "python" for lang, _, _ in _blocks(page))]


# Runs a page's blocks in order in one namespace; a failing block is named by its line.
RUNNER = """
import json, sys, traceback
page, blocks = json.load(sys.stdin)
namespace = {"__name__": "__main__"}
for line, code in blocks:
    try:
        exec(compile(code, f"{page}:{line}", "exec"), namespace)
    except BaseException:
        traceback.print_exc()
        sys.exit(f"the block at {page}:{line} failed")
"""


@pytest.mark.slow
@pytest.mark.parametrize("page", _python_pages(), ids=_name)
def test_python_blocks_run(page):
    """Each page's Python blocks, in order, in a fresh interpreter started in the repository
    root: they exit 0."""
    blocks = [(line, code) for lang, line, code in _blocks(page) if lang == "python"]
    result = subprocess.run(
        [sys.executable, "-c", RUNNER],
        input=json.dumps([_name(page), blocks]),
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "MPLBACKEND": "Agg"},
        timeout=300,
    )
    assert result.returncode == 0, result.stderr[-4000:]


def test_every_block_has_a_known_language():
    """A block without a language would be checked by no test: each says what it is."""
    for page in PAGES:
        for lang, line, _ in _blocks(page):
            known = lang in SHELL | SHOWN | {"python"} or lang.startswith("{")
            assert known, f"{_name(page)}:{line}: a ``` block needs one of python, bash, text, ..."


def _commands(code: str, lang: str) -> list[str]:
    """The command lines of a shell block: continuations joined, prompts (console) and
    comments removed."""
    joined = code.replace("\\\n", " ")
    commands = []
    for raw in joined.splitlines():
        line = raw.strip()
        if lang == "console":
            if not line.startswith("$ ") and not line.startswith(("stt-drake", "make")):
                continue  # output
            line = line.removeprefix("$ ")
        words = shlex.split(line, comments=True)
        if words:
            commands.append(words)
    return commands


def _shell_commands() -> list[tuple[str, list[str]]]:
    return [
        (f"{_name(page)}:{line}", words)
        for page in PAGES
        for lang, line, code in _blocks(page)
        if lang in SHELL
        for words in _commands(code, lang)
    ]


def _parse(words: list[str]) -> tuple[int, str]:
    """The exit code of the CLI's argument parser on `words` (0: accepted), and what it
    printed. Nothing runs: the subcommand's handler is not called."""
    from stt_drake.cli.main import _parser

    out = StringIO()
    try:
        with redirect_stdout(out), redirect_stderr(out):
            _parser().parse_args(words)
    except SystemExit as stop:  # --help, --version (0) or a usage error (2)
        return int(stop.code or 0), out.getvalue()
    return 0, out.getvalue()


def test_stt_drake_lines_parse():
    """Every `stt-drake ...` line of a shell block is accepted by the real parser."""
    lines = [(where, words) for where, words in _shell_commands() if words[0] == "stt-drake"]
    assert len(lines) >= 20
    for where, words in lines:
        code, printed = _parse(words[1:])
        assert code == 0, f"{where}: {shlex.join(words)}\n{printed}"


def test_the_parser_check_can_fail():
    """The check above refuses what the parser refuses."""
    assert _parse(["run", "--no-such-flag"])[0] == 2
    assert _parse(["campaign", "omni_hardware_case1"])[0] == 2  # --runs is required
    assert _parse(["run", "omni_hardware_case1", "--quiet"])[0] == 0


def _make_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text(encoding="utf-8")
    return set(re.findall(r"^([A-Za-z][\w.-]*)\s*:(?!=)", text, re.M))


def test_make_lines_name_makefile_targets():
    targets = _make_targets()
    assert {"demo", "test", "docs"} <= targets
    lines = [(where, words) for where, words in _shell_commands() if words[0] == "make"]
    assert lines
    for where, words in lines:
        named = [word for word in words[1:] if "=" not in word and not word.startswith("-")]
        assert named, f"{where}: `make` with no target"
        for target in named:
            assert target in targets, f"{where}: no Makefile target {target!r}"


def _case_study_names() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text.split("## Case studies", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"^\| `([\w.-]+)` \|", section, re.M)


def test_readme_lists_every_packaged_scenario():
    names = _case_study_names()
    assert len(names) == len(set(names)), "a scenario listed twice"
    assert set(names) == {path.stem for path in (ROOT / "diagrams").glob("*.yaml")}


def test_readme_is_a_front_door():
    """Short, with working links, and no development history."""
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), target
    for page in PAGES:
        history = re.search(r"\bissue \d+|\bwe fixed\b|\bmeasured here\b", page.read_text("utf-8"))
        assert history is None, f"{_name(page)}: {history[0]!r}"
