"""Library errors name their parameters; the command maps them to its flags
(:data:`stt_drake.cli.main.PARAMETER_FLAGS`)."""

from __future__ import annotations

from pathlib import Path

import pytest

from stt_drake.campaign import CampaignError, CampaignSpec, run_campaign
from stt_drake.campaign.backends import check_workers
from stt_drake.campaign.kinds import validate_spec
from stt_drake.cli.main import PARAMETER_FLAGS, flag_message, main

ROOT = Path(__file__).resolve().parents[2]
CASE1 = str(ROOT / "diagrams" / "omni_hardware_case1.yaml")


@pytest.mark.parametrize(
    ("spec", "parameter"),
    [
        (CampaignSpec(CASE1, runs=0), "runs"),
        (CampaignSpec(CASE1, kind="nothing"), "kind"),
        (CampaignSpec(CASE1, seed=-1), "seed"),
        (CampaignSpec(CASE1, tau=-1.0), "tau"),
        (CampaignSpec(CASE1, kind="randomisation", motion="ou"), "motion"),
        (CampaignSpec(CASE1, comfort_distance=-1.0), "comfort_distance"),
    ],
)
def test_a_bad_spec_names_the_parameter_not_the_flag(spec, parameter):
    with pytest.raises(CampaignError) as caught:
        validate_spec(spec)
    message = str(caught.value)
    assert message.startswith(f"`{parameter}`:") and "--" not in message


def test_run_campaign_and_the_backend_name_their_parameters(tmp_path):
    with pytest.raises(CampaignError, match=r"^`chunk_size`: must be ≥ 1"):
        run_campaign(CampaignSpec(CASE1, runs=1), tmp_path, chunk_size=0)
    with pytest.raises(CampaignError, match=r"^`dask_timeout`: "):
        run_campaign(CampaignSpec(CASE1, runs=1), tmp_path, dask_timeout=0.0)
    with pytest.raises(CampaignError, match=r"^`workers`: must be in"):
        check_workers(0)


def test_the_command_says_the_flags():
    message = "`motion`: applies only to `kind` true-obstacles; pass `resume`, not `guide`"
    assert flag_message(message) == (
        "--true-obstacle-motion: applies only to --kind true-obstacles; pass --resume, "
        "not `guide`"
    )
    assert all(flag.startswith("--") or flag.isupper() for flag in PARAMETER_FLAGS.values())


def test_the_campaign_command_prints_flags(capsys):
    assert main(["campaign", CASE1, "--runs", "1", "--chunk-size", "0", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert "stt-drake campaign: --chunk-size: must be ≥ 1 (got 0)" in error
    assert "`" not in error
    assert main(["campaign", CASE1, "--runs", "1", "--kind", "randomisation", "--ou-tau", "3"]) == 2
    error = capsys.readouterr().err
    assert "--ou-tau: applies only to --kind true-obstacles" in error and "`" not in error
