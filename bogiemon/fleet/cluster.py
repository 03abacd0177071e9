"""Where the back office's tasks run: a Dask cluster, or this process (the tests, the fuzz target).

A Runner maps a function over tasks and gives the results as they complete; the analysis and the
judge ask nothing else of it. `dask_runner` opens the cluster the command line asks for (an
existing scheduler, or a LocalCluster of one single-threaded worker per core) and closes it
after. What the cluster does wrong (a bad address, a scheduler that does not answer, a worker that
died, a connection lost) ends as one ClusterError line; an error a task raised is the task's own
(a FleetError is a clear error, anything else a bug), and Dask's own log lines never print a
traceback on the command line.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import os
from collections.abc import Callable, Generator, Iterator, Sequence
from contextlib import contextmanager
from typing import Any, Protocol, TypeVar

from bogiemon.fleet.layout import FleetError
from bogiemon.fleet.paths import one_line, shown

T = TypeVar("T")
R = TypeVar("R")

SCHEMES = ("tcp", "tls")  # what a Dask scheduler listens on in practice
CONNECT_TIMEOUT_S = 20.0
MAX_WORKERS_PER_CORE = 4  # a LocalCluster beyond this only fights over the cores and the memory
DASK_LOGGERS = ("distributed", "tornado", "asyncio")
# Dask's defaults our LocalCluster changes, for the analysis's tasks (the fleet demo's 6 wagons x 3
# days on one worker: 30 CPU s -> 14.5 s, against 11.9 s in one process).
LOCAL_CLUSTER_CONFIG: dict[str, object] = {
    # Dask starts its workers with MALLOC_TRIM_THRESHOLD_=65536, to give memory back to the system
    # at once. Setting it turns glibc's dynamic mmap threshold off: every array over 128 KiB was
    # mapped and unmapped again (60 000 times, each page faulted in anew: 10 s of system time).
    # Unset (None), glibc keeps a day's arrays for the next day's; the workers end with the run. It
    # is also no longer set in this process's environment (the nanny sets it here before spawning).
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    # The dashboard's profiler samples every running task's stack 100 times a second: no dashboard.
    "distributed.worker.profile.enabled": False,
    # Each process's check for a blocked event loop, 50 times a second: its warnings are not shown.
    "distributed.admin.tick.interval": "1s",
}


class ClusterError(FleetError):
    """The Dask cluster could not be used or failed under the run: one line, what and where."""


class Runner(Protocol):
    """Runs fn over items somewhere, giving the results as they complete."""

    workers: int

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Generator[R, None, None]: ...


class InProcess:
    """The tasks run here, one after the other: for tests, the fuzz target and light work."""

    workers = 1

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Generator[R, None, None]:
        for item in items:
            yield fn(item)


class DaskRunner:
    """The tasks on a distributed.Client's cluster; tasks not yet started are cancelled when the
    caller stops taking results (an interrupt, an error): one already running ends and its work
    (a partition written whole) is kept."""

    def __init__(self, client: Any) -> None:
        self.client = client
        try:
            self.workers = len(client.scheduler_info().get("workers", {}))
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"the Dask scheduler does not answer: {one_line(exc)}") from None

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Generator[R, None, None]:
        from distributed import as_completed
        from distributed.scheduler import KilledWorker

        futures: list[Any] = []
        try:
            futures = self.client.map(fn, list(items), pure=False)
            for future in as_completed(futures):
                if future.status == "error" and not isinstance(future.exception(), KilledWorker):
                    future.result()  # the task's own exception, raised here with its traceback
                try:
                    result = future.result()
                except KilledWorker as exc:
                    raise ClusterError(f"a Dask worker died running a task, again on each retry ({one_line(exc)}); see the workers' logs") from None
                yield result
        except (OSError, TimeoutError) as exc:
            raise ClusterError(f"the Dask cluster failed under the run: {one_line(exc)}") from None
        except (concurrent.futures.CancelledError, asyncio.CancelledError) as exc:
            raise ClusterError(f"the Dask cluster cancelled the run's tasks ({one_line(exc) or 'cancelled'}); run it again") from None
        finally:
            if futures:
                self.client.cancel(futures)


def check_options(scheduler: str | None, n_workers: int | None) -> None:
    """ClusterError for a scheduler address or a worker count that cannot work."""
    if scheduler is not None:
        scheme, sep, rest = scheduler.partition("://")
        if not sep or scheme not in SCHEMES or not rest:
            raise ClusterError(f"--scheduler {shown(repr(scheduler), 80)}: expected a Dask scheduler's address, tcp://HOST:PORT (or tls://)")
        if n_workers is not None:
            raise ClusterError("--workers is for the local cluster; a cluster at --scheduler has its own workers")
    if n_workers is not None:
        most = MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)
        if not 1 <= n_workers <= most:
            raise ClusterError(f"--workers {n_workers}: expected 1 to {most} worker processes ({MAX_WORKERS_PER_CORE} per core of this machine)")


@contextmanager
def dask_runner(scheduler: str | None = None, n_workers: int | None = None) -> Iterator[DaskRunner]:
    """A DaskRunner on the scheduler at `scheduler`, else on a LocalCluster of n_workers (default:
    one per core) for the time of the block; ClusterError when it cannot be had."""
    check_options(scheduler, n_workers)
    one_line_dask_logs()
    client = _connect(scheduler) if scheduler else _local_client(n_workers)
    try:
        yield DaskRunner(client)
    finally:
        cluster = client.cluster
        try:
            client.close()
            if cluster is not None:
                cluster.close()
        except (OSError, TimeoutError) as exc:  # the work is done: a hiccup at the close is a note
            logging.getLogger("distributed").error("closing the cluster: %s", one_line(exc))


def _connect(scheduler: str) -> Any:
    from distributed import Client

    try:
        return Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S:g}s")
    except ValueError as exc:
        raise ClusterError(f"--scheduler {shown(repr(scheduler), 80)}: {one_line(exc)}") from None
    except (OSError, TimeoutError) as exc:
        raise ClusterError(f"cannot reach the Dask scheduler at {shown(scheduler, 80)} ({one_line(exc)}); is it running?") from None
    except Exception as exc:  # noqa: BLE001 - what answers there is no Dask scheduler (an HTTP server's reply read as a frame length: MemoryError)
        raise ClusterError(
            f"{shown(scheduler, 80)} did not answer as a Dask scheduler ({type(exc).__name__}: {one_line(exc, 160)}); is that its address?"
        ) from None


def local_client(n_workers: int | None = None) -> Any:
    """A distributed.Client on a LocalCluster of one single-threaded process per core (the
    analysis is numpy's: one thread per process keeps the cores busy without BLAS threads
    fighting over them). The caller closes the client and its cluster."""
    check_options(None, n_workers)
    return _local_client(n_workers)


def _local_client(n_workers: int | None) -> Any:
    import dask.config
    from distributed import Client, LocalCluster

    workers = n_workers or os.cpu_count() or 1
    try:
        with dask.config.set(LOCAL_CLUSTER_CONFIG):  # the nannies hand it to their workers
            cluster = LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                # The workers' own log lines (a worker's view of a failed task, a connection closed
                # at the end) are not the command's: what goes wrong comes back through the results.
                silence_logs=logging.CRITICAL,
                env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
            )  # fmt: skip
    except (OSError, TimeoutError, RuntimeError) as exc:
        raise ClusterError(f"cannot start a local Dask cluster of {workers} workers: {one_line(exc)}") from None
    return Client(cluster)


class _OneLine(logging.Formatter):
    """A log record as one line, without its traceback (Dask logs tracebacks of closed connections)."""

    def format(self, record: logging.LogRecord) -> str:
        return f"bogiemon: dask: {one_line(record.getMessage())}" + (f" ({one_line(record.exc_info[1])})" if record.exc_info and record.exc_info[1] else "")


def one_line_dask_logs() -> None:
    """From now on, Dask's log lines in this process at ERROR and above as one line each on
    stderr, none below (a LocalCluster's INFO lines are noise on a command line). For the whole
    process: Dask logs from its own threads, and at the interpreter's exit too."""
    handler = logging.StreamHandler()
    handler.setFormatter(_OneLine())
    for name in DASK_LOGGERS:
        logger = logging.getLogger(name)
        logger.handlers = [handler]
        logger.setLevel(logging.ERROR)
        logger.propagate = False
