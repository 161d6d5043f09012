"""The documentation site builds with warnings as errors, and its generated pages hold what
the code says: every scenario field, every public module, every exported name."""

import dataclasses
import html
import importlib.util
import re
import subprocess
import sys
from pathlib import Path

import pytest

import stt_drake

ROOT = Path(__file__).resolve().parents[2]
DOCS = ROOT / "docs"

pytestmark = pytest.mark.skipif(importlib.util.find_spec("sphinx") is None, reason="needs sphinx")


def _extension():
    sys.path.insert(0, str(DOCS / "_ext"))
    try:
        import stt_docs
    finally:
        sys.path.remove(str(DOCS / "_ext"))
    return stt_docs


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built from scratch (-E) with -W --keep-going: any warning fails the build."""
    out = tmp_path_factory.mktemp("docs") / "html"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            "-E",
            "-W",
            "--keep-going",
            "-q",
            "-b",
            "html",
            str(DOCS),
            str(out),
        ],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=ROOT,
    )
    assert result.returncode == 0, result.stderr[-5000:]
    return out


def _page(site: Path, name: str) -> str:
    """A built page's HTML, with every run of white space as one space."""
    return " ".join((site / name).read_text(encoding="utf-8").split())


def _text(site: Path, name: str) -> str:
    """A built page's text: tags removed, entities decoded, white space as one space."""
    return " ".join(html.unescape(re.sub(r"<[^>]+>", "", _page(site, name))).split())


@pytest.mark.slow
def test_pages_exist(site):
    for name in [
        "index.html",
        "design.html",
        "api.html",
        "guide/getting_started.html",
        "guide/guarantees.html",
        "guide/outputs.html",
        "guide/own_diagram.html",
        "guide/robot.html",
        "guide/development.html",
        "guide/real_time.html",
        "guide/full_covariances.html",
        "guide/perception.html",
        "guide/guide.html",
        "guide/baselines.html",
        "guide/campaigns.html",
        "guide/crowds.html",
        "guide/plants.html",
        "guide/speed.html",
        "guide/faults.html",
        "guide/scenarios.html",
    ]:
        assert (site / name).is_file(), name


@pytest.mark.slow
def test_index_cites_the_paper_and_gives_the_two_commands(site):
    text = _text(site, "index.html")
    assert "Spatiotemporal Tubes for Probabilistic Temporal Reach-Avoid-Stay Task" in text
    assert "Upadhyay" in text and "Jagtap" in text
    assert "make demo" in text and "make test" in text


@pytest.mark.slow
def test_scenario_reference_lists_every_schema_field(site):
    """Generated from the dataclasses: each section's table names every field."""
    text = _page(site, "guide/scenarios.html")
    sections = _extension().schema_sections()
    names = {kind.__name__ for _, kind in sections}
    assert {
        "Scenario",
        "Obstacle",
        "TubeConfig",
        "Perception",
        "GuideConfig",
        "CrowdConfig",
        "Quadrotor",
        "FrankaArm",
        "Oscillation",
        "Recorded",
    } <= names
    for _, kind in sections:
        for item in dataclasses.fields(kind):
            assert (
                f'<code class="docutils literal notranslate"><span class="pre">{item.name}' in text
            ), (kind.__name__, item.name)


@pytest.mark.slow
def test_api_documents_every_public_module_and_name(site):
    text = _page(site, "api.html")
    stt_docs = _extension()
    for package in [
        "stt_drake.core",
        "stt_drake.systems",
        "stt_drake.assembly",
        "stt_drake.config",
        "stt_drake.campaign",
    ]:
        for module in stt_docs.public_modules(package):
            assert f'id="module-{module}"' in text, module
    homes = getattr(stt_drake, "_PUBLIC", {})
    for name in stt_drake.__all__:
        value = getattr(stt_drake, name)
        module = getattr(value, "__module__", None) if callable(value) else homes.get(name)
        target = f"{module}.{name}"
        assert f'id="{target}"' in text, f"{target} is not documented"
        assert f'href="#{target}"' in text, f"the top-level table does not link {target}"


def _yaml_blocks(page: str) -> list[str]:
    return re.findall(r"```yaml\n(.*?)```", (DOCS / page).read_text(encoding="utf-8"), re.S)


def test_yaml_examples_load():
    """The scenario page's example is a valid scenario, and the guide page's section is a
    valid guide for it (the loader checks every rule)."""
    from stt_drake import parse_scenario

    (example,) = _yaml_blocks("guide/scenarios.md")
    scenario = parse_scenario(example)
    assert scenario.name == "example" and len(scenario.obstacles) == 1
    (guide,) = _yaml_blocks("guide/guide.md")
    assert parse_scenario(example + guide).guide.rate_hz == 10.0


@pytest.mark.slow
def test_scenario_example_runs():
    """The scenario page's example reaches its target with every guarantee held and no
    warning: what the page shows is a run a reader can copy."""
    from stt_drake import parse_scenario, simulate

    (example,) = _yaml_blocks("guide/scenarios.md")
    metrics = simulate(parse_scenario(example)).metrics
    assert metrics.reached and metrics.holds and metrics.stop_reason is None
    assert metrics.warnings == []


def test_plain_docstrings_read_as_written():
    """Bars are absolute values, an indented formula after a colon is literal, and a list
    may follow its paragraph; inline literals are left alone."""
    plain = _extension().plain_docstring
    assert plain(["|ċ| ≤ v_c and ``a|b``"]) == ["\\|ċ\\| ≤ v_c and ``a|b``"]
    assert plain(["the law:", "", "    ċ = k1 (η − c)"])[0] == "the law::"
    assert plain(["Fixes:", "* one", "* two"]) == ["Fixes:", "", "* one", "* two"]


def test_no_page_points_outside_the_repository():
    for path in [*DOCS.rglob("*.md"), DOCS / "conf.py", *(DOCS / "_ext").glob("*.py")]:
        text = path.read_text(encoding="utf-8")
        assert "/work/" not in text and "../shared" not in text and "DESIGN.md" not in text, path


def test_api_overview_names_exactly_the_exported_names():
    """The API page's overview of the top level names each name of `stt_drake.__all__`, and
    only those."""
    text = (DOCS / "api.md").read_text(encoding="utf-8")
    overview = text.split("## The top level", 1)[1].split("```{eval-rst}", 1)[0]
    named = set(re.findall(r"`([A-Za-z_]\w*)`", overview))
    assert named == set(stt_drake.__all__)
