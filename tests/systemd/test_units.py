"""The unit files as systemd itself reads them: `verify` says nothing, the exposure stays <= 2.0."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

SYSTEMD_DIR = Path(__file__).resolve().parents[2] / "systemd"
INSTALLED_BOGIEMON = "/opt/bogiemon/bin/bogiemon"
pytestmark = pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")


def service_units() -> list[Path]:
    return sorted(SYSTEMD_DIR.glob("*.service"))


def installed_copy(unit: Path, tmp_path: Path) -> Path:
    """The unit with ExecStart pointing at this checkout's bogiemon, as an install would."""
    here = Path(sys.executable).with_name("bogiemon")
    out = tmp_path / unit.name
    out.write_text(unit.read_text().replace(INSTALLED_BOGIEMON, str(here)))
    return out


def test_there_is_a_service_unit() -> None:
    assert SYSTEMD_DIR.joinpath("bogiemon.service") in service_units()


@pytest.mark.parametrize("unit", service_units(), ids=lambda p: p.name)
def test_verify_reports_nothing(unit: Path, tmp_path: Path) -> None:
    proc = subprocess.run(["systemd-analyze", "verify", str(installed_copy(unit, tmp_path))], capture_output=True, text=True)
    assert proc.returncode == 0 and proc.stdout == "" and proc.stderr == "", proc.stdout + proc.stderr


@pytest.mark.parametrize("unit", service_units(), ids=lambda p: p.name)
def test_security_exposure_is_at_most_2(unit: Path, tmp_path: Path) -> None:
    proc = subprocess.run(
        ["systemd-analyze", "security", "--offline=true", "--no-pager", str(installed_copy(unit, tmp_path))],
        capture_output=True,
        text=True,
    )
    match = re.search(r"Overall exposure level for \S+: (\d+\.\d+)", proc.stdout)
    assert match, proc.stdout + proc.stderr
    assert float(match.group(1)) <= 2.0, proc.stdout


def test_the_unit_has_what_the_gateway_needs() -> None:
    text = (SYSTEMD_DIR / "bogiemon.service").read_text()
    for line in (
        "Type=notify", "WatchdogSec=", "Restart=on-failure", "ExecReload=", "DynamicUser=yes",
        "StateDirectory=bogiemon", "ConfigurationDirectory=bogiemon", "OPENBLAS_NUM_THREADS=1",
        "ProtectSystem=strict", "CapabilityBoundingSet=\n", "RestrictAddressFamilies=AF_UNIX AF_CAN AF_NETLINK",
        "SystemCallFilter=@system-service", "DeviceAllow=", "MemoryMax=",
    ):  # fmt: skip
        assert line in text, line
