"""Scenario → Drake: the core objects built once (laws), the checks that need them, the
complete scenario loader, the STT composite (AddStt) and the whole diagram."""

from stt_drake.assembly.load import load_scenario, parse_scenario, prepare_scenario

__all__ = ["load_scenario", "parse_scenario", "prepare_scenario"]
