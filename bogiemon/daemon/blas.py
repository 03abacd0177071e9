"""The BLAS thread pool of the daemon's process: kept to one thread while the service runs.

numpy's OpenBLAS hands a matrix product above a size threshold (m n k of about 2^18) to a pool
of worker threads, which then spin for tens of milliseconds waiting for more work before they
sleep. The service's products are small and arrive every few seconds, from a processing thread
of its own: threads buy nothing there, and each spin after a product crossing the threshold
costs a core for up to about 0.1 s. One such product per 10 s hop cost the live daemon 15 to 40
CPU seconds per hour (README, Performance): more than the whole processing thread.

threadpoolctl finds the BLAS libraries loaded in the process (OpenBLAS, and MKL, BLIS or
FlexiBLAS where numpy was built with one) and asks each through its own API, so nothing needs to
be set before numpy is imported. A process without such a library has nothing to limit.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from threadpoolctl import ThreadpoolController


def blas_thread_counts() -> dict[str, int]:
    """The thread count of each BLAS library loaded in this process, by its file's name."""
    return {Path(info["filepath"]).name: int(info["num_threads"]) for info in ThreadpoolController().select(user_api="blas").info()}


@dataclass(frozen=True)
class BlasLimit:
    """What limit_blas_threads changed: the libraries, and how to give each its count back."""

    libraries: list[str]
    restore: Callable[[], None]


def limit_blas_threads(n_threads: int = 1) -> BlasLimit:
    """Limit every loaded BLAS library to n_threads; the result restores what each had."""
    controller = ThreadpoolController().select(user_api="blas")
    libraries = [Path(info["filepath"]).name for info in controller.info()]
    limiter = controller.limit(limits=n_threads)
    return BlasLimit(libraries, limiter.restore_original_limits)
