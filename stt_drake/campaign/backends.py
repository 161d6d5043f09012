"""Where a campaign's runs execute, and :func:`execute`, which feeds them batches.

* :class:`LocalPool`: a :class:`concurrent.futures.ProcessPoolExecutor` of local
  processes, started with the "forkserver" method. A worker process that dies (killed,
  out of memory, a crash in native code) breaks the whole pool: :func:`execute` raises
  :class:`~concurrent.futures.process.BrokenProcessPool` after handing over every batch
  that finished, and the caller may :meth:`LocalPool.restart` it and redo the rest. The
  forkserver and the workers die with the process that made the pool, also when it is
  SIGKILLed (:mod:`stt_drake.campaign.lifeline`).
* :class:`DaskCluster`: the executor of a Dask ``distributed`` client. The scheduler is
  reached and a worker awaited when it is made (before the campaign does any work), each
  within a timeout; while runs are out, a scheduler that is lost, or no worker for the
  same timeout, stops the campaign with :class:`~stt_drake.campaign.spec.CampaignStoppedError`
  instead of a hang or a traceback.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import logging
import multiprocessing
import os
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from stt_drake.campaign.lifeline import PRELOAD_MODULE, mark_pool_parent, worker_lifeline
from stt_drake.campaign.spec import CampaignError, CampaignStoppedError

#: How long :func:`execute` waits for a batch before it looks at the cluster's health (s).
POLL_S = 1.0
#: Default of ``--dask-timeout``: the wait for the scheduler, for a first worker, and the
#: longest time without any worker while runs are out (s).
DASK_TIMEOUT_S = 60.0
#: Address schemes a Dask client can use (``host:port`` alone means tcp).
DASK_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")
#: The module a local pool's forkserver imports last when given `kernels`, and the
#: environment variable through which it learns their output dimension.
KERNELS_PRELOAD_MODULE = "stt_drake.campaign.kernels_preload"
KERNELS_DIMENSION_ENV = "STT_DRAKE_POOL_KERNELS"
#: ``--workers`` may ask for at most this many processes per core this process may use
#: (each local worker imports pydrake, ~0.3-0.8 GB; more than the cores only waits).
MAX_WORKERS_PER_CORE = 4


def default_workers() -> int:
    """Cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        return os.cpu_count() or 1


def check_workers(workers: int | None) -> None:
    """Refuse `workers` below 1 or above :data:`MAX_WORKERS_PER_CORE` × the cores.

    Raises:
        CampaignError: naming ``workers`` and the bound.
    """
    if workers is None:
        return
    most = MAX_WORKERS_PER_CORE * default_workers()
    if not 1 <= workers <= most:
        raise CampaignError(
            f"`workers`: must be in [1, {most}] ({MAX_WORKERS_PER_CORE} per core of the "
            f"{default_workers()} this process may use) (got {workers})"
        )


def check_scheduler_address(address: str) -> None:
    """Refuse an address whose scheme no Dask client speaks, before connecting.

    Raises:
        CampaignError: naming ``scheduler``, the scheme and the known ones.
    """
    scheme = address.split("://", 1)[0] if "://" in address else "tcp"
    if scheme not in DASK_SCHEMES:
        raise CampaignError(
            f"`scheduler`: unknown scheme {scheme!r} in {address!r} (known: "
            f"{', '.join(DASK_SCHEMES)}; e.g. tcp://host:8786)"
        )


class LocalPool:
    """`workers` local processes (default: every core), replaceable after one died.

    The pool uses the "forkserver" start method with `preload` imported once in the
    server: workers fork from a clean process that has imported pydrake but never run a
    simulation or started a thread (plain "fork" from the campaign process would copy a
    process that has simulated; "spawn" re-imports pydrake in every worker, ~2-3 s each).
    With `kernels` (an output dimension) the server also loads that dimension's compiled
    kernels (:mod:`stt_drake.campaign.kernels_preload`), once for every worker and pool (a
    forkserver is started once per process: a later pool's `preload` and `kernels` are moot).
    The server first imports :data:`~stt_drake.campaign.lifeline.PRELOAD_MODULE` and each
    worker runs :func:`~stt_drake.campaign.lifeline.worker_lifeline`, so they die with
    this process however it ends.
    """

    restartable = True

    def __init__(
        self, workers: int | None = None, preload: Sequence[str] = (), kernels: int | None = None
    ) -> None:
        self.slots = default_workers() if workers is None else workers
        self._context = multiprocessing.get_context("forkserver")
        mark_pool_parent()
        if kernels is not None:
            os.environ[KERNELS_DIMENSION_ENV] = str(kernels)
            preload = [*preload, KERNELS_PRELOAD_MODULE]
        self._context.set_forkserver_preload([PRELOAD_MODULE, *preload])
        self.executor: cf.Executor = self._new()

    def _new(self) -> cf.ProcessPoolExecutor:
        return cf.ProcessPoolExecutor(
            max_workers=self.slots, mp_context=self._context, initializer=worker_lifeline
        )

    def restart(self) -> None:
        """Replace a broken pool by a fresh one (the forkserver stays)."""
        self.executor.shutdown(wait=True, cancel_futures=True)
        self.executor = self._new()

    def watch(self) -> None:
        """Nothing to watch: a worker that dies breaks the pool's futures."""

    def lost(self, error: BaseException) -> str:
        """Why a future was cancelled (only a shutdown cancels a local future)."""
        return f"the local process pool cancelled a batch ({type(error).__name__})"

    def close(self) -> None:
        """Shut the pool down (queued batches cancelled, running ones finished)."""
        self.executor.shutdown(wait=True, cancel_futures=True)


class DaskCluster:
    """The executor of a Dask client of the scheduler at `address`, checked usable first.

    Raises:
        CampaignError: the address is malformed or has an unknown scheme, or no scheduler
            answers there within `timeout` seconds.
        CampaignStoppedError: no worker joined within `timeout` seconds.
    """

    restartable = False

    def __init__(self, address: str, timeout: float = DASK_TIMEOUT_S) -> None:
        check_scheduler_address(address)
        try:  # imported here: only --scheduler needs Dask (the `cluster` extra)
            from distributed import Client
        except ImportError as error:
            raise CampaignError(
                f"`scheduler` needs Dask, which is not installed ({error}); install the "
                "cluster extra: pip install 'stt-drake[cluster]' (or run without `scheduler` "
                "on local processes)"
            ) from None

        self.address, self.timeout = address, timeout
        try:
            self.client = Client(address, timeout=f"{timeout}s")
        except (OSError, TimeoutError) as error:
            raise CampaignError(
                f"`scheduler`: no Dask scheduler answered at {address} within {timeout:g} s "
                f"(`dask_timeout`): {error}"
            ) from None
        except (ValueError, TypeError) as error:  # a malformed address, a TLS setup missing
            raise CampaignError(f"`scheduler`: {address!r}: {error}") from None
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except (OSError, TimeoutError):
            self.client.close()
            raise CampaignStoppedError(
                f"no Dask worker joined the scheduler {address} within {timeout:g} s "
                f"(`dask_timeout`); start one with: dask worker {address} --nthreads 1"
            ) from None
        self.slots = max(self._threads(), 1)
        self.executor: cf.Executor = self.client.get_executor(pure=False)
        self._checked = time.monotonic()
        self._no_worker_since: float | None = None

    def _threads(self) -> int:
        workers = self.client.scheduler_info()["workers"].values()
        return sum(w["nthreads"] for w in workers if w.get("status", "running") == "running")

    def restart(self) -> None:  # pragma: no cover - Dask reschedules a lost worker's tasks
        raise NotImplementedError("a Dask cluster is not restarted by the campaign")

    def watch(self) -> None:
        """Stop when the scheduler is gone, or when no worker has been there for the
        timeout (a lost worker's tasks wait for another one; without any, for ever)."""
        if self.client.status != "running":
            raise CampaignStoppedError(self.lost(None))
        now = time.monotonic()
        if now - self._checked < POLL_S:
            return
        self._checked = now
        if self._threads() > 0:
            self._no_worker_since = None
            return
        if self._no_worker_since is None:
            self._no_worker_since = now
        elif now - self._no_worker_since > self.timeout:
            raise CampaignStoppedError(
                f"no Dask worker at {self.address} for {self.timeout:g} s (`dask_timeout`): "
                "the last one left and none joined"
            )

    def lost(self, error: BaseException | None) -> str:
        """Why the runs out stopped: the connection to the scheduler was lost."""
        return f"lost the Dask scheduler {self.address} (client {self.client.status})"

    def close(self) -> None:
        """Close the client (quickly when the scheduler is gone: then its reconnection
        attempt, cancelled by the close, is not logged with a traceback — the campaign
        has said what happened)."""
        logger = logging.getLogger("distributed.client")
        level = logger.level
        if self.client.status != "running":
            logger.setLevel(logging.CRITICAL)
        try:
            with contextlib.suppress(OSError, TimeoutError, RuntimeError):  # already gone
                self.client.close(timeout=min(self.timeout, 10.0))
        finally:
            logger.setLevel(level)


Backend = LocalPool | DaskCluster


def open_backend(
    workers: int | None = None,
    scheduler: str | None = None,
    preload: Sequence[str] = (),
    dask_timeout: float = DASK_TIMEOUT_S,
    kernels: int | None = None,
) -> Backend:
    """A Dask cluster when `scheduler` is given, else a local pool of `workers` (`preload`
    and `kernels` as :class:`LocalPool`'s); close it with its ``close()``."""
    if scheduler is not None:
        return DaskCluster(scheduler, dask_timeout)
    return LocalPool(workers, preload, kernels)


def execute(
    backend: Backend,
    task: Callable[..., list[dict[str, Any]]],
    task_args: tuple[Any, ...],
    batches: Iterable[list[tuple[int, int]]],
    on_records: Callable[[list[dict[str, Any]]], None],
) -> None:
    """Submit ``task(*task_args, batch)`` per batch, at most 2·slots in flight, and hand
    each finished batch's records to `on_records` (in completion order).

    Raises:
        BrokenProcessPool: a local worker process died (every batch that finished before
            has been handed over; the others were not).
        CampaignStoppedError: the Dask scheduler was lost, no Dask worker for the timeout, or
            a batch raised (its message names the exception).
    """
    batches = iter(batches)
    in_flight: set[cf.Future] = set()
    try:
        while True:
            while len(in_flight) < 2 * backend.slots:
                batch = next(batches, None)
                if batch is None:
                    break
                in_flight.add(backend.executor.submit(task, *task_args, batch))
            if not in_flight:
                return
            done, in_flight = cf.wait(in_flight, timeout=POLL_S, return_when=cf.FIRST_COMPLETED)
            broken: BrokenProcessPool | None = None
            for future in done:
                try:
                    records = future.result()
                except BrokenProcessPool as error:
                    broken = error
                    continue
                except cf.CancelledError as error:
                    raise CampaignStoppedError(backend.lost(error)) from None
                except Exception as error:
                    raise CampaignStoppedError(
                        f"a batch of runs raised {type(error).__name__}: {error}"
                    ) from error
                on_records(records)
            if broken is not None:
                raise broken
            backend.watch()
    finally:
        for future in in_flight:
            future.cancel()
