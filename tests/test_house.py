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
    [tool.setuptools.package-dir]
    "bogiemon.detection" = "detection"
    "bogiemon.daemon" = "daemon"
    "bogiemon.daemon.cli" = "daemon/cli"
    "bogiemon.simulator" = "simulator"
    "bogiemon.lab" = "lab"
    "bogiemon.fleet" = "fleet"

    [[tool.bogiemon.house.never]]
    layer = "fleet"
    targets = ["daemon.delivery"]
    why = "not the gateway's delivery stack"

    [[tool.bogiemon.house.never]]
    layer = "detection"
    targets = ["daemon", "simulator", "lab"]
    why = "the pure core"

    [[tool.bogiemon.house.never]]
    layer = "daemon"
    targets = ["lab"]
    why = "the product never loads the lab"

    [[tool.bogiemon.house.lazily]]
    layer = "daemon"
    targets = ["simulator"]
    why = "only when a command needs it"

    [[tool.bogiemon.house.only_from]]
    layer = "lab"
    targets = ["bogiemon.daemon.cli.study"]
    why = "from its command alone"
    """
)


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    (tmp_path / "pyproject.toml").write_text(RULES, encoding="utf-8")
    for name, text in {"detection/__init__.py": "", "daemon/__init__.py": "", "daemon/cli/__init__.py": "",
                       "simulator/__init__.py": "", "lab/__init__.py": "", "fleet/__init__.py": "", **files}.items():  # fmt: skip
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


@pytest.mark.parametrize(
    ("name", "text", "broken"),
    [
        ("detection/core.py", "from bogiemon.daemon.config import load_config\n", "'detection never imports daemon': the pure core"),
        ("detection/core.py", "def f():\n    import bogiemon.lab.study\n", "'detection never imports lab': the pure core"),
        ("daemon/service.py", "from bogiemon.simulator import simulate\n", "'daemon imports simulator only inside a function'"),
        ("daemon/service.py", "def f():\n    from bogiemon.lab import study\n", "'daemon never imports lab'"),
        ("daemon/cli/study.py", "from bogiemon.lab import study\n", "'lab is imported only by bogiemon.daemon.cli.study, inside a function'"),
        ("simulator/run.py", "from ..lab import study\n", "'lab is imported only by bogiemon.daemon.cli.study, inside a function'"),
        ("fleet/judge.py", "from bogiemon.daemon.delivery.publisher import send\n", "'fleet never imports daemon.delivery'"),
        ("fleet/judge.py", "def f():\n    import bogiemon.daemon.delivery\n", "'fleet never imports daemon.delivery'"),
    ],
)
def test_a_wrong_import_is_named_with_its_file_line_and_broken_layer(tmp_path: Path, name: str, text: str, broken: str) -> None:
    problems, _ = house.check(_tree(tmp_path, {name: text}))
    assert problems and all(p.startswith(f"{name}:") for p in problems)
    assert any(broken in p for p in problems), problems


def test_lazy_imports_where_allowed_and_type_checking_imports_pass(tmp_path: Path) -> None:
    files = {
        "daemon/service.py": "def f():\n    from bogiemon.simulator import simulate\n",
        "daemon/cli/study.py": "def run():\n    from bogiemon.lab import study\n",
        "detection/core.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from bogiemon.daemon import config\n",
        "lab/plan.py": "from bogiemon.daemon import config\nfrom bogiemon.simulator import run\n",
        # A dotted target names that part alone: the rest of its layer stays open.
        "fleet/judge.py": "from bogiemon.daemon import messages\nfrom bogiemon.daemon.deliveryman import x\n",
    }
    assert house.check(_tree(tmp_path, files))[0] == []


def test_a_broken_layer_fails_the_command_with_one_line_per_import(tmp_path: Path) -> None:
    root = _tree(tmp_path, {"detection/core.py": "import bogiemon.daemon\nimport bogiemon.simulator\n"})
    code = f"import sys; sys.path.insert(0, {str(house.ROOT)!r}); from tests import house; house.ROOT = __import__('pathlib').Path({str(root)!r}); sys.exit(house.main())"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 1
    lines = proc.stderr.splitlines()
    assert len(lines) == 3 and lines[-1] == "house: 2 import(s) break the layers in pyproject.toml [tool.bogiemon.house]"
