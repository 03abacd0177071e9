"""The gateway bundle's lock (bundle/lock.py, bundle/build.py): checked in, in step with
pyproject.toml, one pinned and hashed wheel per package. No network here: `make bundle` and
`make test-arm` build and install the bundle itself."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bundle"))

import build  # noqa: E402
import lock  # noqa: E402

REQUIREMENT = re.compile(r"^([a-z0-9-]+)==(\S+) --hash=sha256:[0-9a-f]{64}  # (\S+\.whl)$")


@pytest.mark.parametrize("arch", lock.ARCHES)
def test_the_checked_in_lock_is_resolved_from_pyprojects_dependencies(arch: str) -> None:
    assert [path.name for path in build.lock_files(arch)] == [f"{arch}-cp311.txt", f"{arch}-cp312.txt", f"{arch}-cp313.txt"]


@pytest.mark.parametrize("path", sorted((lock.LOCK_DIR).glob("*.txt")), ids=lambda p: p.name)
def test_each_lock_pins_every_dependency_to_one_hashed_wheel_of_its_architecture(path: Path) -> None:
    arch, abi = path.stem.split("-")
    lines = [line for line in path.read_text().splitlines() if not line.startswith("#")]
    found = {m.group(1): m.group(3) for m in map(REQUIREMENT.match, lines) if m}
    assert len(found) == len(lines)  # every line a pinned, hashed wheel
    wanted = {re.split(r"[<>=!~ \[;]", d, maxsplit=1)[0].lower() for d in lock.dependencies()} | {"pip"}
    assert wanted <= set(found)
    for name, wheel in found.items():
        tags = wheel.removesuffix(".whl").split("-")[-3:]
        assert tags[2] == "any" or (arch in tags[2] and "manylinux" in tags[2]), f"{name}: {wheel}"
        assert tags[1] in ("none", "abi3", abi), f"{name}: {wheel}"


def test_a_lock_from_other_dependencies_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(build, "dependencies", lambda: ["numpy>=1.26,<3", "scipy"])
    with pytest.raises(build.BundleError, match=r"resolved from other dependencies than pyproject.toml's: run `make lock`"):
        build.lock_files("aarch64")


def test_a_dependency_with_a_machine_marker_stops_the_cross_resolution() -> None:
    report = [{
        "metadata": {"name": "example", "version": "1.0", "requires_dist": ["helper; platform_machine == 'x86_64'"]},
        "download_info": {"url": "https://files/example-1.0-py3-none-any.whl", "archive_info": {"hashes": {"sha256": "0" * 64}}},
    }]  # fmt: skip
    with pytest.raises(lock.LockError, match="a marker of the machine"):
        lock.lock_lines(report)


def test_the_bundles_version_is_the_packages() -> None:
    import bogiemon

    assert build.version() == bogiemon.__version__
