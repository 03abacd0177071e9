"""The service's BLAS thread limit (daemon/blas.py): found in /proc/self/maps, set, and restored."""

from __future__ import annotations

import numpy as np
import pytest

from bogiemon.daemon.blas import _loaded_paths, limit_blas_threads, loaded_blas_libraries

MAPS = """\
7f00a000-7f00b000 r-xp 00000000 fd:00 123 /venv/lib/numpy.libs/libscipy_openblas64_-32a4b2a6.so
7f00b000-7f00c000 r--p 00001000 fd:00 123 /venv/lib/numpy.libs/libscipy_openblas64_-32a4b2a6.so
7f00c000-7f00d000 r-xp 00000000 fd:00 124 /usr/lib/x86_64-linux-gnu/libopenblas.so.0
7f00d000-7f00e000 r-xp 00000000 fd:00 125 /usr/lib/x86_64-linux-gnu/libm.so.6
7f00e000-7f00f000 rw-p 00000000 00:00 0
7f00f000-7f010000 rw-p 00000000 00:00 0 [heap]
"""


def test_loaded_paths_lists_each_openblas_object_once_and_nothing_else() -> None:
    assert _loaded_paths(MAPS) == [
        "/venv/lib/numpy.libs/libscipy_openblas64_-32a4b2a6.so",
        "/usr/lib/x86_64-linux-gnu/libopenblas.so.0",
    ]


def test_limit_blas_threads_sets_one_thread_and_restore_gives_back_the_previous_count() -> None:
    np.ones((2, 2)) @ np.ones((2, 2))  # numpy's BLAS is loaded
    libraries = loaded_blas_libraries()
    if not libraries:
        pytest.skip("this numpy uses no OpenBLAS: nothing to limit")
    before = [lib.get_num_threads() for lib in libraries]
    limit = limit_blas_threads(1)
    try:
        assert [lib.get_num_threads() for lib in libraries] == [1] * len(libraries)
        assert limit.libraries == [lib.path.rsplit("/", 1)[-1] for lib in libraries]
    finally:
        limit.restore()
    assert [lib.get_num_threads() for lib in libraries] == before
