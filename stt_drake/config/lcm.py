"""The scenario's `lcm:` section (:class:`LcmConfig`): how `stt-drake station` and
`stt-drake controller` talk (:mod:`stt_drake.robot`).

The field names follow Drake's ``DrakeLcmParams`` (`lcm_url`, `channel_suffix`) and its
``LcmBuses`` channel names. A scenario without the section uses the defaults: LCM's default
URL (UDP multicast, or ``LCM_DEFAULT_URL``), our channels for the omni robot and the
quadrotor and the FR3 driver's (``PANDA_STATUS``/``PANDA_COMMAND``) for the arm, 100 Hz and
a stale timeout of 0.1 s. :func:`stt_drake.config.validate_lcm.validate_lcm` checks the section.
"""

# No `from __future__ import annotations`: Drake's yaml_load_typed reads the field types.
import re
from dataclasses import dataclass

#: URL schemes a bus may use: in-process (tests) and UDP multicast (two processes).
LCM_SCHEMES = ("memq://", "udpm://")

#: A channel name: letters, digits and ``_ - . /`` (LCM allows more; these survive shells
#: and logs).
CHANNEL_PATTERN = re.compile(r"[A-Za-z0-9_.\-/]+")

#: Fastest control rate (Hz).
MAX_CONTROL_RATE_HZ = 10_000.0

#: Longest stale timeout (s).
MAX_STALE_TIMEOUT = 60.0


@dataclass
class LcmConfig:
    """The LCM bus between the station and the controller.

    Attributes:
        lcm_url: the bus URL (``DrakeLcmParams.lcm_url``): ``memq://`` in one process,
            ``udpm://239.255.76.67:7667?ttl=0`` between processes; "" is LCM's default.
        channel_suffix: appended to every channel name (``DrakeLcmParams.channel_suffix``),
            so two loops can share one bus.
        status_channel: the robot's state, station → controller; "" is the plant's default
            (``STT_STATUS``; ``PANDA_STATUS`` for the FR3).
        command_channel: the command, controller → station; "" is the plant's default
            (``STT_COMMAND``; ``PANDA_COMMAND`` for the FR3).
        detections_channel: obstacle detections, station → controller (scenarios with
            `perception`).
        control_rate_hz: how often the station publishes its status and the controller its
            command (Hz).
        stale_timeout: how long the controller runs without a new status before it commands
            the safe action (zero velocity, zero force, the arm's zero torque) and stops (s).
    """

    lcm_url: str = ""
    channel_suffix: str = ""
    status_channel: str = ""
    command_channel: str = ""
    detections_channel: str = "STT_DETECTIONS"
    control_rate_hz: float = 100.0
    stale_timeout: float = 0.1

    @property
    def period(self) -> float:
        """The control period 1/`control_rate_hz` (s)."""
        return 1.0 / self.control_rate_hz
