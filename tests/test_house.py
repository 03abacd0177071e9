"""The house's import contract (tests/house.py): the project keeps it, and a broken layer is named."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests import house

RULES = textwrap.dedent(
    """
    [tool.bogiemon.house]
    layers = ["cli", "fleet | lab", "daemon", "judgement | simulator", "drivers | detection"]

    [[tool.bogiemon.house.only]]
    layer = "judgement"
    of = "drivers"
    targets = ["drivers.base"]
    why = "the window and its status bits"

    [[tool.bogiemon.house.never]]
    layer = "fleet"
    targets = ["daemon.delivery"]
    why = "not the gateway's delivery stack"

    [[tool.bogiemon.house.lazily]]
    layer = "daemon"
    targets = ["simulator"]
    why = "only when a command needs it"
    """
)
LAYERS = ("cli", "fleet", "lab", "daemon", "judgement", "simulator", "drivers", "detection")


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    (tmp_path / "pyproject.toml").write_text(RULES, encoding="utf-8")
    base = {f"bogiemon/{layer}/__init__.py": "" for layer in LAYERS} | {"bogiemon/daemon/delivery/__init__.py": ""}
    for name, text in {**base, **files}.items():
        path = tmp_path / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text), encoding="utf-8")
    return tmp_path


def test_the_project_keeps_its_layers() -> None:
    problems, n_modules = house.check()
    assert problems == []
    assert n_modules > 50


def test_the_check_in_make_test_passes_on_the_project() -> None:
    proc = subprocess.run([sys.executable, str(house.ROOT / "tests" / "house.py")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "modules keep the layers" in proc.stdout


def test_the_project_names_every_layer_of_its_package_in_the_contract() -> None:
    layers = {path.parent.name for path in (house.ROOT / "bogiemon").glob("*/__init__.py")}
    problems, _ = house.check()
    assert layers >= {"cli", "judgement", "daemon", "drivers", "detection", "fleet", "lab", "simulator", "config"}
    assert not [p for p in problems if "is not in [tool.bogiemon.house] layers" in p]


@pytest.mark.parametrize(
    ("name", "text", "broken"),
    [
        # The command line is on top: nothing imports it, not even inside a function.
        ("bogiemon/daemon/service.py", "def f():\n    from bogiemon.cli import main\n", "'daemon never imports cli, a layer above it'"),
        ("bogiemon/fleet/judge.py", "from bogiemon.cli.fleet import run\n", "'fleet never imports cli, a layer above it'"),
        # The verdict sits below the service.
        ("bogiemon/judgement/verdict.py", "from bogiemon.daemon.monitor import Monitor\n", "'judgement never imports daemon, a layer above it'"),
        ("bogiemon/judgement/verdict.py", "from ..daemon import monitor\n", "'judgement never imports daemon, a layer above it'"),
        ("bogiemon/judgement/verdict.py", "from bogiemon.drivers.recording import read\n", "'judgement imports of drivers only drivers.base'"),
        ("bogiemon/detection/core.py", "def f():\n    import bogiemon.judgement.verdict\n", "'detection never imports judgement, a layer above it'"),
        ("bogiemon/simulator/run.py", "from bogiemon.judgement import verdict\n", "'simulator and judgement are siblings and never import each other'"),
        ("bogiemon/fleet/judge.py", "from bogiemon.lab import study\n", "'fleet and lab are siblings and never import each other'"),
        ("bogiemon/daemon/service.py", "from bogiemon.simulator import simulate\n", "'daemon imports simulator only inside a function'"),
        ("bogiemon/fleet/judge.py", "from bogiemon.daemon.delivery.publisher import send\n", "'fleet never imports daemon.delivery'"),
        ("bogiemon/fleet/judge.py", "def f():\n    import bogiemon.daemon.delivery\n", "'fleet never imports daemon.delivery'"),
        ("bogiemon/fleet/judge.py", "from bogiemon.daemon import delivery\n", "'fleet never imports daemon.delivery'"),
        ("bogiemon/tools/x.py", "from bogiemon.daemon import config\n", "the layer 'tools' is not in [tool.bogiemon.house] layers"),
    ],
)
def test_a_wrong_import_is_named_with_its_file_line_and_broken_layer(tmp_path: Path, name: str, text: str, broken: str) -> None:
    problems, _ = house.check(_tree(tmp_path, {name: text}))
    assert problems and all(p.startswith(f"{name}:") for p in problems)
    assert any(broken in p for p in problems), problems


def test_imports_down_the_layers_and_lazy_ones_where_allowed_pass(tmp_path: Path) -> None:
    files = {
        "bogiemon/cli/main.py": "from bogiemon.lab import study\nfrom bogiemon.fleet import judge\nfrom bogiemon.simulator import run\n",
        "bogiemon/daemon/service.py": "from bogiemon.judgement import verdict\ndef f():\n    from bogiemon.simulator import simulate\n",
        "bogiemon/judgement/verdict.py": "from bogiemon.drivers.base import Block\nfrom bogiemon.detection import core\n",
        # A dotted target names that part alone: the rest of its layer stays open.
        "bogiemon/fleet/judge.py": "from bogiemon.daemon import messages\nfrom bogiemon.daemon.deliveryman import x\n",
    }
    assert house.check(_tree(tmp_path, files))[0] == []


def test_an_import_cycle_is_refused_even_when_one_side_is_for_the_type_checker(tmp_path: Path) -> None:
    files = {
        "bogiemon/judgement/health.py": "from bogiemon.judgement.gating import Gate\n",
        "bogiemon/judgement/gating.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from bogiemon.judgement.health import HealthSettings\n",
    }
    problems, _ = house.check(_tree(tmp_path, files))
    assert problems == [
        "bogiemon/judgement/gating.py: an import cycle (those inside functions and for TYPE_CHECKING counted): "
        "bogiemon.judgement.gating <-> bogiemon.judgement.health"
    ]


def test_an_import_back_inside_a_function_is_a_cycle_too(tmp_path: Path) -> None:
    files = {
        "bogiemon/fleet/judge.py": "def judge_fleet():\n    from bogiemon.fleet.evidence import fleet_relative\n",
        "bogiemon/fleet/evidence.py": "from bogiemon.fleet.judge import WagonJudged\n",
    }
    problems, _ = house.check(_tree(tmp_path, files))
    assert [p.split(": ", 1)[1] for p in problems] == [
        "an import cycle (those inside functions and for TYPE_CHECKING counted): bogiemon.fleet.evidence <-> bogiemon.fleet.judge"
    ]


def test_a_broken_layer_fails_the_command_with_one_line_per_import(tmp_path: Path) -> None:
    root = _tree(tmp_path, {"bogiemon/detection/core.py": "import bogiemon.daemon\nimport bogiemon.simulator\n"})
    code = f"import sys; sys.path.insert(0, {str(house.ROOT)!r}); from tests import house; house.ROOT = __import__('pathlib').Path({str(root)!r}); sys.exit(house.main())"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 1
    lines = proc.stderr.splitlines()
    assert len(lines) == 3 and lines[-1] == "house: 2 import(s) break the layers in pyproject.toml [tool.bogiemon.house]"
