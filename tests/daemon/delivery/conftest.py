"""Fixtures of the delivery tests: a real mosquitto (skipped, saying why, where it cannot run) and the in-memory broker."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import pytest

from bogiemon.daemon.delivery.memory_transport import MemoryBroker
from tests.daemon.delivery.mqtt_broker import Broker, Certs, ensure_mosquitto, make_certs


@pytest.fixture(scope="session")
def mosquitto() -> None:
    reason = ensure_mosquitto()
    if reason is not None:
        pytest.skip(reason)


@pytest.fixture(scope="session")
def certs(tmp_path_factory: pytest.TempPathFactory, mosquitto: None) -> Certs:
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed: it makes the test certificates (apt-get install openssl)")
    return make_certs(tmp_path_factory.mktemp("certs"))


@pytest.fixture
def broker(tmp_path: Path, mosquitto: None) -> Iterator[Broker]:
    b = Broker(tmp_path / "broker").start()
    yield b
    b.kill()


@pytest.fixture
def memory_broker() -> MemoryBroker:
    return MemoryBroker()
