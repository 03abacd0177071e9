"""The real loggers' files the readers are tested on: ../shared/data/canedge-mf4/ beside the
repository (BOGIEMON_SHARED names another shared folder), MIT-licensed CANedge MF4 files."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SHARED = Path(os.environ.get("BOGIEMON_SHARED", REPO.parent / "shared"))
CANEDGE_MF4 = SHARED / "data" / "canedge-mf4"


@pytest.fixture(scope="session")
def shared_mf4() -> Path:
    """The folder of real CANedge MF4 files; the test is skipped, saying where they were looked for, without it."""
    if not CANEDGE_MF4.is_dir():
        pytest.skip(f"the real CANedge MF4 fixtures are not at {CANEDGE_MF4} (the shared folder beside the repository; BOGIEMON_SHARED names another)")
    return CANEDGE_MF4
