"""Fixtures of the back office's tests."""

from __future__ import annotations

import pytest

from tests.fleet import tree


@pytest.fixture(scope="session")
def runs(tmp_path_factory: pytest.TempPathFactory) -> tree.Runs:
    """Three simulated 5-min runs (two healthy, one where the spring breaks), simulated once."""
    return tree.simulate_runs(tmp_path_factory.mktemp("runs"))
