"""Scenario files: schema, loading, validation, random fields."""

from stt_drake.config.scenario import *  # noqa: F403 (temporary during the restructure)
