"""The bad-scenario corpus (tests/bad_scenarios/): every file is refused by `stt-drake run`
with exit code 2, one line on stderr that names the field path and the rule, no traceback,
nothing written, within 5 s — the contract of issue 12 for bad input.

Each corpus file is a valid base of tests/bad_scenarios/base/ with one defect, and says in
a comment line what it expects: ``# expect: <field path> | <word of the rule>`` (the path
``<file>`` stands for the file itself, for defects in its bytes). The bases are loaded too,
so every refusal comes from the defect alone. A few files also go through the installed
console script in a subprocess, to see the real process exit without a traceback. The
same bad inputs given on the command line (--seed, --depth, --out) are checked here too.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

from stt_drake.assembly import load_scenario
from stt_drake.cli.main import main
from stt_drake.config import ScenarioError, limits, source

HERE = Path(__file__).resolve().parents[1]
CORPUS = HERE / "bad_scenarios"
BASES = sorted((CORPUS / "base").glob("*.yaml"))
CASES = sorted(CORPUS.glob("*.yaml"))
OMNI_BASE = CORPUS / "base" / "omni.yaml"

#: The bound of issue 12 on refusing one bad file (seconds). Generous on purpose: this is a
#: contract (no hang, no spin), not a speed benchmark; a refusal takes ~10-50 ms.
REFUSAL_BOUND_S = 5.0

#: Files also run through the console script in a subprocess (interpreter start included).
SUBPROCESS_CASES = (
    "k1_inf",
    "scheme_bogus",
    "billion_laughs",
    "latin1_bytes",
    "random_count_1e8",
    "duplicate_top_level",
)


def expectation(path: Path) -> tuple[str, str]:
    """(field path, rule word) from the file's ``# expect:`` line; ``<file>`` → the path."""
    data = path.read_bytes()
    text = (
        data.decode("utf-16")
        if data[:2] in (b"\xff\xfe", b"\xfe\xff")
        else data.decode("utf-8", errors="replace")
    )
    match = re.search(r"^# expect: (.+?) \| (.+?)\s*$", text, re.MULTILINE)
    assert match, f"{path.name}: no '# expect: <field path> | <word>' line"
    field, word = match.group(1), match.group(2)
    return (str(path) if field == "<file>" else field), word


def assert_one_line_naming(message: str, field: str, word: str) -> None:
    """`message` is one line, names exactly `field` (not a longer path it prefixes) and
    the rule `word` (outside the echoed "(got ...)" value)."""
    assert "\n" not in message.strip(), f"not one line: {message!r}"
    assert re.search(re.escape(field) + r"(?![\w.\[])", message), (
        f"expected field path {field!r} in: {message}"
    )
    rule = message.rsplit(" (got ", 1)[0]
    assert word in rule, f"expected rule word {word!r} in: {message}"


@pytest.fixture(scope="module", autouse=True)
def _warm() -> None:
    """Load a base once before the timed cases: the first use of the compiled kernels in a
    process loads them (or compiles them on a fresh checkout), which is no part of
    refusing a file."""
    load_scenario(OMNI_BASE)


def test_the_corpus_has_at_least_100_files():
    assert len(CASES) >= 100, len(CASES)
    assert len({expectation(path) for path in CASES}) > 90  # not one defect many times


@pytest.mark.parametrize("base", BASES, ids=lambda p: p.stem)
def test_every_base_is_valid(base):
    assert load_scenario(base).name == f"bad_base_{base.stem}"


@pytest.mark.parametrize("path", CASES, ids=lambda p: p.stem)
def test_bad_scenario_exits_2_with_one_line_naming_field_and_rule(path, tmp_path, capsys):
    field, word = expectation(path)
    out = tmp_path / "out"
    start = time.perf_counter()
    code = main(["run", str(path), "--out", str(out), "--no-figures"])
    elapsed = time.perf_counter() - start
    captured = capsys.readouterr()
    assert code == 2, captured.out + captured.err
    assert captured.out == ""
    assert_one_line_naming(captured.err, field, word)
    assert "Traceback" not in captured.err
    assert not out.exists(), "a refused scenario wrote its out folder"
    assert elapsed < REFUSAL_BOUND_S, f"{path.name}: refused after {elapsed:.2f} s"


def _console_script() -> str:
    script = Path(sys.executable).parent / "stt-drake"
    assert script.exists(), "the stt-drake console script is not installed next to python"
    return str(script)


@pytest.mark.slow
@pytest.mark.parametrize("name", SUBPROCESS_CASES)
def test_bad_scenario_in_a_real_process_exits_2_without_traceback(name, tmp_path):
    path = CORPUS / f"{name}.yaml"
    field, word = expectation(path)
    out = tmp_path / "out"
    completed = subprocess.run(
        [_console_script(), "run", str(path), "--out", str(out), "--no-figures"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert completed.returncode == 2, completed.stdout + completed.stderr
    assert "Traceback" not in completed.stdout + completed.stderr
    assert_one_line_naming(completed.stderr, field, word)
    assert not out.exists()


# --------------------------------------------------------------------------- command line


def _refused(args: list[str], capsys) -> str:
    start = time.perf_counter()
    code = main(args)
    elapsed = time.perf_counter() - start
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and "\n" not in err.strip()
    assert elapsed < REFUSAL_BOUND_S
    return err


def test_run_with_a_negative_seed_exits_2_naming_seed(tmp_path, capsys):
    err = _refused(["run", str(OMNI_BASE), "--seed", "-1", "--out", str(tmp_path / "o")], capsys)
    assert "--seed" in err and "[0, 2^63" in err
    assert not (tmp_path / "o").exists()


def test_diagram_with_a_negative_depth_exits_2_naming_depth(tmp_path, capsys):
    err = _refused(
        ["diagram", str(OMNI_BASE), "--depth", "-5", "--out", str(tmp_path / "o")], capsys
    )
    assert "--depth" in err and "≥ 0" in err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("command", ["run", "diagram"])
def test_an_out_folder_that_cannot_be_made_exits_2_before_any_simulation(command, tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder\n")
    for out in (blocker, blocker / "sub"):
        err = _refused([command, str(OMNI_BASE), "--out", str(out)], capsys)
        assert "--out" in err and "not a folder" in err
    assert blocker.read_text() == "not a folder\n"


@pytest.mark.parametrize("command", ["run", "diagram"])
def test_non_utf8_file_exits_2_in_run_and_diagram(command, tmp_path, capsys):
    path = CORPUS / "latin1_bytes.yaml"
    err = _refused([command, str(path), "--out", str(tmp_path / "o")], capsys)
    assert "not UTF-8" in err and "0xe9" in err
    assert not (tmp_path / "o").exists()


def test_missing_scenario_exits_2(tmp_path, capsys):
    err = _refused(["run", str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "o")], capsys)
    assert "no such scenario file" in err


# --------------------------------------------------------------------------- the limits


def test_memory_budget_is_overridden_by_the_environment_and_by_the_scenario(monkeypatch):
    text = OMNI_BASE.read_text()
    heavy = text.replace("log_period: 0.02\n", "log_period: 2.0e-4\n")  # ~ 0.2 GB of logs
    monkeypatch.setenv(limits.MEMORY_BUDGET_ENV, "0.1")
    with pytest.raises(ScenarioError) as info:
        _parse(heavy)
    assert_one_line_naming(str(info.value), "scenario.log_period", "memory budget")
    assert limits.MEMORY_BUDGET_ENV in str(info.value) and "0.1 GB" in str(info.value)
    monkeypatch.setenv(limits.MEMORY_BUDGET_ENV, "1")
    assert _parse(heavy).log_period == 2.0e-4
    # The scenario's own budget comes first.
    with pytest.raises(ScenarioError, match=r"scenario\.max_memory_gb"):
        _parse(heavy.replace("max_memory_gb: 0.0\n", "max_memory_gb: 0.05\n"))
    monkeypatch.setenv(limits.MEMORY_BUDGET_ENV, "lots")
    with pytest.raises(ScenarioError, match=limits.MEMORY_BUDGET_ENV):
        _parse(text)


def test_memory_estimate_counts_samples_obstacles_and_copies():
    # 501 samples of 3 obstacles in 2D: 3·(2 + 4 + 7) + 128 values, 8 B, 3 copies, + 3·4 kB.
    assert limits.estimate_run_bytes(501, 3, 2) == 3 * 8 * 501 * (3 * 13 + 128) + 3 * 4096


def test_an_oversized_file_is_refused_unread(tmp_path, monkeypatch):
    monkeypatch.setattr(source, "MAX_FILE_BYTES", 100)
    path = tmp_path / "big.yaml"
    path.write_text("# " + "x" * 200 + "\n")
    with pytest.raises(ScenarioError, match="at most 100"):
        load_scenario(path)


def test_a_utf8_byte_order_mark_is_accepted(tmp_path):
    path = tmp_path / "bom.yaml"
    path.write_bytes(b"\xef\xbb\xbf" + OMNI_BASE.read_bytes())
    assert load_scenario(path).name == "bad_base_omni"


def test_short_repr_never_forms_the_whole_repr():
    nested: list = [1] * 10
    for _ in range(8):  # 10^9 leaves when expanded
        nested = [nested] * 10
    text = source.short_repr(nested)
    assert len(text) <= source.REPR_LIMIT and text.endswith("...")


def _parse(text: str):
    from stt_drake.assembly import parse_scenario

    return parse_scenario(text)
