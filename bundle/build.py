"""`make bundle ARCH=aarch64|x86_64`: the offline bundle a gateway installs from (docs/gateway.md).

build/bundle/bogiemon-<version>-<arch>.tar.gz unpacks to one folder holding:

    install.sh          the installer: needs python3 (3.11 to 3.13) and this folder, no network
    VERSION, ARCH       what the bundle installs, and for which machine
    wheels/             bogiemon's wheel (built from this checkout) and, for CPython 3.11, 3.12 and
                        3.13, every wheel of bundle/lock/<arch>-cp3XX.txt (downloaded from PyPI by
                        pip, each checked against the lock's SHA-256); pip's wheel runs the install
    lock/               those lock files, and bogiemon.txt: bogiemon's wheel with its SHA-256
    config/             the shipped default config (bogiemon.toml)
    systemd/            the units and the network files
    SHA256SUMS          of every file above

The lock is the one checked in: a lock resolved from other dependencies than pyproject.toml's
is refused (`make lock` regenerates it). Run with the tools venv: `python bundle/build.py --arch A`.
"""

from __future__ import annotations

import argparse
import hashlib
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lock import ARCHES, LOCK_DIR, PYTHONS, REPO, dependencies, dependencies_digest, platforms  # noqa: E402

OUT_DIR = REPO / "build" / "bundle"


class BundleError(RuntimeError):
    """The bundle cannot be built (a stale lock, pip failed); the message says what to do."""


def version() -> str:
    """bogiemon.__version__ of this checkout (the package's __init__, read: nothing imported)."""
    found = re.search(r'^__version__ = "([^"]+)"$', (REPO / "bogiemon" / "__init__.py").read_text(encoding="utf-8"), re.M)
    if found is None:
        raise BundleError("bogiemon/__init__.py: no __version__ = \"...\" line")
    return found.group(1)


def lock_files(arch: str) -> list[Path]:
    """The arch's lock files, checked to be resolved from pyproject.toml's dependencies as they are."""
    digest = dependencies_digest(dependencies())
    files = []
    for python in PYTHONS:
        path = LOCK_DIR / f"{arch}-cp{python.replace('.', '')}.txt"
        if not path.exists():
            raise BundleError(f"{path.relative_to(REPO)} is missing: run `make lock`")
        if f"# dependencies-digest: {digest}" not in path.read_text(encoding="utf-8"):
            raise BundleError(f"{path.relative_to(REPO)} was resolved from other dependencies than pyproject.toml's: run `make lock`")
        files.append(path)
    return files


def pip(*args: str) -> None:
    done = subprocess.run([sys.executable, "-m", "pip", "--disable-pip-version-check", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise BundleError(f"pip {args[0]} failed:\n{done.stderr[-3000:]}")


def sha256_of(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def build(arch: str, out_dir: Path = OUT_DIR) -> Path:
    """Build the bundle folder and its tarball; returns the tarball."""
    locks = lock_files(arch)
    name = f"bogiemon-{version()}-{arch}"
    folder = out_dir / name
    shutil.rmtree(folder, ignore_errors=True)
    (folder / "wheels").mkdir(parents=True)
    (folder / "lock").mkdir()
    for python, lock in zip(PYTHONS, locks, strict=True):
        abi = "cp" + python.replace(".", "")
        pip("download", "--no-deps", "--only-binary=:all:", "--require-hashes", *(f"--platform={p}" for p in platforms(arch)),
            f"--python-version={python}", "--implementation=cp", f"--abi={abi}", "--abi=abi3", "--abi=none",
            "-r", str(lock), "-d", str(folder / "wheels"))  # fmt: skip
        shutil.copy2(lock, folder / "lock" / lock.name)
    with tempfile.TemporaryDirectory() as tmp:
        # The package built from a copy of what makes it: setuptools keeps a build/ folder beside
        # the project, whose leftovers (a module since deleted) would go into the wheel.
        source = Path(tmp) / "bogiemon"
        shutil.copytree(REPO / "bogiemon", source / "bogiemon", ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        for file in ("pyproject.toml", "README.md"):
            shutil.copy2(REPO / file, source / file)
        pip("wheel", "--no-deps", "-w", str(folder / "wheels"), str(source))
    own = sorted((folder / "wheels").glob("bogiemon-*.whl"))
    if len(own) != 1:
        raise BundleError(f"expected one bogiemon wheel in {folder / 'wheels'}, found {len(own)}")
    (folder / "lock" / "bogiemon.txt").write_text(f"bogiemon=={version()} --hash=sha256:{sha256_of(own[0])}\n", encoding="utf-8")
    (folder / "config").mkdir()
    shutil.copy2(REPO / "bogiemon" / "config" / "bogiemon.toml", folder / "config" / "bogiemon.toml")
    shutil.copytree(REPO / "systemd", folder / "systemd")
    shutil.copy2(REPO / "bundle" / "install.sh", folder / "install.sh")
    (folder / "install.sh").chmod(0o755)
    (folder / "VERSION").write_text(version() + "\n", encoding="utf-8")
    (folder / "ARCH").write_text(arch + "\n", encoding="utf-8")
    files = sorted(p for p in folder.rglob("*") if p.is_file())
    (folder / "SHA256SUMS").write_text("".join(f"{sha256_of(p)}  {p.relative_to(folder)}\n" for p in files), encoding="utf-8")
    tarball = out_dir / f"{name}.tar.gz"
    with tarfile.open(tarball, "w:gz") as tar:
        tar.add(folder, arcname=name)
    return tarball


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--arch", choices=ARCHES, required=True)
    parser.add_argument("-o", "--out-dir", type=Path, default=OUT_DIR, help=f"where the bundle goes (default {OUT_DIR.relative_to(REPO)})")
    args = parser.parse_args()
    try:
        tarball = build(args.arch, args.out_dir)
    except BundleError as exc:
        print(f"bundle: error: {exc}", file=sys.stderr)
        return 2
    wheels = list((tarball.parent / tarball.name.removesuffix(".tar.gz") / "wheels").glob("*.whl"))
    print(f"bundle: {tarball} ({tarball.stat().st_size / 1e6:.1f} MB, {len(wheels)} wheels for CPython {', '.join(PYTHONS)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
