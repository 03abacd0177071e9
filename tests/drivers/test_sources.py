"""open_source: the [source] section builds the right driver with its settings."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import BaseModel

from bogiemon.daemon.config import ConfigError, parse_config
from bogiemon.daemon.sources import OPENERS, open_source
from bogiemon.drivers.can_source import CanBusPort, CanSource
from bogiemon.drivers.candb import DbcError
from bogiemon.drivers.recording import RecordingError, write_csv_recording
from bogiemon.drivers.replay import CsvReplaySource
from bogiemon.drivers.replay_can import CanLogReplaySource
from bogiemon.drivers.serial_source import SerialSource
from tests.drivers.frames import write_recording


def test_the_default_source_is_socketcan_on_can0_with_the_shipped_hub_layout() -> None:
    config = parse_config("", "t")
    source = open_source(config)
    try:
        assert isinstance(source, CanSource) and isinstance(source.port, CanBusPort)
        assert (source.port.kind, source.port.channel, source.port.receive_buffer_bytes) == ("socketcan", "can0", 1048576)
        assert source.layout.name == "hub" and source.layout.source == "shipped bogiemon.dbc"
        assert source.fs_hz == 500.0 and source.max_block_n == 500
        if not source.connected:  # as here: no can0 (nor SocketCAN); the source retries, never raises
            assert source.last_error.startswith("SocketCAN interface 'can0': cannot open")
    finally:
        source.close()


def test_a_virtual_per_node_can_source_from_the_config() -> None:
    config = parse_config('[source]\ninterface = "virtual"\nchannel = "cfg-test"\nlayout = "per-node"\nmax_block_s = 0.2\n', "t")
    with open_source(config) as source:
        assert isinstance(source, CanSource)
        assert isinstance(source.port, CanBusPort) and (source.port.kind, source.port.channel) == ("virtual", "cfg-test")
        assert source.connected
        assert source.layout.name == "per-node" and source.max_block_n == 100


def test_a_serial_source_from_the_config(tmp_path: Path) -> None:
    config = parse_config(f'[source]\nkind = "serial"\nport = "{tmp_path}/ttyX"\nbaudrate = 230400\n', "t")
    with open_source(config) as source:
        assert isinstance(source, SerialSource) and (source.port, source.baudrate) == (f"{tmp_path}/ttyX", 230400)


def test_replay_sources_from_the_config(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 10)
    csv = open_source(parse_config(f'[source]\nkind = "replay"\npath = "{tmp_path}/run.csv"\nrealtime = false\n', "t"))
    assert isinstance(csv, CsvReplaySource) and csv.rate == 0
    (tmp_path / "run.log").write_text("(0.0) vcan0 100#0000000000000000\n")
    log = open_source(parse_config(f'[source]\nkind = "replay"\npath = "{tmp_path}/run.log"\n', "t"))
    assert isinstance(log, CanLogReplaySource) and log.rate == 1.0
    log.close()


@pytest.mark.parametrize(
    "text",
    ["", '[source]\nkind = "serial"\n', '[source]\nkind = "replay"\npath = "x.csv"\n', '[source]\nkind = "simulated"\n'],
)
def test_every_source_kind_the_config_accepts_has_an_opener(text: str) -> None:
    assert type(parse_config(text, "t").source) in OPENERS


def test_a_source_model_without_an_opener_is_an_internal_error_naming_it() -> None:
    class UsbSourceConfig(BaseModel):
        kind: str = "usb"

    config = parse_config("", "t").model_copy(update={"source": UsbSourceConfig()})
    with pytest.raises(TypeError, match=r"^\[source\] kind 'usb' \(UsbSourceConfig\) has no opener in daemon/sources.py OPENERS$"):
        open_source(config)


def test_opening_a_can_source_never_imports_the_simulator() -> None:
    code = (
        "import sys\n"
        "from bogiemon.daemon.config import parse_config\n"
        "from bogiemon.daemon.sources import open_source\n"
        "open_source(parse_config('[source]\\ninterface = \"virtual\"\\n', 't')).close()\n"
        "print(sorted(m for m in sys.modules if m.startswith(('bogiemon.simulator', 'bogiemon.daemon.simsource'))))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout == "[]\n"


def test_a_bad_dbc_in_the_config_is_a_user_error(tmp_path: Path) -> None:
    with pytest.raises(DbcError, match="nope.dbc: cannot read the DBC file"):
        open_source(parse_config(f'[source]\ninterface = "virtual"\ndbc_path = "{tmp_path}/nope.dbc"\n', "t"))


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ('[source]\nkind = "usb"\n', "source: kind must be 'can', 'serial', 'replay' or 'simulated'"),
        ('[source]\nchanel = "vcan0"\n', "source.chanel: unknown field (did you mean 'channel'?)"),
        ('[source]\nkind = "serial"\nbaud = 9600\n', "source.baud: unknown field (did you mean 'baudrate'?)"),
        ('[source]\nkind = "replay"\n', "source.path: Field required"),
        ('[source]\ninterface = "pcan"\n', "source.interface: Input should be 'socketcan' or 'virtual'"),
        ("[source]\nreconnect_backoff_min_s = 60\n", "source: reconnect_backoff_min_s (60.0) must not exceed reconnect_backoff_max_s (30.0)"),
    ],
)  # fmt: skip
def test_a_bad_source_field_is_named_with_its_path(text: str, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(text, "site.toml")
    assert expected in str(info.value)


def test_a_csv_replay_at_a_rate_the_config_cannot_run_is_refused_at_start_in_one_line(tmp_path: Path) -> None:
    path = tmp_path / "slow.csv"
    write_csv_recording(path, 1.7e9 + np.arange(400) / 10.0, np.full((400, 3), 9.81))  # 10 Hz: the 10 Hz low-pass cannot run
    with pytest.raises(RecordingError, match=r"slow\.csv: recorded at 10 Hz, a rate the config's \[processing\] cannot run at"):
        open_source(parse_config(f'[source]\nkind = "replay"\npath = "{path}"\n', "t"))
