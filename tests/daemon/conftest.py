"""Fixtures of the daemon tests."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.daemon.synthetic import short_windows_config


@pytest.fixture
def short_config(tmp_path: Path) -> Path:
    """The daemon tests' short-window config (tests/daemon/synthetic.py) as a file, its state in tmp_path."""
    path = tmp_path / "bogiemon.toml"
    path.write_text(short_windows_config(state_dir=tmp_path / "state"), encoding="utf-8")
    return path
