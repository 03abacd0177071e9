"""The service's BLAS thread limit (daemon/blas.py, through threadpoolctl): set, and restored."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from bogiemon.daemon.blas import blas_thread_counts, limit_blas_threads


def test_limit_blas_threads_sets_one_thread_and_restore_gives_back_the_previous_count() -> None:
    np.ones((2, 2)) @ np.ones((2, 2))  # numpy's BLAS is loaded
    with threadpool_limits(limits=2, user_api="blas"):  # the tests' workers may run with one thread
        before = blas_thread_counts()
        assert before and all(n == 2 for n in before.values())
        limit = limit_blas_threads(1)
        try:
            assert blas_thread_counts() == dict.fromkeys(before, 1)
            assert sorted(limit.libraries) == sorted(before)
        finally:
            limit.restore()
        assert blas_thread_counts() == before


def test_numpys_own_blas_is_among_the_libraries_found() -> None:
    config = np.show_config(mode="dicts")
    name = config["Build Dependencies"]["blas"]["name"]
    if "openblas" not in name:
        pytest.skip(f"numpy is built with {name}, not OpenBLAS")
    assert any("openblas" in library for library in blas_thread_counts())
