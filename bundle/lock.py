"""`make lock`: the gateway's lock files, bundle/lock/<arch>-cp3XX.txt, from PyPI.

For each architecture (aarch64, x86_64) and CPython (3.11, 3.12, 3.13), pip resolves bogiemon's
base dependencies (pyproject.toml [project].dependencies: what a gateway runs, no extra) and pip
itself (the installer runs pip from its wheel, so the target needs no pip) to manylinux wheels
only, and writes what it chose as a requirements file: one wheel per package, pinned with its
SHA-256. `make bundle` downloads exactly those wheels (pip download --require-hashes) and
install.sh installs them with --require-hashes: nothing on a gateway is resolved again.

The lock is regenerated on purpose (a dependency's new release, pyproject.toml's dependencies
changed), never by the bundle: each file's header holds the digest of the dependencies it was
resolved from, and bundle/build.py refuses a lock that no longer matches pyproject.toml.

Run with the tools venv of `make lock` (bundle/tools.mk): `python bundle/lock.py [--arch A]`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import subprocess
import sys
import tempfile
import tomllib
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
LOCK_DIR = REPO / "bundle" / "lock"
PYTHONS = ("3.11", "3.12", "3.13")
# manylinux tags a gateway's glibc runs: 2.17 (manylinux2014) up to 2.28 (Debian 10, Raspberry Pi
# OS 10, RHEL 8, Ubuntu 20.04 and later). numpy publishes its newer aarch64 wheels for 2.28 only.
MANYLINUX = ("manylinux2014", "manylinux_2_24", "manylinux_2_28")
ARCHES = ("aarch64", "x86_64")
# The installer bootstraps from pip's wheel; pinned here, locked with the rest.
INSTALLER = "pip==24.3.1"


class LockError(RuntimeError):
    """The lock cannot be made (pip failed, or a marker a cross-resolution cannot evaluate)."""


def platforms(arch: str) -> list[str]:
    return [f"{tag}_{arch}" for tag in MANYLINUX]


def dependencies(pyproject: Path = REPO / "pyproject.toml") -> list[str]:
    """pyproject.toml's base dependencies: the gateway's."""
    project = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]
    return list(project["dependencies"])


def dependencies_digest(deps: list[str]) -> str:
    """What a lock was resolved from, as a short digest (the lock's header; build.py compares)."""
    return hashlib.sha256("\n".join([*deps, INSTALLER]).encode()).hexdigest()[:16]


def resolve(arch: str, python: str, deps: list[str], pip: list[str]) -> list[dict[str, Any]]:
    """pip's resolution of deps for (arch, python), wheels only: its report's install list."""
    abi = "cp" + python.replace(".", "")
    with tempfile.TemporaryDirectory() as tmp:
        report = Path(tmp) / "report.json"
        command = [
            *pip, "install", "--dry-run", "--ignore-installed", "--quiet", "--disable-pip-version-check",
            "--only-binary=:all:", *(f"--platform={p}" for p in platforms(arch)),
            f"--python-version={python}", "--implementation=cp", f"--abi={abi}", "--abi=abi3", "--abi=none",
            f"--target={tmp}/target", f"--report={report}", *deps, INSTALLER,
        ]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True)
        if done.returncode != 0:
            raise LockError(f"pip could not resolve for {arch} CPython {python}:\n{done.stderr[-3000:]}")
        installs: list[dict[str, Any]] = json.loads(report.read_text())["install"]
    return installs


# Markers a resolution on this machine evaluates for the machine it runs on, not for the target.
_HOST_MARKERS = re.compile(r"platform_machine|platform\.machine|platform_release|platform_version")


def lock_lines(installs: list[dict[str, Any]]) -> list[str]:
    """One requirement per wheel: `name==version --hash=sha256:...`, with the file as a comment."""
    lines = []
    for item in sorted(installs, key=lambda i: str(i["metadata"]["name"]).lower()):
        meta = item["metadata"]
        for requirement in meta.get("requires_dist") or []:
            if _HOST_MARKERS.search(requirement):
                raise LockError(f"{meta['name']} requires '{requirement}': a marker of the machine, which a cross-resolution "
                                "cannot evaluate for the target; resolve on the target architecture")  # fmt: skip
        url = str(item["download_info"]["url"])
        sha256 = item["download_info"]["archive_info"]["hashes"]["sha256"]
        name = re.sub(r"[-_.]+", "-", str(meta["name"])).lower()
        lines.append(f"{name}=={meta['version']} --hash=sha256:{sha256}  # {url.rsplit('/', 1)[-1]}")
    return lines


def write_lock(arch: str, python: str, lines: list[str], digest: str, pip_version: str) -> Path:
    abi = "cp" + python.replace(".", "")
    path = LOCK_DIR / f"{arch}-{abi}.txt"
    header = [
        f"# bogiemon's gateway lock for {arch}, CPython {python} ({', '.join(platforms(arch))} wheels).",
        "# Regenerate with `make lock` (bundle/lock.py); never edit. `make bundle` downloads these wheels",
        "# and install.sh installs them with --require-hashes.",
        f"# dependencies-digest: {digest}",
        f"# resolved: {datetime.now(UTC).date().isoformat()} by pip {pip_version} from PyPI",
    ]
    path.write_text("\n".join([*header, *lines]) + "\n", encoding="utf-8")
    return path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", choices=ARCHES, action="append", help="only this architecture (repeatable; default both)")
    args = parser.parse_args()
    pip = [sys.executable, "-m", "pip"]
    pip_version = subprocess.run([*pip, "--version"], capture_output=True, text=True, check=True).stdout.split()[1]
    deps = dependencies()
    digest = dependencies_digest(deps)
    LOCK_DIR.mkdir(parents=True, exist_ok=True)
    try:
        for arch in args.arch or ARCHES:
            for python in PYTHONS:
                lines = lock_lines(resolve(arch, python, deps, pip))
                path = write_lock(arch, python, lines, digest, pip_version)
                print(f"lock: {path.relative_to(REPO)}: {len(lines)} wheels")
    except LockError as exc:
        print(f"lock: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
