"""The BLAS thread pool of the daemon's process: kept to one thread while the service runs.

numpy's OpenBLAS hands a matrix product above a size threshold (m n k of about 2^18) to a pool
of worker threads, which then spin for tens of milliseconds waiting for more work before they
sleep. The service's products are small and arrive every few seconds, from a processing thread
of its own: threads buy nothing there, and each spin after a product crossing the threshold
costs a core for up to about 0.1 s. One such product per 10 s hop cost the live daemon 15 to 40
CPU seconds per hour (README, Performance): more than the whole processing thread.

Linux only, like the gateway: the loaded OpenBLAS libraries are found in /proc/self/maps and
asked through their own API (the same calls threadpoolctl makes), so nothing needs to be set
before numpy is imported. A process without OpenBLAS (a reference BLAS) has nothing to limit.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

# The setter's and getter's names: OpenBLAS's own, and those of the copy numpy and scipy wheels
# bundle (scipy-openblas, 64-bit integers, symbols prefixed and suffixed).
_PREFIXES = ("openblas_", "scipy_openblas_")
_SUFFIXES = ("", "64_", "_64_")


@dataclass(frozen=True)
class BlasLibrary:
    path: str
    set_num_threads: Callable[[int], None]
    get_num_threads: Callable[[], int]


def _loaded_paths(maps: str) -> list[str]:
    """The OpenBLAS shared objects mapped into this process, from the text of /proc/self/maps."""
    paths: list[str] = []
    for line in maps.splitlines():
        fields = line.split(maxsplit=5)  # address, perms, offset, device, inode[, path]
        path = fields[5].strip() if len(fields) == 6 else ""
        name = Path(path).name.lower()
        if "openblas" in name and ".so" in name and path not in paths:
            paths.append(path)
    return paths


def _bind(path: str) -> BlasLibrary | None:
    try:
        lib = ctypes.CDLL(path)  # already loaded: the same handle, no second copy
    except OSError:
        return None
    for prefix in _PREFIXES:
        for suffix in _SUFFIXES:
            setter = getattr(lib, f"{prefix}set_num_threads{suffix}", None)
            getter = getattr(lib, f"{prefix}get_num_threads{suffix}", None)
            if setter is not None and getter is not None:
                setter.argtypes, setter.restype = [ctypes.c_int], None
                getter.argtypes, getter.restype = [], ctypes.c_int
                return BlasLibrary(path, setter, getter)
    return None


def loaded_blas_libraries() -> list[BlasLibrary]:
    """The OpenBLAS libraries loaded in this process that can be told a thread count."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:  # not Linux: nothing found, nothing limited
        return []
    found = (_bind(path) for path in _loaded_paths(maps))
    return [lib for lib in found if lib is not None]


@dataclass(frozen=True)
class BlasLimit:
    """What limit_blas_threads changed: each library with the thread count it had before."""

    before: tuple[tuple[BlasLibrary, int], ...]

    @property
    def libraries(self) -> list[str]:
        return [Path(lib.path).name for lib, _ in self.before]

    def restore(self) -> None:
        for lib, n in self.before:
            lib.set_num_threads(n)


def limit_blas_threads(n_threads: int = 1) -> BlasLimit:
    """Limit every loaded OpenBLAS to n_threads; the result restores what each had."""
    before = tuple((lib, lib.get_num_threads()) for lib in loaded_blas_libraries())
    for lib, _ in before:
        lib.set_num_threads(n_threads)
    return BlasLimit(before)
