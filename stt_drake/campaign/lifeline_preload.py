"""Imported in a local pool's forkserver only (``set_forkserver_preload``, first): makes
the forkserver die with the campaign process (:mod:`stt_drake.campaign.lifeline`).
Importing it anywhere else would tie that process's life to its parent's."""

from stt_drake.campaign.lifeline import forkserver_lifeline

forkserver_lifeline()
