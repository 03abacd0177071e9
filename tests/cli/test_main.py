"""The command line's frame: what `bogiemon run` loads, and the user errors it turns into one line."""

from __future__ import annotations

import importlib
import json
import subprocess
import sys

import pytest

from bogiemon.cli.main import USER_ERRORS, is_user_error

# What a gateway never loads: the offline lab, the simulator (and its compiler), the plotting
# library, scipy and pyarrow (extras a gateway installs without: pyproject.toml).
NOT_ON_A_GATEWAY = ("bogiemon.lab", "bogiemon.simulator", "bogiemon.fleet", "matplotlib", "numba", "scipy", "pyarrow")

# Everything `bogiemon run` imports before it reads its first block: the command line, the
# service and the CAN source it opens, the config with its shipped models and the monitor's settings.
RUN_PATH = """
import json, sys
from bogiemon.cli.main import build_parser
build_parser()
import bogiemon.cli.run
from bogiemon.daemon.config import load_config
from bogiemon.daemon.service import Service
from bogiemon.daemon.sources import open_source
config = load_config(None)
config.monitor_settings()
source = open_source(config)
source.close()
print(json.dumps(sorted(sys.modules)))
"""


# As installed without the mf4 extra (a gateway): python-can imports asammdf, and with it pandas
# and pyarrow, at `import can` wherever asammdf is installed (can/io/mf4.py), as in the test venv.
WITHOUT_MF4 = "import sys; sys.modules['asammdf'] = None\n"


def _loaded(code: str) -> list[str]:
    proc = subprocess.run([sys.executable, "-c", WITHOUT_MF4 + code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def _forbidden(modules: list[str]) -> list[str]:
    return [m for m in modules if any(m == bad or m.startswith(bad + ".") for bad in NOT_ON_A_GATEWAY)]


def test_the_run_command_loads_neither_the_lab_nor_the_simulator_nor_matplotlib_nor_scipy_stats() -> None:
    modules = _loaded(RUN_PATH)
    assert "bogiemon.daemon.service" in modules and "bogiemon.detection" in modules
    assert _forbidden(modules) == []


def test_the_command_line_imports_only_argparse_and_its_command_modules_to_parse() -> None:
    modules = _loaded("import json, sys\nfrom bogiemon.cli.main import build_parser\nbuild_parser()\nprint(json.dumps(sorted(sys.modules)))")
    assert _forbidden(modules) == []
    heavy = [m for m in modules if m.split(".")[0] in ("numpy", "scipy", "pydantic", "can", "paho", "cantools")]
    assert heavy == []


@pytest.mark.parametrize("name", sorted(USER_ERRORS))
def test_every_user_error_names_an_exception_class(name: str) -> None:
    module, _, qualname = name.rpartition(".")
    cls = getattr(importlib.import_module(module), qualname)
    assert isinstance(cls, type) and issubclass(cls, Exception)
    assert is_user_error(cls("x"))


def test_a_subclass_of_a_user_error_is_one_and_an_internal_error_is_not() -> None:
    from bogiemon.daemon.config import ConfigError

    class Narrower(ConfigError):
        pass

    assert is_user_error(Narrower("x"))
    assert not is_user_error(KeyError("x"))


@pytest.mark.parametrize("command", ["run", "replay", "events", "demo"])
def test_every_command_that_keeps_an_event_store_takes_state_dir(command: str) -> None:
    from bogiemon.cli.main import build_parser

    extra = {"replay": ["run.csv"]}.get(command, [])
    args = build_parser().parse_args([command, *extra, "--state-dir", "/tmp/elsewhere"])
    assert args.state_dir == "/tmp/elsewhere"
