"""Worker processes that die with the campaign that started them (Linux).

A campaign's local pool (:class:`stt_drake.campaign.backends.LocalPool`) is a forkserver
(a child of the campaign process) and worker processes forked by it (children of the
forkserver). When the campaign process is killed (SIGKILL: no clean-up runs) nothing
would stop them: each worker holds the pipes that would tell the forkserver and the
other workers that their parent is gone, so they sat there, reparented, holding their
memory. Here each of them asks the kernel to SIGKILL it when its own parent dies
(``prctl(PR_SET_PDEATHSIG, SIGKILL)``): the forkserver when the campaign process dies
(:data:`PRELOAD_MODULE`, imported in the forkserver before anything else), a worker when
the forkserver dies (:func:`worker_lifeline`, the pool's ``initializer``), so killing
the campaign takes its whole tree down at once.

A parent that died before the request was made is caught by comparing ``os.getppid()``
with the parent's pid recorded in the environment (:data:`MAIN_PID_ENV` by the campaign
process before it starts the forkserver, :data:`FORKSERVER_PID_ENV` by the forkserver
for its workers). Elsewhere than on Linux this is a no-op.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys

#: The module a pool's forkserver imports first (``set_forkserver_preload``): importing
#: it there makes the forkserver die with the campaign process. Never import it elsewhere.
PRELOAD_MODULE = "stt_drake.campaign.lifeline_preload"
#: Environment variables holding the pid a process expects as its parent.
MAIN_PID_ENV, FORKSERVER_PID_ENV = "STT_DRAKE_POOL_PARENT", "STT_DRAKE_FORKSERVER"
#: From <linux/prctl.h>.
PR_SET_PDEATHSIG = 1


def die_with_parent(expected_parent: int | None = None) -> bool:
    """Ask the kernel to SIGKILL this process when its parent dies; if the parent is not
    `expected_parent` any more (it died before the request), die now. Returns whether the
    request was made (False off Linux, or when prctl is not available)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        made = libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):  # pragma: no cover - no libc prctl
        return False
    if made and expected_parent is not None and os.getppid() != expected_parent:
        os.kill(os.getpid(), signal.SIGKILL)  # orphaned already: the parent is gone
    return made


def _pid_from(variable: str) -> int | None:
    try:
        return int(os.environ[variable])
    except (KeyError, ValueError):
        return None


def mark_pool_parent() -> None:
    """Record this process's pid as the parent a forkserver it starts must watch (call
    before the pool's first process starts)."""
    os.environ[MAIN_PID_ENV] = str(os.getpid())


def forkserver_lifeline() -> None:
    """In the forkserver: die with the campaign process, and tell the workers (through
    the environment they inherit) which pid their parent is."""
    die_with_parent(_pid_from(MAIN_PID_ENV))
    os.environ[FORKSERVER_PID_ENV] = str(os.getpid())


def worker_lifeline() -> None:
    """A pool's ``initializer``: the worker dies with the forkserver that forked it."""
    die_with_parent(_pid_from(FORKSERVER_PID_ENV))
