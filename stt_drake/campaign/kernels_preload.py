"""Imported in a local pool's forkserver only (``set_forkserver_preload``, after the
modules the runs need): loads the compiled kernels of the output dimension the campaign
process put in :data:`~stt_drake.campaign.backends.KERNELS_DIMENSION_ENV`
(:func:`stt_drake.core.backend.warm_up`) once there, so every worker forked from it starts
with them loaded instead of loading them itself (~0.7 s per worker and pool)."""

import contextlib
import os

from stt_drake.campaign.backends import KERNELS_DIMENSION_ENV
from stt_drake.core import backend

# An exception here would kill the forkserver; a worker's run warms up again and reports it.
with contextlib.suppress(Exception):
    backend.warm_up(int(os.environ[KERNELS_DIMENSION_ENV]))
