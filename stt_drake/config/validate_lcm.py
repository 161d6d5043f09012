"""The rules of the scenario's `lcm:` section (:class:`stt_drake.config.lcm.LcmConfig`); each
broken rule raises :class:`stt_drake.config.schema.ScenarioError` naming
``scenario.lcm.<field>``."""

import math

from stt_drake.config.lcm import (
    CHANNEL_PATTERN,
    LCM_SCHEMES,
    MAX_CONTROL_RATE_HZ,
    MAX_STALE_TIMEOUT,
    LcmConfig,
)
from stt_drake.config.limits import require


def validate_lcm(config: LcmConfig) -> None:
    """Check the `lcm:` section: a known URL scheme, channel names of
    :data:`CHANNEL_PATTERN`, a rate in (0, :data:`MAX_CONTROL_RATE_HZ`] Hz and a stale
    timeout longer than one control period and at most :data:`MAX_STALE_TIMEOUT` s.

    Raises:
        ScenarioError: naming ``scenario.lcm.<field>``, the rule and the value.
    """
    path = "scenario.lcm"
    require(
        config.lcm_url == "" or config.lcm_url.startswith(LCM_SCHEMES),
        f"{path}.lcm_url",
        f"must be empty (LCM's default) or start with {' or '.join(LCM_SCHEMES)}",
        config.lcm_url,
    )
    require(
        config.channel_suffix == "" or CHANNEL_PATTERN.fullmatch(config.channel_suffix),
        f"{path}.channel_suffix",
        "may hold only letters, digits and _ - . /",
        config.channel_suffix,
    )
    for name in ("status_channel", "command_channel", "detections_channel"):
        value = getattr(config, name)
        allowed = name != "detections_channel" and value == ""
        require(
            allowed or CHANNEL_PATTERN.fullmatch(value) is not None,
            f"{path}.{name}",
            "must be a channel name of letters, digits and _ - . /",
            value,
        )
    rate = config.control_rate_hz
    require(
        math.isfinite(rate) and 0.0 < rate <= MAX_CONTROL_RATE_HZ,
        f"{path}.control_rate_hz",
        f"must lie in (0, {MAX_CONTROL_RATE_HZ:g}] Hz",
        rate,
    )
    timeout = config.stale_timeout
    require(
        math.isfinite(timeout) and config.period < timeout <= MAX_STALE_TIMEOUT,
        f"{path}.stale_timeout",
        f"must be longer than one control period ({config.period:g} s) and at most "
        f"{MAX_STALE_TIMEOUT:g} s",
        timeout,
    )
